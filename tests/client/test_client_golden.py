"""The client, driven through its public API the way the real eProsima client was driven in each
golden scenario and answered with the captured agent datagrams, sends the captured client datagrams.

What legitimately varies is masked by comparing decoded submessages instead of raw bytes (padding
bytes are not part of a decoded value; the C client leaves garbage there) and by ignoring TIMESTAMP
values. Message lengths, headers, request ids, object ids, flags and every field are compared.
"""

import json
import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from xrce.wire import constants as C
from xrce.client.session import Session, discover_agents, ping_agent
from xrce.wire.message import decode_header, iter_submessages
from xrce.wire.submessages import Fragment, Timestamp, decode_message

GOLDEN = Path(__file__).parents[1] / "golden" / "wire_captures.json"
CAPTURES = json.loads(GOLDEN.read_text())["scenarios"]

TWIST = "geometry_msgs::msg::dds_::Twist_"


class ScriptedAgent:
    """A transport that plays the captured agent: each A->C datagram is handed to the client once the
    client has sent as many datagrams as the capture shows before it. Datagrams the capture marks
    DROPPED are lost in the direction they were lost in."""

    mtu = 512

    def __init__(self, datagrams):
        self.script = []
        sent_before = 0
        for d in datagrams:
            data = bytes.fromhex(d["hex"])
            if d["dir"].startswith("C->A"):
                sent_before += 1
                self.script.append(("C", data, d["dir"].endswith("DROPPED")))
            else:
                self.script.append(("A", data, d["dir"].endswith("DROPPED"), sent_before))
        self.expected = [entry[1] for entry in self.script if entry[0] == "C"]
        self.agent_queue = [entry for entry in self.script if entry[0] == "A"]
        self.sent = []

    def send(self, msg):
        self.sent.append(bytes(msg))
        return True

    def recv(self, timeout_ms):
        while self.agent_queue and self.agent_queue[0][3] <= len(self.sent):
            _, data, dropped, _ = self.agent_queue.pop(0)
            if not dropped:
                return data
        time.sleep(min(timeout_ms, 5) / 1000)
        return None

    def close(self):
        pass


def _submessages(data):
    header = decode_header(data)
    return header, [(sub_id, flags) for sub_id, flags, _, _ in iter_submessages(data, header.size)]


def assert_same_datagram(ours, captured, where):
    assert len(ours) == len(captured), "%s: length %d, captured %d\nours     %s\ncaptured %s" % (
        where, len(ours), len(captured), ours.hex(), captured.hex())
    header_ours, subs_ours = _submessages(ours)
    header_cap, subs_cap = _submessages(captured)
    assert header_ours == header_cap, where
    assert subs_ours == subs_cap, where
    _, payloads_ours = decode_message(ours)
    _, payloads_cap = decode_message(captured)
    for mine, theirs in zip(payloads_ours, payloads_cap):
        if isinstance(mine, Timestamp):
            continue  # the clock differs between runs
        if isinstance(mine, Fragment):
            assert len(mine.data) == len(theirs.data), where
            continue  # chunk contents are checked on the reassembled message below
        assert mine == theirs, "%s:\nours     %r\ncaptured %r" % (where, mine, theirs)


def reassembled(datagrams):
    """The inner submessage payloads carried by consecutive FRAGMENT messages."""
    chunks = bytearray()
    for data in datagrams:
        _, payloads = decode_message(data)
        if isinstance(payloads[0], Fragment):
            chunks += payloads[0].data
    return bytes(chunks)


def assert_same_traffic(agent):
    assert len(agent.sent) == len(agent.expected), "sent %d datagrams, captured %d:\n%s" % (
        len(agent.sent), len(agent.expected), "\n".join(d.hex() for d in agent.sent))
    for i, (ours, captured) in enumerate(zip(agent.sent, agent.expected)):
        assert_same_datagram(ours, captured, "client datagram %d" % (i + 1))
    ours_inner, captured_inner = reassembled(agent.sent), reassembled(agent.expected)
    if captured_inner:
        # The inner WRITE_DATA: header and body equal; only its trailing padding may differ.
        inner_len = 4 + (captured_inner[2] | (captured_inner[3] << 8))
        assert ours_inner[:inner_len] == captured_inner[:inner_len]


def key_of(scenario):
    create_client = bytes.fromhex(CAPTURES[scenario][0]["hex"]) if CAPTURES[scenario][0]["hex"][:2] == "80" else None
    for d in CAPTURES[scenario]:
        data = bytes.fromhex(d["hex"])
        if d["dir"].startswith("C->A") and data[4] == C.CREATE_CLIENT:
            return data[16:20]
    return create_client


def new_session(scenario, history=8):
    agent = ScriptedAgent(CAPTURES[scenario])
    # No link supervision: its pings are ours, not the C client's, and would change the traffic.
    session = Session(agent, key=key_of(scenario), history=history, auto_recover=False)
    assert session.create(attempts=1, timeout_ms=1000)
    return agent, session


