"""Hostile network (issue 26, the engine's rows; issue 21, reliable streams under a parked client).

Live (a real agent process on loopback, raw datagrams from the test, ``bench/hostile/network.py``
at suite size): the robot gets in after a CREATE_CLIENT flood; at most one reply, no larger than
the request, per datagram from an unknown session or to the discovery port; agent RSS bounded by
the memory budget under a mixed flood and the strangers' sessions expired afterwards; another
client's ping during a CREATE storm.

In process (the engine with CED behind it): a parked client's reliable stream loses nothing; a
nested FRAGMENT is rejected without recursion and the messages behind it survive; the budget holds
per client and in all.
"""

import sys
from pathlib import Path

from engine_peer import BIN, Clock, Link, Peer
from ros_helpers import ros_domain  # noqa: F401
from xrce.wire import constants as C
from xrce.agent.middleware.ced import CedMiddleware
from xrce.agent.engine.agent import Agent
from xrce.agent.engine.inbound import MAX_PARKED_MESSAGES
from xrce.agent.middleware import TypeNotReady
from xrce.wire.objects import DataWriterBin, EndpointQos, ParticipantBin, PubSubBin, TopicBin
from xrce.wire.streams import OutputReliableStream
from xrce.wire.submessages import Create, Fragment, Heartbeat, WriteData, decode_message, encode_message

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from bench.hostile import network as hostile_network  # noqa: E402

MIB = 1024 * 1024


# ------------------------------------------------------------------------------------ live

def test_robot_admitted_after_a_create_client_flood():
    result = hostile_network.lockout()
    print(result)
    # Before: ERR_RESOURCES (0x87) for the robot, kept out by ~34 datagrams/s.
    assert result["robot_admitted"] and result["robot_create_status"] == C.STATUS_OK, result
    assert result["robot_entities_ok"], result


def test_at_most_one_reply_per_unknown_session_datagram():
    result = hostile_network.amplification()
    print(result)
    for case in ("get_info", "delete_client", "discovery"):
        row = result[case]
        # Before: 5000 replies, 2.2-4.3x the request's bytes.
        assert row["replies"] <= 1 and row["reply_bytes"] <= row["request_bytes"], result


def test_memory_budget_holds_under_a_mixed_flood_and_strangers_expire():
    budget = 32 * MIB
    result = hostile_network.memory(seconds=20.0, dead_time_ms=1500, max_memory=budget)
    print(result)
    assert result["agent_alive"], result
    assert result["keys"] >= 20, result  # the flood did run (each key is ~2000 datagrams)
    # Before: +140 MB per 1.2 s, never freed. The budget plus the interpreter's own slack
    # (datagram buffers, allocator rounding) on a loaded box.
    assert result["rss_peak_kib"] - result["rss_before_kib"] < (budget + 24 * MIB) // 1024, result
    assert result["budget_refused"] > 0, result  # the budget was what bounded it
    assert result["clients_after"] == 0 and result["expired"] >= 1, result
    # Back to baseline: the expired sessions' bytes and the heap pages behind them given back.
    assert result["rss_after_kib"] - result["rss_before_kib"] < 8 * MIB // 1024, result


def test_another_clients_ping_during_a_create_storm(ros_domain):  # noqa: F811
    # -m dds: each CREATE is a ROS entity. Before: the storm ran under the engine lock in one go
    # (issue 26 measured p99 40 ms); now each CREATE gives the loop a turn.
    result = hostile_network.storm(agent_args=("-m", "dds"), creates=100, domain_id=ros_domain,
                                   rounds=2)
    print(result)
    assert result["all_ok"], result
    # A generous bound for a loaded 2-core box; bench/hostile/network.py --rows storm prints
    # p50/p99/max beside the idle figures for a same-run comparison.
    assert result["ping_ms_p99"] < 50, result


# ------------------------------------------------------------------------------ in process

class SlowTypeMiddleware(CedMiddleware):
    """CED whose ``slow::`` topics wait for a build the test finishes; records what is written."""

    def __init__(self):
        super().__init__()
        import concurrent.futures
        self.build = concurrent.futures.Future()
        self.written = []

    def create_topic(self, key, participant, topic):
        if topic.type_name.startswith("slow::") and not self.build.done():
            raise TypeNotReady("slow is being built", self.build)
        return super().create_topic(key, participant, topic)

    def writer(self, key):
        def write(sample):
            self.written.append(bytes(sample))
            return True
        return write


class ReliableSender:
    """A client's reliable output stream 0x80: a window of 16, retransmission of what the agent's
    ACKNACKs name missing, HEARTBEATs while anything is unacknowledged."""

    def __init__(self, peer):
        self.peer = peer
        self.state = OutputReliableStream(0x80, 16)
        self.statuses = []

    def offer(self, *payloads):
        seq = self.state.next_seq()
        if seq is None:
            return False
        message = encode_message(self.peer.session_id, 0x80, seq, self.peer.header_key,
                                 list(payloads))
        self.state.commit(seq, message)
        self.peer.raw(message)
        return True

    def pump(self):
        for raw in self.peer.take_raw():
            _, payloads = decode_message(raw)
            for payload in payloads:
                if payload.ID == C.ACKNACK and payload.stream_id == 0x80:
                    for message in self.state.on_acknack(payload.first_unacked,
                                                         payload.nack_bitmap):
                        self.peer.raw(message)
                elif payload.ID == C.STATUS:
                    self.statuses.append(payload.status)
        span = self.state.heartbeat()
        if span is not None:
            self.peer.send(0, Heartbeat(span[0], span[1], 0x80))


