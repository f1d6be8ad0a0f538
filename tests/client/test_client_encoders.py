"""The client's lean encoders (xrce/client/outbound.py and entities.py, the session's control
submessages) write the same bytes as the general codec the agent decodes with (xrce/wire/submessages.py,
xrce/wire/objects.py)."""

import pytest
from hypothesis import given, settings, strategies as st

from xrce.wire import constants as C
from xrce.client import entities, outbound
from xrce.client.session import Session
from xrce.wire.message import MessageWriter
from xrce.wire.objects import DataReaderBin, DataWriterBin, EndpointQos, ParticipantBin, PubSubBin, TopicBin
from xrce.wire.session_payloads import Locator
from xrce.wire.submessages import (
    AckNack, Create, DeliveryControl, Delete, GetInfo, ReadData, Timestamp, decode_message, encode_message,
    write_submessage,
)


class _Lean:
    # A request as the session writes it (outbound.put_request), shaped for write_submessage.

    def __init__(self, sub_id, flags, request_id, object_id, body):
        self.ID, self.flags = sub_id, flags
        self.request_id, self.object_id, self.body = request_id, object_id, body

    def encode(self, w):
        outbound.put_request(w, self.request_id, self.object_id, self.body)


def _message(payload, session_id=0x81):
    mw = MessageWriter(64)
    mw.begin(session_id, 0x80, 3)
    write_submessage(mw, payload)
    return mw.getvalue()


@pytest.mark.parametrize("name", [None, "", "talker", "a_node_with_a_longer_name"])
def test_participant_blob(name):
    assert entities.participant_blob(name) == ParticipantBin(name).to_blob()


@pytest.mark.parametrize("type_name", [None, "std_msgs::msg::dds_::String_"])
def test_topic_blob(type_name):
    assert entities.topic_blob("rt/chatter", type_name) == TopicBin("rt/chatter", type_name).to_blob()


def test_pubsub_blob():
    assert entities.PUBSUB_BLOB == PubSubBin().to_blob()


@pytest.mark.parametrize("flags", [0, C.QOS_RELIABLE | C.QOS_KEEP_LAST, C.QOS_KEEP_LAST | C.QOS_TRANSIENT_LOCAL])
@pytest.mark.parametrize("depth", [None, 1, 10, 0xFFFF])
def test_endpoint_blobs(flags, depth):
    qos = EndpointQos(flags, depth)
    assert entities.endpoint_blob(0x12, flags, depth, False) == DataWriterBin(0x12, qos).to_blob()
    assert entities.endpoint_blob(0x12, flags, depth, True) == DataReaderBin(0x12, qos).to_blob()


@pytest.mark.parametrize("kind, rep, tail", [
    (C.OBJK_PARTICIPANT, ParticipantBin("n"), 42),
    (C.OBJK_PARTICIPANT, ParticipantBin(None), -1),
    (C.OBJK_TOPIC, TopicBin("rt/x", "T"), 0x11),
    (C.OBJK_PUBLISHER, PubSubBin(), 0x11),
    (C.OBJK_DATAWRITER, DataWriterBin(0x12, EndpointQos(3, 10)), 0x13),
    (C.OBJK_DATAREADER, DataReaderBin(0x12, EndpointQos(2, None)), 0x14),
])
def test_create_binary(kind, rep, tail):
    flags = C.FLAG_LITTLE_ENDIAN | C.FLAG_REUSE | C.FLAG_REPLACE
    lean = _Lean(C.CREATE, flags, 0x1234, 0x0156, entities.create_body(kind, C.REPRESENTATION_IN_BINARY, rep.to_blob(), tail))
    assert _message(lean) == _message(Create(0x1234, 0x0156, kind, C.REPRESENTATION_IN_BINARY, rep, tail, flags))


@pytest.mark.parametrize("fmt, text", [(C.REPRESENTATION_AS_XML_STRING, "<dds/>"),
                                       (C.REPRESENTATION_BY_REFERENCE, "profile"),
                                       (C.REPRESENTATION_AS_XML_STRING, "")])
def test_create_text(fmt, text):
    lean = _Lean(C.CREATE, 1, 11, 0x0011, entities.create_body(C.OBJK_TOPIC, fmt, text, 0x0001))
    assert _message(lean) == _message(Create(11, 0x0011, C.OBJK_TOPIC, fmt, text, 0x0001, 1))


@pytest.mark.parametrize("delivery", [None, (0xFFFF, 0, 0, 0), (3, 2, 100, 7), (0, 0, 0, 0)])
def test_read_data_and_delete(delivery):
    control = DeliveryControl(*delivery) if delivery is not None else None
    lean = _Lean(C.READ_DATA, 1, 12, 0x0016, entities.read_data_body(0x80, delivery))
    assert _message(lean) == _message(ReadData(12, 0x0016, 0x80, control))
    assert _message(_Lean(C.DELETE, 1, 13, 0x0016, b"")) == _message(Delete(13, 0x0016))