def twist_bytes(scenario, index):
    """The captured Twist samples (the test feeds the same values the probe wrote)."""
    samples = []
    for d in CAPTURES[scenario]:
        data = bytes.fromhex(d["hex"])
        _, payloads = decode_message(data)
        for p in payloads:
            if p.ID in (C.WRITE_DATA, C.DATA) and len(p.data) == 48 and p.data not in samples:
                samples.append(p.data)
    return samples[index]


def create_twist_writer(session, reliable=True):
    participant = session.create_participant(0, "xrce_probe", object_id=0x11, flags=C.FLAG_REPLACE)
    topic = session.create_topic(participant, "rt/cmd_vel", TWIST, object_id=0x12, flags=C.FLAG_REPLACE)
    publisher = session.create_publisher(participant, object_id=0x13, flags=C.FLAG_REPLACE)
    writer = session.create_datawriter(publisher, topic, session.endpoint_qos(reliable, True, 10),
                                       object_id=0x15, flags=C.FLAG_REPLACE)
    assert session.run_until_all_status(1000)
    return participant, writer


def create_twist_reader(session, reliable=True):
    participant = session.create_participant(0, "xrce_probe", object_id=0x11, flags=C.FLAG_REPLACE)
    topic = session.create_topic(participant, "rt/cmd_vel", TWIST, object_id=0x12, flags=C.FLAG_REPLACE)
    subscriber = session.create_subscriber(participant, object_id=0x14, flags=C.FLAG_REPLACE)
    reader = session.create_datareader(subscriber, topic, session.endpoint_qos(reliable, True, 10),
                                       object_id=0x16, flags=C.FLAG_REPLACE)
    assert session.run_until_all_status(1000)
    return reader


def test_ping_outside_and_inside_a_session():
    agent = ScriptedAgent(CAPTURES["ping"])
    assert ping_agent(agent, timeout_ms=500, attempts=1) is not None
    session = Session(agent, key=key_of("ping"), auto_recover=False)
    assert session.create(attempts=1)
    assert session.ping(timeout_ms=500)
    assert_same_traffic(agent)


def test_time_sync(monkeypatch):
    import xrce.client.on_demand as timesync
    agent, session = new_session("timesync")
    replies = [decode_message(entry[1])[1][0] for entry in agent.agent_queue]
    for reply in replies:
        # The captured replies echo the captured originate stamps: our clock is pinned to them (and
        # t3 to a 1 ms round trip, so the clock filter takes each one) so that the reply is
        # accepted and the arithmetic is checked exactly.
        t3 = reply.originate_ns + (reply.transmit_ns - reply.receive_ns) + 1000000
        stamps = iter([reply.originate_ns, t3])
        monkeypatch.setattr(timesync, "_now", lambda demand: timesync._anchor_at(demand, next(stamps)))
        assert session.sync_time(timeout_ms=500)
        delta = (reply.originate_ns + t3) - (reply.receive_ns + reply.transmit_ns)
        assert session.time_offset_ns == int(delta / 2)
        assert session.time_rtt_ns == 1000000
    assert_same_traffic(agent)


def _timestamp_reply(session, originate_ns, received_ns, transmitted_ns, t3_ns, monkeypatch, little=True):
    import struct
    import xrce.client.on_demand as timesync
    # The client's clock reads originate_ns for the stamp sent, then t3_ns on the reply.
    monkeypatch.setattr(timesync, "_now", lambda demand: timesync._anchor_at(demand, originate_ns))
    timesync._begin_exchange(session)
    monkeypatch.setattr(timesync, "_now", lambda demand: timesync._anchor_at(demand, t3_ns))
    reply = struct.pack("<iIiIiI" if little else ">iIiIiI", *divmod(transmitted_ns, 10**9),
                        *divmod(received_ns, 10**9), *divmod(originate_ns, 10**9))
    timesync.on_timestamp_reply(session, reply, 1 if little else 0, 0, len(reply))


# Any stamp an int32 of seconds holds: a board without a clock (near 0) and an agent in 2026 differ
# by more than a small integer of seconds on a 32-bit port.
_STAMP_NS = st.integers(min_value=-(2**31) * 10**9, max_value=(2**31 - 4) * 10**9)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(exchanges=st.lists(st.tuples(_STAMP_NS, _STAMP_NS, st.integers(0, 1_500_000_000),
                                    st.integers(-2_000_000_000, 3_000_000_000)), min_size=1, max_size=4),
       little=st.booleans())
