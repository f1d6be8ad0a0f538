"""Agent engine behaviour (XRCE-WIRE.md §1–§10, §12) through its public entry point, with CED behind it."""

import asyncio
import logging
import threading

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from xrce import constants as C
from xrce.agent.ced import CedMiddleware
from xrce.agent.engine import TRACE, Agent
from xrce.agent.xmlrep import refs_from_profiles
from xrce.objects import (
    DataReaderBin, DataWriterBin, EndpointQos, ParticipantBin, PubSubBin, ReplierBin, RequesterBin,
    TopicBin,
)
from xrce.submessages import (
    AckNack, Create, CreateClient, DeliveryControl, Delete, Fragment, GetInfo, Heartbeat, ReadData,
    Timestamp, WriteData, decode_message, encode_message,
)

BIN, XML, REF = C.REPRESENTATION_IN_BINARY, C.REPRESENTATION_AS_XML_STRING, C.REPRESENTATION_BY_REFERENCE
REUSE, REPLACE = C.FLAG_REUSE | 1, C.FLAG_REPLACE | 1


class Link:
    name = "test"

    def __init__(self):
        self.sent = []

    def send(self, endpoint, data):
        self.sent.append((endpoint, bytes(data)))


class Clock:
    def __init__(self):
        self.now = 1000.0

    def __call__(self):
        return self.now


class Peer:
    """A scripted client: numbers its streams and reads back what the agent sent it."""

    def __init__(self, agent, link, endpoint, key=b"\x5a\xa5\x3c\xc3", session_id=0x81, mtu=508):
        self.agent, self.link, self.endpoint = agent, link, endpoint
        self.key, self.session_id, self.mtu = key, session_id, mtu
        self.seqs = {}
        self.request_id = 0x40

    @property
    def header_key(self):
        return self.key if self.session_id < 0x80 else None

    def connect(self):
        self.seqs.clear()
        self.raw(encode_message(self.session_id & 0x80, 0, 0, self.header_key,
                                [CreateClient(self.key, self.session_id, self.mtu)]))
        (header, (status,)), = self.take()
        return header, status.status

    def raw(self, data):
        self.agent.receive(self.link, self.endpoint, data)

    def send(self, stream_id, *payloads, seq=None):
        if seq is None:
            seq = self.seqs.get(stream_id, 0) if stream_id else 0
            if stream_id:
                self.seqs[stream_id] = (seq + 1) & 0xFFFF
        self.raw(encode_message(self.session_id, stream_id, seq, self.header_key, list(payloads)))

    def next_request(self):
        self.request_id += 1
        return self.request_id

    def take(self):
        """Decoded messages the agent sent to this peer since the last call."""
        mine = [data for endpoint, data in self.link.sent if endpoint == self.endpoint]
        self.link.sent = [(e, d) for e, d in self.link.sent if e != self.endpoint]
        return [decode_message(data) for data in mine]

    def take_raw(self):
        mine = [data for endpoint, data in self.link.sent if endpoint == self.endpoint]
        self.link.sent = [(e, d) for e, d in self.link.sent if e != self.endpoint]
        return mine

    def statuses(self):
        return [(h.stream_id, p.request_id, p.status) for h, ps in self.take() for p in ps
                if p.ID == C.STATUS]

    def create(self, object_id, kind, fmt, representation, tail=0, flags=1, stream_id=0x80):
        request_id = self.next_request()
        self.send(stream_id, Create(request_id, object_id, kind, fmt, representation, tail, flags))
        found = [s for s in self.statuses() if s[1] == request_id]
        return found[0][2] if found else None

    def build_pubsub(self, topic="rt/chatter", reader_depth=10, reliable=True, domain=0):
        qos_flags = C.QOS_KEEP_LAST | (C.QOS_RELIABLE if reliable else 0)
        assert self.create(0x0011, C.OBJK_PARTICIPANT, BIN, ParticipantBin("p"), domain) == 0
        assert self.create(0x0012, C.OBJK_TOPIC, BIN, TopicBin(topic, "std_msgs::msg::dds_::String_"),
                           0x0011) == 0
        assert self.create(0x0013, C.OBJK_PUBLISHER, BIN, PubSubBin(), 0x0011) == 0
        assert self.create(0x0015, C.OBJK_DATAWRITER, BIN,
                           DataWriterBin(0x0012, EndpointQos(qos_flags, 10)), 0x0013) == 0
        assert self.create(0x0014, C.OBJK_SUBSCRIBER, BIN, PubSubBin(), 0x0011) == 0
        assert self.create(0x0016, C.OBJK_DATAREADER, BIN,
                           DataReaderBin(0x0012, EndpointQos(qos_flags, reader_depth)), 0x0014) == 0
        self.ack_all()

    def ack_all(self):
        """ACKNACK everything the agent has sent on 0x80 (what a well-behaved client does)."""
        stream = self.agent.clients[self.key].out_reliable.get(0x80)
        if stream is not None:
            self.send(0, AckNack((stream.last_sent + 1) & 0xFFFF, 0, 0x80))

    def read(self, stream_id=0x80, delivery=None, object_id=0x0016):
        request_id = self.next_request()
        self.send(0x80, ReadData(request_id, object_id, stream_id, delivery))
        return request_id

    def write(self, sample, stream_id=0x80, object_id=0x0015):
        self.send(stream_id, WriteData(self.next_request(), object_id, sample))