def test_a_parked_clients_reliable_stream_loses_nothing():
    # Before: 1000 reliable samples behind a CREATE waiting for its type build -> 511 delivered,
    # 489 acknowledged and dropped (a parked queue of 512).
    middleware = SlowTypeMiddleware()
    agent = Agent(middleware)
    agent.clock = Clock()
    peer = Peer(agent, Link(), "board")
    assert peer.connect()[1] == C.STATUS_OK
    sender = ReliableSender(peer)
    qos = EndpointQos(C.QOS_KEEP_LAST | C.QOS_RELIABLE, 10)
    setup = [Create(1, 0x0011, C.OBJK_PARTICIPANT, BIN, ParticipantBin("p"), 0, 1),
             Create(2, 0x0012, C.OBJK_TOPIC, BIN, TopicBin("rt/slow", "slow::msg::dds_::T_"),
                    0x0011, 1),
             Create(3, 0x0013, C.OBJK_PUBLISHER, BIN, PubSubBin(), 0x0011, 1),
             Create(4, 0x0015, C.OBJK_DATAWRITER, BIN, DataWriterBin(0x0012, qos), 0x0013, 1)]
    for create in setup:
        assert sender.offer(create)
    samples = [b"\x04\x00\x00\x00%04d" % i for i in range(1000)]
    sent = 0
    most_parked = 0
    for turn in range(20000):
        while sent < len(samples) and sender.offer(WriteData(0x100 + sent, 0x0015,
                                                             samples[sent])):
            sent += 1
        sender.pump()
        client = agent.clients[peer.key]
        most_parked = max(most_parked, len(client.parked or ()))
        if turn == 300:
            middleware.build.set_result(None)  # the build ends while the board keeps writing
        agent.tick()
        if len(middleware.written) == len(samples) and not sender.state.pending():
            break
    assert middleware.written == samples  # all, in order
    assert most_parked <= MAX_PARKED_MESSAGES + 16
    assert agent.stats.budget_refused > 0  # the stream stopped advancing instead of dropping
    assert sender.statuses.count(C.STATUS_OK) == 4
    client = agent.clients[peer.key]
    assert client.parked is None
    # What it still holds is the agent's unacknowledged STATUS replies, and nothing else.
    assert client.buffered == client.stream_bytes() == agent.buffered_total


def _nested_fragments(levels):
    """A FRAGMENT (last) whose bytes are a FRAGMENT (last) whose bytes are … ``levels`` deep."""
    inner = bytes((C.WRITE_DATA, 1, 6, 0, 0, 1, 0, 0x15, 1, 2))
    for _ in range(levels):
        inner = bytes((C.FRAGMENT, C.FLAG_LITTLE_ENDIAN | C.FLAG_LAST_FRAGMENT,
                       len(inner) & 0xFF, len(inner) >> 8)) + inner
    return inner


def test_nested_fragments_are_rejected_and_the_messages_behind_survive(ced_agent):
    # Before: 2000 nested FRAGMENTs in one datagram -> RecursionError, and the reliable
    # messages popped from the stream behind it were lost.
    agent, link = ced_agent
    peer = Peer(agent, link, ("h", 9))
    peer.connect()
    peer.build_pubsub()
    client = agent.clients[peer.key]
    first = peer.seqs[0x80]
    nested = encode_message(0x81, 0x80, (first + 1) & 0xFFFF, None, [])[:4] + \
        _nested_fragments(2000)
    written = agent.stats.samples_in
    peer.raw(nested)  # out of order: stored behind the missing one
    peer.send(0x80, WriteData(0x300, 0x0015, b"\x02\x00\x00\x00a\x00"), seq=(first + 2) & 0xFFFF)
    peer.send(0x80, WriteData(0x301, 0x0015, b"\x02\x00\x00\x00b\x00"), seq=first)
    assert agent.stats.nested_fragments == 1
    assert agent.stats.handler_errors == 0
    assert agent.stats.samples_in - written == 2  # both messages around it were delivered
    assert client.in_reliable[0x80].last_handled == (first + 2) & 0xFFFF
    assert not client.reassembly


def test_the_budget_holds_per_client_and_in_all():
    agent = Agent(CedMiddleware(), max_client_bytes=2 * MIB, max_total_bytes=5 * MIB)
    agent.clock = Clock()
    link = Link()
    payload = bytes(60000)
    peers = [Peer(agent, link, ("h", i), key=bytes((9, 9, 9, i))) for i in range(4)]
    for peer in peers:
        peer.connect()
        for stream_id in range(0x80, 0x100):
            for seq in range(1, 16):  # out of order: stored, never deliverable
                peer.send(stream_id, WriteData(1, 0x15, payload), seq=seq)
            peer.send(stream_id, Fragment(payload, 1), seq=0)  # a chain that never ends
        client = agent.clients[peer.key]
        assert client.buffered <= 2 * MIB
        assert client.buffered == client.stream_bytes()  # the accounting matches the buffers
    assert agent.buffered_total <= 5 * MIB
    assert agent.stats.budget_refused > 4 * 128
    # The strangers go quiet: past the dead time their sessions (no objects) expire, and every
    # byte they held is given back.
    agent.clock.now += agent.client_dead_time + 1
    agent.tick()
    assert not agent.clients and agent.buffered_total == 0 and agent.queued_total == 0