class _Capture:
    mtu = 512

    def __init__(self):
        self.sent = []

    def send(self, data):
        self.sent.append(bytes(data))
        return True

    def recv(self, timeout_ms):
        return None

    def close(self):
        pass


def _control(payload):
    mw = MessageWriter(64)
    mw.begin(0x81, 0, 0)
    write_submessage(mw, payload)
    return mw.getvalue()


def test_session_control_submessages_match_the_codec():
    transport = _Capture()
    session = Session(transport, key=b"\x01\x02\x03\x04", auto_recover=False)
    session._send_ping()
    assert transport.sent[-1] == _control(GetInfo())
    assert session.sync_time(timeout_ms=0) is False
    stamp = decode_message(transport.sent[-1])[1][0]
    assert isinstance(stamp, Timestamp) and transport.sent[-1] == _control(stamp)
    w = session._begin_control(C.ACKNACK)
    w.u16(7)
    w.u8(0x80)
    w.u8(0x01)
    w.u8(0x80)
    session._send_control()
    assert transport.sent[-1] == _control(AckNack(7, 0x8001, 0x80))
    session.delete(attempts=1, timeout_ms=0)
    assert transport.sent[-1] == _control(Delete(C.REQUEST_ID_LOGOUT, C.OBJECTID_CLIENT))


@pytest.mark.parametrize("small", [0, 1, 3])
def test_fragments_carry_the_codec_bytes_after_buffered_samples(small):
    """A sample too big for any message is cut from the bytes already written into the open message
    (not encoded again): the fragments must still carry exactly the general codec's submessage."""
    from xrce.wire.message import iter_submessages
    from xrce.msgs.std_msgs import String
    from xrce.wire.submessages import WriteData

    transport = _Capture()
    session = Session(transport, key=b"\x01\x02\x03\x04", auto_recover=False, history=8)
    session.connected = True
    for i in range(small):
        session.write(0x15, String(data="r%d" % i))
    rid = session.write(0x15, String(data="z" * 1500))
    session.flush()
    mw = MessageWriter(2048)
    mw.begin(0x81, 0, 0)
    write_submessage(mw, WriteData(rid, 0x15, String(data="z" * 1500).to_bytes()))
    mw.pad_to_4()
    expected = mw.getvalue()[4:]
    carried = b""
    for message in transport.sent:
        for sub_id, flags, s, e in iter_submessages(message, 4):
            if sub_id == C.FRAGMENT:
                carried += message[s:e]
    assert carried == expected
    assert transport.sent[0][4] == (C.WRITE_DATA if small else C.FRAGMENT)


class _AckingCapture(_Capture):
    """Answers every wait for input with an ACKNACK of everything the reliable stream sent."""

    def recv(self, timeout_ms):
        sent = [m for m in self.sent if m[1] == 0x80]
        if not sent:
            return None
        last = sent[-1][2] | (sent[-1][3] << 8)
        return encode_message(0x81, 0, 0, None, [AckNack((last + 1) & 0xFFFF, 0, 0x80)])


@pytest.mark.parametrize("in_flight", [0, 2, 3])
def test_fragments_when_the_window_is_short_of_room(in_flight):
    """A sample whose fragments do not all fit the reliable window waits for room between them
    (callbacks may then write to the stream): the fragments still carry the codec's bytes, on
    consecutive sequence numbers."""
    from xrce.wire.message import iter_submessages
    from xrce.msgs.std_msgs import String
    from xrce.wire.submessages import WriteData

    transport = _AckingCapture()
    session = Session(transport, key=b"\x01\x02\x03\x04", auto_recover=False, history=4)
    session.connected = True
    for i in range(in_flight):  # sent and not yet acknowledged: the window has 4 - in_flight left
        session.write(0x15, String(data="r%d" % i))
        session.flush()
    rid = session.write(0x15, String(data="z" * 1500))  # four fragments
    assert rid
    session.flush()
    mw = MessageWriter(2048)
    mw.begin(0x81, 0, 0)
    write_submessage(mw, WriteData(rid, 0x15, String(data="z" * 1500).to_bytes()))
    mw.pad_to_4()
    reliable = [m for m in transport.sent if m[1] == 0x80]
    assert [m[2] | (m[3] << 8) for m in reliable] == list(range(in_flight + 4))
    carried = b""
    for message in reliable[in_flight:]:
        for sub_id, flags, s, e in iter_submessages(message, 4):
            assert sub_id == C.FRAGMENT
            carried += message[s:e]
    assert carried == mw.getvalue()[4:]