def data_of(messages):
    return [p.data for _, ps in messages for p in ps if p.ID == C.DATA]


@pytest.fixture
def setup():
    link = Link()
    agent = Agent(CedMiddleware())
    agent.clock = Clock()
    return agent, link


def test_create_reuse_replace_table(setup):
    agent, link = setup
    peer = Peer(agent, link, ("h", 1))
    assert peer.connect()[1] == C.STATUS_OK
    mw = agent.middleware
    p1, p2 = ParticipantBin("one"), ParticipantBin("two")
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, p1) == C.STATUS_OK
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, p1) == C.STATUS_ERR_ALREADY_EXISTS
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, p1, flags=REUSE) == C.STATUS_OK_MATCHED
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, p2, flags=REUSE) == C.STATUS_ERR_MISMATCH
    # A different domain (tail) is a different representation too.
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, p1, 3, flags=REUSE) == C.STATUS_ERR_MISMATCH
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, p1, flags=REUSE | REPLACE) == \
        C.STATUS_OK_MATCHED
    assert peer.create(0x0012, C.OBJK_TOPIC, BIN, TopicBin("t", "T"), 0x0011) == C.STATUS_OK
    assert (agent.clients[peer.key].key_int, 0x0012) in mw.topics
    # REUSE|REPLACE with another representation re-creates the participant and drops its children.
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, p2, flags=REUSE | REPLACE) == C.STATUS_OK
    assert not mw.topics and len(mw.participants) == 1
    # REPLACE alone always re-creates, even when identical.
    assert peer.create(0x0012, C.OBJK_TOPIC, BIN, TopicBin("t", "T"), 0x0011) == C.STATUS_OK
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, p2, flags=REPLACE) == C.STATUS_OK
    assert not mw.topics
    # The parent must exist; its kind nibble is forced (0x0010 means participant 0x0011).
    assert peer.create(0x0022, C.OBJK_TOPIC, BIN, TopicBin("t", "T"), 0x0020) == \
        C.STATUS_ERR_UNKNOWN_REFERENCE
    assert peer.create(0x0020, C.OBJK_TOPIC, BIN, TopicBin("t", "T"), 0x0010) == C.STATUS_OK
    assert 0x0022 in agent.clients[peer.key].objects  # own nibble replaced by the kind too


def test_status_stream_follows_request_stream(setup):
    agent, link = setup
    peer = Peer(agent, link, ("h", 1))
    peer.connect()
    peer.send(0x01, Create(0x50, 0x0011, C.OBJK_PARTICIPANT, BIN, ParticipantBin("x"), 0))
    assert peer.statuses() == [(0x01, 0x50, C.STATUS_OK)]
    peer.send(0x80, Create(0x51, 0x0021, C.OBJK_PARTICIPANT, BIN, ParticipantBin("y"), 0))
    assert peer.statuses() == [(0x80, 0x51, C.STATUS_OK)]
    peer.send(0, Create(0x52, 0x0031, C.OBJK_PARTICIPANT, BIN, ParticipantBin("z"), 0))
    assert peer.statuses() == [(0x01, 0x52, C.STATUS_OK)]
    peer.send(0x80, Delete(0x53, 0x0011))
    assert peer.statuses() == [(0x80, 0x53, C.STATUS_OK)]
    peer.send(0x80, Delete(0x54, 0x0011))
    assert peer.statuses() == [(0x80, 0x54, C.STATUS_ERR_UNKNOWN_REFERENCE)]


