"""Agent engine: sessions (XRCE-WIRE.md §3, §9, §10): CREATE_CLIENT and its checks, a client key
met again on the same or another session or endpoint, keyed sessions, GET_INFO, TIMESTAMP,
deleting the client, and hostile bytes that must not disturb another session."""

from hypothesis import HealthCheck, given, settings, strategies as st

from engine_peer import BIN, REUSE, XML, Clock, Link, Peer, data_of
from xrce.wire import constants as C
from xrce.agent.middleware.ced import CedMiddleware
from xrce.agent.engine.agent import Agent
from xrce.agent.engine.output import TRACE
from xrce.wire.objects import ParticipantBin
from xrce.wire.submessages import (
    AckNack, Create, CreateClient, DeliveryControl, Delete, Fragment, GetInfo, Heartbeat, ReadData,
    Timestamp, WriteData, encode_message,
)


def test_same_key_same_session_keeps_entities_and_restarts_streams(ced_agent):
    agent, link = ced_agent
    peer = Peer(agent, link, ("h", 1))
    peer.connect()
    peer.build_pubsub()
    assert peer.connect()[1] == C.STATUS_OK
    assert len(agent.middleware.writers) == 1
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, ParticipantBin("p"), flags=REUSE) == \
        C.STATUS_OK_MATCHED
    # The agent's reliable output restarted at seq 0.
    assert agent.clients[peer.key].out_reliable[0x80].last_sent == 0


def test_same_key_other_session_replaces_client(ced_agent):
    agent, link = ced_agent
    peer = Peer(agent, link, ("h", 1))
    peer.connect()
    peer.build_pubsub()
    peer.session_id = 0x82
    assert peer.connect()[1] == C.STATUS_OK
    mw = agent.middleware
    assert not mw.participants and not mw.writers and not mw.readers
    assert agent.clients[peer.key].session_id == 0x82


def test_endpoint_rebound_to_another_key_deletes_old_client(ced_agent):
    agent, link = ced_agent
    old = Peer(agent, link, ("h", 1), key=b"\x01\x01\x01\x01")
    old.connect()
    old.build_pubsub()
    new = Peer(agent, link, ("h", 1), key=b"\x02\x02\x02\x02")
    assert new.connect()[1] == C.STATUS_OK
    assert b"\x01\x01\x01\x01" not in agent.clients
    assert not agent.middleware.writers


def test_create_client_checks(ced_agent):
    agent, link = ced_agent
    peer = Peer(agent, link, ("h", 1), key=b"\x00\x00\x00\x00")
    assert peer.connect()[1] == C.STATUS_ERR_INVALID_DATA
    peer = Peer(agent, link, ("h", 2))
    peer.raw(encode_message(0x80, 0, 0, None, [CreateClient(peer.key, cookie=b"XRCF")]))
    assert peer.take()[0][1][0].status == C.STATUS_ERR_INVALID_DATA
    peer.raw(encode_message(0x80, 0, 0, None, [CreateClient(peer.key, version=b"\x02\x00")]))
    assert peer.take()[0][1][0].status == C.STATUS_ERR_INCOMPATIBLE
    assert not agent.clients
    # A header session id other than 0x00/0x80 is not a CREATE_CLIENT the agent answers.
    peer.raw(encode_message(0x81, 0, 0, None, [CreateClient(peer.key)]))
    assert peer.take() == []


def test_keyed_session(ced_agent):
    agent, link = ced_agent
    peer = Peer(agent, link, ("h", 1), key=b"\xaa\xbb\xcc\xdd", session_id=0x01)
    header, status = peer.connect()
    assert status == C.STATUS_OK and header.session_id == 0x01 and header.key == b"\xaa\xbb\xcc\xdd"
    # Keyed clients are found by key, whatever endpoint the message comes from.
    peer.endpoint = ("elsewhere", 9)
    peer.send(0x80, Create(0x50, 0x0011, C.OBJK_PARTICIPANT, BIN, ParticipantBin("x"), 0))
    peer.endpoint = ("h", 1)
    messages = peer.take()
    assert [(h.session_id, h.key, ps[0].ID) for h, ps in messages] == [
        (0x01, b"\xaa\xbb\xcc\xdd", C.STATUS), (0x01, b"\xaa\xbb\xcc\xdd", C.ACKNACK)]


def test_keyed_session_from_outside_allow_from_is_dropped_before_lookup(ced_agent, caplog):
    """With --allow-from, a keyed client is still found by key from any allowed source (as
    eProsima's agent finds it), but a datagram from outside the list never reaches it: a
    stranger's WRITE_DATA and DELETEs naming its key are counted and dropped, logged sparingly."""
    from xrce.agent.allow_lists import parse_networks
    from xrce.agent.engine.admission import AdmissionPolicy
    agent, link = ced_agent
    agent.admission = AdmissionPolicy(networks=parse_networks("10.0.0.0/24"))
    board = Peer(agent, link, ("10.0.0.5", 2019), key=b"\xaa\xbb\xcc\xdd", session_id=0x01)
    assert board.connect()[1] == C.STATUS_OK
    board.build_pubsub()
    stranger = Peer(agent, link, ("10.9.9.9", 2019), key=board.key, session_id=0x01)
    heard = agent.clients[board.key].messages_in
    with caplog.at_level("WARNING", logger="xrce.agent.admission"):
        for _ in range(20):
            stranger.send(0x01, WriteData(0x60, 0x0015, b"\x05\x00\x00\x00evil"), seq=0x100)
            stranger.send(0, Delete(0x61, 0x0015))
            stranger.send(0, Delete(0x62, C.OBJECTID_CLIENT))
    assert stranger.take() == [] and board.take() == []
    assert agent.stats.sources_refused == 60 and agent.stats.samples_in == 0
    client = agent.clients[board.key]
    assert 0x0015 in client.objects and client.messages_in == heard
    drops = [r for r in caplog.records if "not in --allow-from" in r.getMessage()]
    assert 1 <= len(drops) <= 5 and "session 0x01 from test 10.9.9.9:2019" in drops[0].getMessage()
    # Another allowed address with the key is the board's (a second socket, NAT): accepted.
    board.endpoint = ("10.0.0.6", 3000)
    board.send(0, Delete(0x63, 0x0016))
    assert 0x0016 not in client.objects and agent.stats.sources_refused == 60
    # A CREATE_CLIENT from outside still gets its ERR_DENIED.
    assert Peer(agent, link, ("10.9.9.9", 1), key=b"\x01\x02\x03\x04").connect()[1] == \
        C.STATUS_ERR_DENIED