@pytest.mark.parametrize("properties", [None, [("uxr_hl", "010000")]])
@pytest.mark.parametrize("impl_status,availability", [(1, 1), (0, 1), (1, 0)])
def test_info_activity_with_and_without_agent_properties(properties, impl_status, availability):
    # The session reads an INFO's implementation status and availability itself; one whose agent
    # configuration carries properties goes through discovery's INFO reader (xrce.client.discovery).
    from xrce.wire.cdr import CdrWriter
    from xrce.client.session import _agent_activity
    from xrce.wire.session_payloads import Info

    w = CdrWriter()
    Info(C.REQUEST_ID_PING, impl_status=impl_status, availability=availability, properties=properties).encode(w)
    message = bytes(8) + w.getvalue()  # where a payload starts: after a keyless header and its subheader
    assert _agent_activity(message, 1, 8, len(message)) == availability
    assert message[8 + 5] == impl_status  # read by the session where it needs it


def test_discovery_get_info_is_the_general_codecs():
    from xrce.client.discovery import _GET_INFO_DISCOVERY

    mw = MessageWriter(32)
    mw.begin(C.SESSION_ID_NONE_WITHOUT_KEY, C.STREAM_NONE, 0)
    write_submessage(mw, GetInfo(C.REQUEST_ID_DISCOVERY, C.OBJECTID_AGENT,
                                 C.INFO_CONFIGURATION | C.INFO_ACTIVITY))
    assert _GET_INFO_DISCOVERY == mw.getvalue()


_ADDRESS_SIZES = {C.LOCATOR_SMALL: 2, C.LOCATOR_MEDIUM: 4, C.LOCATOR_LARGE: 16}


@st.composite
def _locators(draw):
    kind = draw(st.sampled_from([C.LOCATOR_SMALL, C.LOCATOR_MEDIUM, C.LOCATOR_LARGE, C.LOCATOR_STRING]))
    if kind == C.LOCATOR_STRING:
        return Locator(kind, draw(st.text(max_size=12)))
    bits = {C.LOCATOR_SMALL: 8, C.LOCATOR_MEDIUM: 16, C.LOCATOR_LARGE: 32}[kind]
    return Locator(kind, draw(st.binary(min_size=_ADDRESS_SIZES[kind], max_size=_ADDRESS_SIZES[kind])),
                   draw(st.integers(0, 2 ** bits - 1)))


@settings(max_examples=300, deadline=None)
@given(
    impl_status=st.integers(0, 255),
    config=st.none() | st.tuples(st.just(C.XRCE_COOKIE), st.sampled_from([C.XRCE_VERSION, b"\x02\x00"]),
                                 st.just(C.XRCE_VENDOR_EPROSIMA)),
    properties=st.none() | st.lists(st.tuples(st.text(max_size=8), st.text(max_size=8)), max_size=3),
    availability=st.none() | st.integers(-2 ** 15, 2 ** 15 - 1),
    locators=st.lists(_locators(), max_size=4),
)
def test_discovery_reads_info_as_the_general_codec_writes_it(impl_status, config, properties, availability,
                                                             locators):
    # discover_agents' own INFO reader (xrce.client.discovery) against the general codec's encoder
    # (little-endian, as agents send it): every field it reports, with configuration, properties,
    # activity and each locator kind present or not; string locators are left out of what it returns.
    from xrce.client.discovery import _info_locators, read_info
    from xrce.wire.session_payloads import Info

    if config is None:
        properties = None  # properties travel inside the configuration
    info = Info(C.REQUEST_ID_DISCOVERY, impl_status=impl_status, config=config, availability=availability,
                locators=locators if availability is not None else (), properties=properties)
    mw = MessageWriter(64)
    mw.begin(C.SESSION_ID_NONE_WITHOUT_KEY, C.STREAM_NONE, 0)
    info.encode(mw.begin_submessage(C.INFO, 1))
    mw.end_submessage()
    message = mw.getvalue()
    addresses = [(loc.address, loc.port) for loc in info.locators if loc.fmt != C.LOCATOR_STRING]
    assert read_info(message, 1, 8, len(message)) == (
        impl_status, config[1] if config else None, availability, addresses)
    assert _info_locators(message) == (addresses if config and config[1] == C.XRCE_VERSION else [])


def test_on_demand_names_reach_their_module_without_the_entities_module(monkeypatch):
    # Session.__getattr__ sends xrce.client.on_demand's own names straight there: a firmware's
    # first time sync (or ping, link_state, time_offset_ns) must not load the entity-creation
    # module on a board.
    from xrce.client import on_demand
    from xrce.client import session as session_module

    properties = {"link_state", "time_offset_ns"}
    assert set(session_module._ON_DEMAND.split()) == set(on_demand._HERE.split()) | properties
    loaded = []
    real = session_module._set_up_module
    monkeypatch.setattr(session_module, "_set_up_module", lambda name: loaded.append(name) or real(name))
    for name in session_module._ON_DEMAND.split() + ["create_requester"]:
        monkeypatch.delattr(Session, name, raising=False)  # as before its first look-up
    session = Session(_Capture(), key=b"\x01\x02\x03\x04", auto_recover=False)
    for name in session_module._ON_DEMAND.split():
        getattr(session, name)
    assert loaded == []
    session.create_requester  # a services name still goes through the entities module's router
    assert loaded == ["entities"]