def test_same_key_same_session_keeps_entities_and_restarts_streams(setup):
    agent, link = setup
    peer = Peer(agent, link, ("h", 1))
    peer.connect()
    peer.build_pubsub()
    assert peer.connect()[1] == C.STATUS_OK
    assert len(agent.middleware.writers) == 1
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, ParticipantBin("p"), flags=REUSE) == \
        C.STATUS_OK_MATCHED
    # The agent's reliable output restarted at seq 0.
    assert agent.clients[peer.key].out_reliable[0x80].last_sent == 0


def test_same_key_other_session_replaces_client(setup):
    agent, link = setup
    peer = Peer(agent, link, ("h", 1))
    peer.connect()
    peer.build_pubsub()
    peer.session_id = 0x82
    assert peer.connect()[1] == C.STATUS_OK
    mw = agent.middleware
    assert not mw.participants and not mw.writers and not mw.readers
    assert agent.clients[peer.key].session_id == 0x82


def test_endpoint_rebound_to_another_key_deletes_old_client(setup):
    agent, link = setup
    old = Peer(agent, link, ("h", 1), key=b"\x01\x01\x01\x01")
    old.connect()
    old.build_pubsub()
    new = Peer(agent, link, ("h", 1), key=b"\x02\x02\x02\x02")
    assert new.connect()[1] == C.STATUS_OK
    assert b"\x01\x01\x01\x01" not in agent.clients
    assert not agent.middleware.writers


def test_create_client_checks(setup):
    agent, link = setup
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


def test_keyed_session(setup):
    agent, link = setup
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


def test_unknown_client_only_delete_and_get_info_answered(setup):
    agent, link = setup
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


def test_get_info_timestamp_and_delete_client(setup):
    agent, link = setup
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


def test_failing_submessage_stops_the_rest_of_the_message(setup):
    agent, link = setup
    peer = Peer(agent, link, ("h", 1))
    peer.connect()
    peer.send(0x80, WriteData(0x50, 0x0995, b"nobody"),
              Create(0x51, 0x0011, C.OBJK_PARTICIPANT, BIN, ParticipantBin("x"), 0))
    assert peer.statuses() == []
    assert not agent.clients[peer.key].objects


def test_delete_cascades_to_children(setup):
    agent, link = setup
    peer = Peer(agent, link, ("h", 1))
    peer.connect()
    peer.build_pubsub()
    peer.send(0x80, Delete(0x70, 0x0011))
    assert peer.statuses() == [(0x80, 0x70, C.STATUS_OK)]
    mw = agent.middleware
    assert not (mw.participants or mw.topics or mw.groups or mw.writers or mw.readers)


def test_two_clients_exchange_data_reliable_and_best_effort(setup):
    agent, link = setup
    talker = Peer(agent, link, ("h", 1), key=b"\x01\x00\x00\x01")
    listener = Peer(agent, link, ("h", 2), key=b"\x02\x00\x00\x02")
    for peer in (talker, listener):
        peer.connect()
        peer.build_pubsub()
    request = listener.read(0x80, DeliveryControl())
    talker.write(b"\x03\x00\x00\x00hi\x00")
    talker.write(b"\x03\x00\x00\x00be\x00", stream_id=0x01)
    messages = listener.take()
    data = [(h.stream_id, p.request_id, p.object_id, p.data) for h, ps in messages for p in ps
            if p.ID == C.DATA]
    assert data == [(0x80, request, 0x0016, b"\x03\x00\x00\x00hi\x00"),
                    (0x80, request, 0x0016, b"\x03\x00\x00\x00be\x00")]
    listener.ack_all()
    request = listener.read(0x01, DeliveryControl())
    talker.write(b"\x03\x00\x00\x00ok\x00")
    (header, (data,)), = [(h, ps) for h, ps in listener.take() if ps[0].ID == C.DATA]
    assert header.stream_id == 0x01 and data.data == b"\x03\x00\x00\x00ok\x00"


def test_read_data_delivery_control(setup):
    agent, link = setup
    talker = Peer(agent, link, ("h", 1), key=b"\x01\x00\x00\x01")
    listener = Peer(agent, link, ("h", 2), key=b"\x02\x00\x00\x02")
    talker.connect()
    talker.build_pubsub()
    listener.connect()
    listener.build_pubsub(reader_depth=2)
    # Samples before any READ_DATA wait in a queue bounded by the reader's depth.
    for i in range(5):
        talker.write(bytes([i]))
    listener.read(0x80, DeliveryControl(max_samples=3))
    assert data_of(listener.take()) == [b"\x03", b"\x04"]
    talker.write(b"\x05")
    talker.write(b"\x06")
    assert data_of(listener.take()) == [b"\x05"]  # the third sample ends this READ_DATA
    listener.read(0x80)  # no delivery control: exactly one sample
    talker.write(b"\x07")
    assert data_of(listener.take()) == [b"\x06"]
    talker.write(b"\x08")
    assert data_of(listener.take()) == []
    listener.read(0x80, DeliveryControl())
    assert data_of(listener.take()) == [b"\x07", b"\x08"]
    listener.read(0, DeliveryControl(0, 0, 0, 0))  # uxr_buffer_cancel_data
    talker.write(b"\x09")
    assert data_of(listener.take()) == []