def test_time_sync_offset_is_the_ns_formula_whatever_the_clocks(monkeypatch, exchanges, little):
    # The session counts seconds from per-clock bases and keeps nanoseconds apart (no big integer on
    # a board); its offset and round trip are still exactly the nanosecond formulas', rounded
    # toward zero as the C client's int64 division, for any clocks and any order of exchanges.
    session = Session(ScriptedAgent([]), auto_recover=False)
    for originate, received, processing, elapsed in exchanges:
        transmitted = min(received + processing, (2**31 - 1) * 10**9)
        t3 = max(min(originate + elapsed, (2**31 - 1) * 10**9), -(2**31) * 10**9)
        session.time_synced = False  # every exchange taken (the clock filter is tested above)
        _timestamp_reply(session, originate, received, transmitted, t3, monkeypatch, little)
        twice = (originate + t3) - (received + transmitted)
        assert session.time_offset_ns == (-((-twice) // 2) if twice < 0 else twice // 2)
        assert session.time_rtt_ns == max(0, (t3 - originate) - (transmitted - received))
        assert session.time_synced and session.stale_timestamps == 0
        # The agent's clock as the session gives it: its own clock (read at t3) less the offset.
        assert session.epoch_ns() == t3 - session.time_offset_ns


def test_time_sync_keeps_the_tightest_exchange_and_follows_drift(monkeypatch):
    session = Session(ScriptedAgent([]), auto_recover=False)
    t0 = 1_700_000_000 * 10**9
    # The agent's clock is 5 ms ahead; a 1 ms round trip, symmetric: offset -5 ms exactly.
    _timestamp_reply(session, t0, t0 + 5_500_000, t0 + 5_500_000, t0 + 1_000_000, monkeypatch)
    assert session.time_synced and session.time_offset_ns == -5_000_000
    # A reply stalled 20 ms on the way back (GC pause) would say -15 ms: it is not taken.
    t0 += 10**9
    _timestamp_reply(session, t0, t0 + 5_500_000, t0 + 5_500_000, t0 + 21_000_000, monkeypatch)
    assert session.time_offset_ns == -5_000_000
    # The agent's clock moved 3 ms further; exchanges at 1.5 ms round trip are taken again once the
    # kept bound has aged past them.
    offsets = []
    for _ in range(4):
        t0 += 10**9
        _timestamp_reply(session, t0, t0 + 8_750_000, t0 + 8_750_000, t0 + 1_500_000, monkeypatch)
        offsets.append(session.time_offset_ns)
    assert offsets[-1] == -8_000_000, offsets
    assert session.stale_timestamps == 0


def test_stale_timestamp_reply_is_rejected():
    agent, session = new_session("timesync")
    assert not session.sync_time(timeout_ms=50)  # our originate differs from the captured one
    assert session.stale_timestamps >= 1 and not session.time_synced


def test_timestamp_reply_nobody_asked_for_is_counted_not_decoded():
    import xrce.client.on_demand as timesync
    session = Session(ScriptedAgent([]), auto_recover=False)
    reply = bytes(range(24))
    session.handle_message(b"\x81\x00\x00\x00\x0f\x01\x18\x00" + reply)  # before any sync or ping
    timesync._new_state(session)  # as a ping leaves it: no clock read yet
    timesync.on_timestamp_reply(session, reply, 1, 0, len(reply))
    assert session.stale_timestamps == 2 and not session.time_synced


def test_xml_helloworld_publisher():
    agent, session = new_session("xml_helloworld_pub")
    participant = session.create_participant(
        0, xml="<dds><participant><rtps><name>default_xrce_participant</name></rtps></participant></dds>",
        object_id=0x11, flags=C.FLAG_REPLACE)
    topic = session.create_topic(
        participant, xml="<dds><topic><name>HelloWorldTopic</name><dataType>HelloWorld</dataType></topic></dds>",
        object_id=0x12, flags=C.FLAG_REPLACE)
    publisher = session.create_publisher(participant, xml="", object_id=0x13, flags=C.FLAG_REPLACE)
    session.create_datawriter(
        publisher, xml="<dds><data_writer><topic><kind>NO_KEY</kind><name>HelloWorldTopic</name>"
        "<dataType>HelloWorld</dataType></topic></data_writer></dds>", object_id=0x15, flags=C.FLAG_REPLACE)
    assert topic == 0x12
    assert session.run_until_all_status(1000)
    for index in (1, 2, 3):
        body = bytes((index, 0, 0, 0)) + b"\x11\x00\x00\x00Hello DDS world!\x00"
        assert session.write(0x15, body)
        assert session.run_until_confirm_delivery(1000)
    assert session.delete(attempts=1)
    assert_same_traffic(agent)


def test_binary_twist_reliable_with_entity_deletes():
    agent, session = new_session("bin_twist_reliable")
    participant, writer = create_twist_writer(session)
    for i in range(3):
        session.write(writer, twist_bytes("bin_twist_reliable", i))
        assert session.run_until_confirm_delivery(1000)
    session.delete_entity(writer)
    session.delete_entity(participant)
    assert session.run_until_all_status(1000)
    assert session.delete(attempts=1)
    assert_same_traffic(agent)


def test_xml_twist_reliable_spills_into_a_second_message():
    agent, session = new_session("xml_twist_reliable")
    participant = session.create_participant(
        0, xml="<dds><participant><rtps><name>xrce_probe</name></rtps></participant></dds>",
        object_id=0x11, flags=C.FLAG_REPLACE)
    topic = session.create_topic(
        participant, xml="<dds><topic><name>rt/cmd_vel</name><dataType>%s</dataType></topic></dds>" % TWIST,
        object_id=0x12, flags=C.FLAG_REPLACE)
    publisher = session.create_publisher(participant, xml="", object_id=0x13, flags=C.FLAG_REPLACE)
    session.create_datawriter(
        publisher, xml="<dds><data_writer><topic><kind>NO_KEY</kind><name>rt/cmd_vel</name><dataType>%s"
        "</dataType><historyQos><kind>KEEP_LAST</kind><depth>10</depth></historyQos></topic><qos>"
        "<reliability><kind>RELIABLE</kind></reliability><durability><kind>VOLATILE</kind></durability>"
        "</qos></data_writer></dds>" % TWIST, object_id=0x15, flags=C.FLAG_REPLACE)
    assert topic == 0x12
    assert session.run_until_all_status(1000)
    for i in range(2):
        session.write(0x15, twist_bytes("xml_twist_reliable", i))
        assert session.run_until_confirm_delivery(1000)
    assert session.delete(attempts=1)
    assert_same_traffic(agent)


def test_binary_twist_best_effort():
    agent, session = new_session("bin_twist_besteffort")
    _, writer = create_twist_writer(session, reliable=False)
    for i in range(3):
        session.write(writer, twist_bytes("bin_twist_besteffort", i), stream_id=session.best_effort)
        session.flush()
    assert session.delete(attempts=1)
    assert_same_traffic(agent)


@pytest.mark.parametrize("scenario,data_stream", [
    ("sub_twist_reliable", C.BUILTIN_RELIABLE),
    ("sub_twist_besteffort", C.BUILTIN_BEST_EFFORT),
    ("reliable_loss_a2c", C.BUILTIN_RELIABLE),
])
def test_subscriber_reads_three_samples(scenario, data_stream):
    agent, session = new_session(scenario)
    reader = create_twist_reader(session, reliable=data_stream == C.BUILTIN_RELIABLE)
    received = []
    session.set_reader_callback(reader, received.append)
    session.read_data(reader, data_stream, max_samples=3)
    session.flush()
    deadline = time.monotonic() + 3
    while len(received) < 3 and time.monotonic() < deadline:
        session.spin_once(50)
    assert received == [twist_bytes(scenario, i) for i in range(3)]
    assert session.delete(attempts=1)
    assert_same_traffic(agent)


def test_lost_write_recovered_by_heartbeat():
    agent, session = new_session("reliable_loss_c2a")
    _, writer = create_twist_writer(session)
    for i in range(3):
        session.write(writer, twist_bytes("reliable_loss_c2a", i))
        assert session.run_until_confirm_delivery(1000)
    assert session.delete(attempts=1)
    assert_same_traffic(agent)


@pytest.mark.parametrize("scenario,length", [("fragment_reliable", 1500), ("string_1k_body_reliable", 1019)])
def test_large_string_is_fragmented_like_the_c_client(scenario, length):
    agent, session = new_session(scenario)
    _, writer = create_string_writer(session)
    pattern = "abcdefghijklmnopqrstuvwxyz"
    text = ("#1 " + (pattern * 100)[3:])[:length]
    body = (length + 1).to_bytes(4, "little") + text.encode() + b"\x00"
    assert session.write(writer, body)
    assert session.run_until_confirm_delivery(1000)
    assert session.delete(attempts=1)
    assert_same_traffic(agent)


def create_string_writer(session):
    participant = session.create_participant(0, "xrce_probe", object_id=0x11, flags=C.FLAG_REPLACE)
    topic = session.create_topic(participant, "rt/chatter", "std_msgs::msg::dds_::String_",
                                 object_id=0x12, flags=C.FLAG_REPLACE)
    publisher = session.create_publisher(participant, object_id=0x13, flags=C.FLAG_REPLACE)
    writer = session.create_datawriter(publisher, topic, session.endpoint_qos(True, True, 10),
                                       object_id=0x15, flags=C.FLAG_REPLACE)
    assert session.run_until_all_status(1000)
    return participant, writer


def test_discovery():
    agent = ScriptedAgent(CAPTURES["discovery"])
    found = discover_agents(agent, attempts=5, period_ms=30)
    assert (b"\x7f\x00\x00\x01", 8888) in found
    assert_same_traffic(agent)