def test_unknown_client_only_delete_and_get_info_answered(ced_agent):
    agent, link = ced_agent
    stranger = Peer(agent, link, ("h", 7))
    stranger.send(0x80, Create(0x50, 0x0011, C.OBJK_PARTICIPANT, BIN, ParticipantBin("x"), 0))
    stranger.send(0x80, WriteData(0x51, 0x0015, b"abc"))
    assert stranger.take() == []
    stranger.raw(encode_message(0x81, 0, 0, None, [Delete(2, C.OBJECTID_CLIENT)]))
    stranger.raw(encode_message(0x81, 0, 0, None, [GetInfo()]))
    (h1, (status,)), (h2, (info,)) = stranger.take()
    assert h1.session_id == 0x81 and status.status == C.STATUS_OK and status.request_id == 2
    assert info.ID == C.INFO and info.impl_status == 0
    assert agent.stats.dropped == 2


def test_get_info_timestamp_and_delete_client(ced_agent):
    agent, link = ced_agent
    peer = Peer(agent, link, ("h", 1))
    peer.raw(encode_message(0x80, 0, 0, None, [GetInfo()]))
    assert peer.take()[0][1][0].impl_status == 0
    peer.connect()
    peer.raw(encode_message(0x80, 0, 0, None, [GetInfo()]))
    assert peer.take()[0][1][0].impl_status == 1  # the endpoint maps to a live session
    peer.send(0, GetInfo())
    assert peer.take()[0][1][0].impl_status == 1
    peer.send(0, Timestamp(1795341880, 706827427))
    (header, (reply,)), = peer.take()
    assert header.stream_id == 0 and reply.originate_ns == 1795341880706827427
    assert reply.transmit_ns >= reply.receive_ns > 0
    peer.build_pubsub()
    peer.send(0, Delete(2, C.OBJECTID_CLIENT))
    (header, (status,)), = peer.take()
    assert (header.stream_id, status.request_id, status.object_id) == (0, 2, C.OBJECTID_CLIENT)
    assert not agent.clients and not agent.middleware.participants


def test_trace_logging_names_submessages(ced_agent, caplog):
    agent, link = ced_agent
    peer = Peer(agent, link, ("h", 1))
    with caplog.at_level(TRACE, logger="xrce.agent"):
        peer.connect()
    assert any("CREATE_CLIENT" in r.getMessage() for r in caplog.records)
    assert any("STATUS_AGENT" in r.getMessage() for r in caplog.records)


def _seed_messages():
    seeds = [
        encode_message(0x80, 0, 0, None, [CreateClient(b"\x11\x22\x33\x44")]),
        encode_message(0x81, 0x80, 0, None, [Create(10, 0x11, 1, BIN, ParticipantBin("x"), 0)]),
        encode_message(0x81, 0x80, 1, None, [Create(11, 0x12, 2, XML, "<dds><topic>", 0x11)]),
        encode_message(0x81, 0x80, 2, None, [ReadData(12, 0x16, 0x80, DeliveryControl())]),
        encode_message(0x81, 0x01, 0, None, [WriteData(13, 0x15, b"abc")]),
        encode_message(0x81, 0x80, 3, None, [Fragment(b"\x07\x01\x20\x00\x00", 1)]),
        encode_message(0x81, 0, 0, None, [AckNack(5, 0xFFFF, 0x80), Heartbeat(0, 40, 0x80)]),
        encode_message(0x01, 0x80, 0, b"\x11\x22\x33\x44", [Delete(3, 0x11)]),
    ]
    return seeds


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.one_of(
    st.binary(max_size=80),
    st.tuples(st.sampled_from(_seed_messages()), st.lists(st.tuples(st.integers(0, 200),
                                                                    st.integers(0, 255)), max_size=6))
    .map(lambda t: bytes(_mutate(*t))),
))
def test_fuzzed_input_never_raises_or_disturbs_another_client(data):
    link = Link()
    agent = Agent(CedMiddleware())
    agent.clock = Clock()
    good = Peer(agent, link, ("good", 1))
    good.connect()
    good.build_pubsub()
    good.read(0x80, DeliveryControl())
    good.take()
    agent.receive(link, ("evil", 2), data)
    agent.receive(link, ("evil", 2), data[: len(data) // 2])
    assert agent.stats.handler_errors == 0
    good.write(b"\x03\x00\x00\x00ok\x00")
    assert data_of(good.take()) == [b"\x03\x00\x00\x00ok\x00"]


def _mutate(seed, edits):
    out = bytearray(seed)
    for position, value in edits:
        if out:
            out[position % len(out)] = value
    return out