def test_read_data_elapsed_time_and_rate(setup):
    agent, link = setup
    clock = agent.clock
    talker = Peer(agent, link, ("h", 1), key=b"\x01\x00\x00\x01")
    listener = Peer(agent, link, ("h", 2), key=b"\x02\x00\x00\x02")
    for peer in (talker, listener):
        peer.connect()
        peer.build_pubsub()
    listener.read(0x01, DeliveryControl(max_elapsed_time=2))
    talker.write(b"a")
    clock.now += 2.5
    talker.write(b"b")
    assert data_of(listener.take()) == [b"a"]
    listener.read(0x01, DeliveryControl(max_bytes_per_second=100))
    talker.write(b"x" * 60)
    talker.write(b"y" * 60)
    assert data_of(listener.take()) == [b"b", b"x" * 60]  # "b" was queued; "y" waits for tokens
    clock.now += 0.5
    agent.tick()
    assert data_of(listener.take()) == [b"y" * 60]


def test_reliable_window_heartbeat_and_nack(setup):
    agent, link = setup
    clock = agent.clock
    talker = Peer(agent, link, ("h", 1), key=b"\x01\x00\x00\x01")
    listener = Peer(agent, link, ("h", 2), key=b"\x02\x00\x00\x02")
    talker.connect()
    talker.build_pubsub()
    listener.connect()
    listener.build_pubsub(reader_depth=40)
    listener.read(0x80, DeliveryControl())
    for i in range(20):
        talker.write(bytes([i]))
    sent = listener.take()
    assert data_of(sent) == [bytes([i]) for i in range(16)]  # window of 16, nothing acknowledged
    first_seq = [h.seq for h, ps in sent if ps[0].ID == C.DATA][0]
    clock.now += 0.2
    agent.tick()
    (header, (heartbeat,)), = listener.take()
    assert heartbeat.ID == C.HEARTBEAT and (heartbeat.first_unacked, heartbeat.last_unacked) == (
        first_seq, (first_seq + 15) & 0xFFFF)
    # NACK two of them: exactly those are resent; the acknowledged part frees room for the rest.
    listener.send(0, AckNack(first_seq + 2, 0b101, 0x80))
    resent = listener.take()
    assert [h.seq for h, _ in resent[:2]] == [first_seq + 2, first_seq + 4]
    assert data_of(resent[2:]) == [bytes([i]) for i in range(16, 18)]
    assert agent.stats.retransmissions == 2
    # A dead client gets no heartbeats; any message revives it.
    clock.now += agent.client_dead_time + 1
    agent.tick()
    assert listener.take() == []
    listener.send(0, GetInfo())
    listener.take()
    agent.tick()
    assert [ps[0].ID for _, ps in listener.take()] == [C.HEARTBEAT]


def test_reliable_input_acknack_duplicates_and_heartbeat(setup):
    agent, link = setup
    peer = Peer(agent, link, ("h", 1))
    peer.connect()
    create = Create(0x50, 0x0011, C.OBJK_PARTICIPANT, BIN, ParticipantBin("x"), 0)
    peer.send(0x80, create, seq=1)  # seq 0 lost: stored, not processed
    acks = [ps[0] for _, ps in peer.take() if ps[0].ID == C.ACKNACK]
    assert [(a.first_unacked, a.nack_bitmap) for a in acks] == [(0, 0b1)]
    peer.send(0, Heartbeat(0, 1, 0x80))
    acks = [ps[0] for _, ps in peer.take()]
    assert [(a.ID, a.first_unacked, a.nack_bitmap) for a in acks] == [(C.ACKNACK, 0, 0b1)]
    peer.send(0x80, Create(0x4F, 0x0021, C.OBJK_PARTICIPANT, BIN, ParticipantBin("y"), 0), seq=0)
    assert [s[1] for s in peer.statuses()] == [0x4F, 0x50]
    peer.send(0x80, create, seq=1)  # duplicate: acknowledged again, not processed
    (header, (ack,)), = peer.take()
    assert (ack.ID, ack.first_unacked, ack.nack_bitmap) == (C.ACKNACK, 2, 0)
    assert agent.stats.duplicates == 1


def test_fragmentation_out_at_small_mtu(setup):
    agent, link = setup
    talker = Peer(agent, link, ("h", 1), key=b"\x01\x00\x00\x01")
    listener = Peer(agent, link, ("h", 2), key=b"\x02\x00\x00\x02", mtu=64)
    for peer in (talker, listener):
        peer.connect()
        peer.build_pubsub()
    request = listener.read(0x80, DeliveryControl())
    listener.take()
    sample = bytes(range(200))
    talker.write(sample)
    raw = listener.take_raw()
    assert all(len(m) <= 64 for m in raw)
    assert [m[4] for m in raw] == [C.FRAGMENT] * len(raw)
    assert [m[5] for m in raw] == [0x01] * (len(raw) - 1) + [0x03]
    assert all(len(m) == 64 for m in raw[:-1])  # chunk = mtu - header - 4
    inner = b"".join(m[8:] for m in raw)
    assert inner[:4] == bytes((C.DATA, 1, 204, 0)) and inner[4:6] == request.to_bytes(2, "big")
    assert inner[8:] == sample
    # Best-effort output larger than the mtu is dropped and counted.
    listener.ack_all()
    listener.read(0x01, DeliveryControl())
    listener.take()
    talker.write(sample)
    assert listener.take_raw() == [] and agent.stats.oversize_dropped == 1


def test_fragment_reassembly_in(setup):
    agent, link = setup
    talker = Peer(agent, link, ("h", 1), key=b"\x01\x00\x00\x01")
    listener = Peer(agent, link, ("h", 2), key=b"\x02\x00\x00\x02", mtu=4096)
    for peer in (talker, listener):
        peer.connect()
        peer.build_pubsub()
    listener.read(0x80, DeliveryControl())
    sample = bytes(range(256)) * 5
    inner = encode_message(0x81, 0x80, 0, None, [WriteData(0x60, 0x0015, sample)])[4:]
    chunks = [inner[i:i + 500] for i in range(0, len(inner), 500)]
    base = talker.seqs[0x80]
    # Delivered out of order: the stream puts them back in sequence before reassembly.
    for index in (2, 0, 1):
        flags = 0x03 if index == len(chunks) - 1 else 0x01
        talker.send(0x80, Fragment(chunks[index], flags), seq=base + index)
    assert data_of(listener.take()) == [sample]
    # A reassembly growing past the bound is abandoned and counted.
    agent.max_reassembly_bytes = 600
    talker.seqs[0x80] = base + 3
    for index, chunk in enumerate(chunks):
        talker.send(0x80, Fragment(chunk, 0x03 if index == len(chunks) - 1 else 0x01))
    assert data_of(listener.take()) == [] and agent.stats.reassembly_overflows >= 1


def test_requester_and_replier_through_ced(setup):
    agent, link = setup
    caller = Peer(agent, link, ("h", 1), key=b"\x01\x00\x00\x01")
    server = Peer(agent, link, ("h", 2), key=b"\x02\x00\x00\x02")
    service = ("add_two_ints", "example_interfaces::srv::dds_::AddTwoInts_Request_",
               "example_interfaces::srv::dds_::AddTwoInts_Response_", "rq/add_two_intsRequest",
               "rr/add_two_intsReply")
    for peer, kind, blob in ((caller, C.OBJK_REQUESTER, RequesterBin(*service)),
                             (server, C.OBJK_REPLIER, ReplierBin("/" + service[0], *service[1:]))):
        peer.connect()
        assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, ParticipantBin("p")) == 0
        assert peer.create(0x0010 | kind, kind, BIN, blob, 0x0011) == 0
        peer.ack_all()
    server_read = server.read(0x80, DeliveryControl(), object_id=0x0018)
    caller_read = caller.read(0x80, DeliveryControl(), object_id=0x0017)
    caller.send(0x80, WriteData(0x0123, 0x0017, b"\x02" + b"\x00" * 7 + b"\x03" + b"\x00" * 7))
    (request,), = [ps for _, ps in server.take() if ps[0].ID == C.DATA]
    assert (request.request_id, request.object_id) == (server_read, 0x0018)
    identity, body = request.data[:24], request.data[24:]
    assert body == b"\x02" + b"\x00" * 7 + b"\x03" + b"\x00" * 7
    server.send(0x80, WriteData(0x0200, 0x0018, identity + b"\x05" + b"\x00" * 7))
    (reply,), = [ps for _, ps in caller.take() if ps[0].ID == C.DATA]
    assert (reply.request_id, reply.object_id) == (caller_read, 0x0017)
    # The reply carries the BaseObjectRequest of the WRITE_DATA that asked.
    assert reply.data == b"\x01\x23\x00\x17" + b"\x05" + b"\x00" * 7


def test_xml_and_reference_representations(setup, monkeypatch):
    agent, link = setup
    profiles = """<?xml version="1.0"?>
    <dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"><profiles>
      <participant profile_name="node"><domainId>7</domainId><rtps><name>ref_node</name></rtps></participant>
      <topic profile_name="chatter"><name>rt/chatter</name><dataType>std_msgs::msg::dds_::String_</dataType></topic>
      <data_writer profile_name="writer"><topic><name>rt/chatter</name><dataType>std_msgs::msg::dds_::String_</dataType>
        <historyQos><kind>KEEP_LAST</kind><depth>3</depth></historyQos></topic>
        <qos><reliability><kind>BEST_EFFORT</kind></reliability></qos></data_writer>
    </profiles></dds>"""
    agent.refs = refs_from_profiles(profiles)
    assert set(agent.refs) == {"node", "chatter", "writer"}
    peer = Peer(agent, link, ("h", 1))
    peer.connect()
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, REF, "node", 255) == C.STATUS_OK
    assert agent.middleware.participants[(peer.agent.clients[peer.key].key_int, 0x0011)] == 7
    assert peer.create(0x0012, C.OBJK_TOPIC, REF, "chatter", 0x0011) == C.STATUS_OK
    assert peer.create(0x0013, C.OBJK_PUBLISHER, XML, "", 0x0011) == C.STATUS_OK
    assert peer.create(0x0015, C.OBJK_DATAWRITER, REF, "writer", 0x0013) == C.STATUS_OK
    (writer,) = agent.middleware.writers.values()
    assert (writer.topic, writer.qos.reliable, writer.qos.depth) == ("rt/chatter", False, 3)
    assert peer.create(0x0025, C.OBJK_DATAWRITER, REF, "missing", 0x0013) == C.STATUS_ERR_DDS_ERROR
    assert peer.create(0x0035, C.OBJK_DATAWRITER, XML,
                       "<dds><data_writer><topic><name>rt/other</name></topic></data_writer></dds>",
                       0x0013) == C.STATUS_ERR_DDS_ERROR  # no such topic in the participant
    assert peer.create(0x0045, C.OBJK_DATAWRITER, XML, "<dds><data_wr", 0x0013) == \
        C.STATUS_ERR_DDS_ERROR
    assert peer.create(0x0023, C.OBJK_PUBLISHER, REF, "node", 0x0011) == C.STATUS_ERR_INVALID_DATA
    monkeypatch.setenv("XRCE_DOMAIN_ID_OVERRIDE", "42")
    assert peer.create(0x0021, C.OBJK_PARTICIPANT, XML,
                       "<dds><participant><rtps><name>n</name></rtps></participant></dds>", 255) == 0
    assert agent.middleware.participants[(agent.clients[peer.key].key_int, 0x0021)] == 42


def test_trace_logging_names_submessages(setup, caplog):
    agent, link = setup
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


def test_run_sends_heartbeats_and_close_deletes_everything():
    async def scenario():
        link = Link()
        agent = Agent(CedMiddleware(), heartbeat_period=0.02)
        peer = Peer(agent, link, ("h", 1))
        peer.connect()
        peer.build_pubsub()
        peer.send(0x80, Create(0x70, 0x0021, C.OBJK_PARTICIPANT, BIN, ParticipantBin("y"), 0))
        peer.take()
        task = asyncio.ensure_future(agent.run())
        await asyncio.sleep(0.15)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        heartbeats = [ps[0] for _, ps in peer.take() if ps[0].ID == C.HEARTBEAT]
        assert len(heartbeats) >= 3 and all(h.stream_id == 0x80 for h in heartbeats)
        await agent.close()
        assert not agent.clients and not agent.middleware.participants
    asyncio.run(asyncio.wait_for(scenario(), 5))


def test_timed_work_is_scheduled_when_due_and_nothing_runs_when_idle():
    async def scenario():
        link = Link()
        agent = Agent(CedMiddleware(), heartbeat_period=0.02, client_dead_time=0.3)
        ticks = []
        tick = agent.tick
        agent.tick = lambda: (ticks.append(agent.clock()), tick())[1]
        task = asyncio.ensure_future(agent.run())
        await asyncio.sleep(0.2)
        assert len(ticks) == 1 and agent.next_wakeup is None  # no client: no timer at all
        peer = Peer(agent, link, ("h", 1))
        peer.connect()  # a session: its dead time is due
        assert agent.next_wakeup == pytest.approx(agent.clock() + 0.3, abs=0.05)
        peer.build_pubsub()  # acknowledged output: still only the dead time
        peer.take()
        peer.read(0x80, DeliveryControl())
        peer.send(0x80, WriteData(0x60, 0x0015, b"unacknowledged"))
        assert agent.next_wakeup == pytest.approx(agent.clock() + 0.02, abs=0.01)
        await asyncio.sleep(0.1)
        heartbeats = [ps[0] for _, ps in peer.take() if ps[0].ID == C.HEARTBEAT]
        assert len(heartbeats) >= 2  # sent by the timer, nobody called tick()
        peer.ack_all()
        del ticks[:]
        await asyncio.sleep(0.1)
        assert len(ticks) <= 1 and not [1 for _, ps in peer.take() if ps[0].ID == C.HEARTBEAT]
        await asyncio.sleep(0.3)  # past the dead time: dead, and nothing more to do for it
        assert agent.stats.clients_dead == 1 and agent.next_wakeup is None
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        await agent.close()
    asyncio.run(asyncio.wait_for(scenario(), 5))


def test_best_effort_samples_take_the_short_path_with_the_same_accounting(setup):
    agent, link = setup
    talker = Peer(agent, link, ("h", 1), key=b"\x01\x00\x00\x01")
    listener = Peer(agent, link, ("h", 2), key=b"\x02\x00\x00\x02")
    for peer in (talker, listener):
        peer.connect()
        peer.build_pubsub(reliable=False)
    listener.read(0x01, DeliveryControl())
    general = []
    receive = agent._receive
    agent._receive = lambda *args: (general.append(args[2]), receive(*args))[1]
    for index in range(3):
        talker.write(bytes([index]), stream_id=0x01)
    talker.send(0x01, WriteData(0x50, 0x0015, b"stale"), seq=1)  # older than the last: dropped
    assert len(general) == 1  # only the stream's first message went the general way
    assert data_of(listener.take()) == [b"\x00", b"\x01", b"\x02"]
    writer = agent.clients[talker.key].objects[0x0015]
    assert (writer.samples, writer.sample_bytes, agent.stats.dropped) == (3, 3, 1)
    client = agent.clients[talker.key]
    assert client.messages_in == len(general) + 3 + 7  # 7 messages built the entities
    # Reliable: the next message in order goes the short way and is acknowledged; a gap does not.
    del general[:]
    base = talker.seqs[0x80]
    talker.write(b"r0")
    talker.take()
    talker.write(b"r1")
    (_, (acknack,)), = talker.take()
    assert acknack.ID == C.ACKNACK and acknack.first_unacked == (base + 2) & 0xFFFF
    talker.send(0x80, WriteData(0x51, 0x0015, b"r3"), seq=base + 3)  # r2 missing
    talker.send(0x80, WriteData(0x52, 0x0015, b"r2"), seq=base + 2)
    assert len(general) == 2 and writer.samples == 7


@settings(max_examples=200, deadline=None)
@given(session_id=st.sampled_from([0x01, 0x7F, 0x81, 0xFF]), stream_id=st.integers(0, 255),
       request_id=st.integers(0, 0xFFFF), object_id=st.integers(0, 0xFFFF),
       sample=st.binary(max_size=600))
def test_the_direct_data_encoding_is_byte_exact(session_id, stream_id, request_id, object_id,
                                               sample):
    from xrce.agent.datapath import data_message
    from xrce.submessages import Data

    class Client:
        pass
    client = Client()
    client.session_id = session_id
    client.header_key = b"\x0a\x0b\x0c\x0d" if session_id < 0x80 else None
    assert data_message(client, stream_id, request_id, object_id, sample) == encode_message(
        session_id, stream_id, 0, client.header_key, [Data(request_id, object_id, sample)])


def test_ced_routes_only_within_a_domain(setup):
    agent, link = setup
    a = Peer(agent, link, ("h", 1), key=b"\x01\x00\x00\x01")
    b = Peer(agent, link, ("h", 2), key=b"\x02\x00\x00\x02")
    a.connect()
    a.build_pubsub(domain=0)
    b.connect()
    b.build_pubsub(domain=1)
    b.read(0x80, DeliveryControl())
    a.write(b"zz")
    assert data_of(b.take()) == []
    logging.getLogger("xrce.agent").debug("domains isolated")


class SlowTypeMiddleware(CedMiddleware):
    """CED, except that topics of type ``slow::...`` need a build that finishes when told to."""

    def __init__(self):
        super().__init__()
        import concurrent.futures
        self.build = concurrent.futures.Future()

    def create_topic(self, key, participant, topic):
        if topic.type_name.startswith("slow::") and not self.build.done():
            from xrce.agent.middleware import TypeNotReady
            raise TypeNotReady("slow is being built", self.build)
        return super().create_topic(key, participant, topic)


def test_a_create_waiting_for_its_type_parks_only_its_client():
    link = Link()
    middleware = SlowTypeMiddleware()
    agent = Agent(middleware)
    agent.clock = Clock()
    waiting, other = Peer(agent, link, "waiting"), Peer(agent, link, "other", key=b"\x01\x02\x03\x04")
    assert waiting.connect()[1] == 0 and other.connect()[1] == 0
    assert waiting.create(0x0011, C.OBJK_PARTICIPANT, BIN, ParticipantBin("p"), 0) == 0
    # The topic and, in a later message, its writer's publisher: neither is answered yet.
    topic_request = waiting.next_request()
    waiting.send(0x80, Create(topic_request, 0x0012, C.OBJK_TOPIC, BIN,
                              TopicBin("rt/slow", "slow::msg::dds_::Thing_"), 0x0011, 1))
    publisher_request = waiting.next_request()
    waiting.send(0x80, Create(publisher_request, 0x0013, C.OBJK_PUBLISHER, BIN, PubSubBin(), 0x0011, 1))
    assert waiting.statuses() == []
    # Meanwhile another client is served as usual.
    other.build_pubsub("rt/fast")
    other.read()
    other.write(b"\x02\x00\x00\x00a\x00")
    assert data_of(other.take()) == [b"\x02\x00\x00\x00a\x00"]
    # The build finishes: the parked CREATE and everything queued behind it run, in order.
    middleware.build.set_result(None)
    agent.tick()
    assert waiting.statuses() == [(0x80, topic_request, 0), (0x80, publisher_request, 0)]


def test_output_queue_quota_keeps_the_newest_samples_within_the_bound():
    link = Link()
    agent = Agent(CedMiddleware(), max_output_queue_bytes=200)
    agent.clock = Clock()
    peer = Peer(agent, link, "q")
    assert peer.connect()[1] == 0
    peer.build_pubsub(reader_depth=100)
    samples = [bytes([i]) * 50 for i in range(10)]  # no READ_DATA yet: they queue for the reader
    for sample in samples:
        peer.write(sample)
    client = agent.clients[peer.key]
    assert client.queued_bytes <= 200
    assert agent.stats.quota_output_dropped == 6
    peer.take()
    peer.read(delivery=DeliveryControl(0xFFFF, 0, 0, 0))
    assert data_of(peer.take()) == samples[-4:]  # the newest that fit, oldest dropped first


class ThreadRecordingLink(Link):
    """Records which thread sent each DATA."""

    def send(self, endpoint, data):
        self.sent.append((endpoint, bytes(data)))
        if data_of([decode_message(data)]):
            self.threads.append(threading.get_ident())


@pytest.mark.parametrize("any_thread", [True, False])
async def test_samples_from_the_middleware_thread(any_thread):
    # A sample a middleware hands over on a thread of its own (RosMiddleware's executor thread)
    # goes out from that thread when the link can send from any thread (UDP), under the engine's
    # lock; otherwise (TCP, serial: asyncio transports) from the loop, in order either way.
    link = ThreadRecordingLink()
    link.threads = []
    link.sends_from_any_thread = any_thread
    agent = Agent(CedMiddleware(), loop=asyncio.get_running_loop())
    listener = Peer(agent, link, ("h", 2), key=b"\x02\x00\x00\x02")
    listener.connect()
    listener.build_pubsub()
    listener.read(0x80, DeliveryControl())
    listener.take()
    link.threads.clear()
    on_data = agent._sample_callback(agent.clients[listener.key], 0x0016)

    def middleware_thread():
        with agent.lock:  # what RosMiddleware's hand-off takes before it calls on_data
            for i in range(3):
                on_data(bytes([i]))

    thread = threading.Thread(target=middleware_thread)
    thread.start()
    thread.join(5)
    await asyncio.sleep(0.05)  # the loop's turn
    assert data_of(listener.take()) == [b"\x00", b"\x01", b"\x02"]
    loop_thread = threading.get_ident()
    assert all((sender != loop_thread) == any_thread for sender in link.threads)
    assert len(link.threads) == 3
    await agent.close()
