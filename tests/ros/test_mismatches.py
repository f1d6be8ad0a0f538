"""Mismatches that silently lose data, named (issue 38): a real agent process, real rclpy peers
and real sockets. A board's best-effort publisher beside a reliable ROS subscription, a ROS
publisher whose type differs from the board's subscription, and samples from ROS larger than the
board's stream can carry each give ONE WARNING naming the board (key and address), the topic,
both sides and the fix, counted in the stats."""

from __future__ import annotations

import contextlib
import re
import time

from rclpy.qos import QoSProfile, ReliabilityPolicy

from agent_process import AgentProcess
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from xrce.wire import constants as C
from xrce.agent.observe.stats_view import fetch_stats, format_snapshot
from xrce.client.session import Session
from xrce.msgs.std_msgs import String
from xrce.wire.stream_payloads import AckNack, Heartbeat
from xrce.wire.submessages import decode_message, encode_message
from xrce.transports.udp import UdpTransport


def stats_port(agent):
    return int(re.search(r"stats on 127\.0\.0\.1:(\d+)", agent.banner).group(1))


def warnings(agent, what):
    return [line for line in "".join(agent.output).splitlines()
            if "WARNING" in line and what in line]


def mismatches(port):
    return fetch_stats(port)["agent"]["mismatches"]


def keep_alive_until(session, predicate, timeout_s=20.0):
    deadline = time.monotonic() + timeout_s
    while not predicate() and time.monotonic() < deadline:
        session.run_until_timeout(100)
    return predicate()


@contextlib.contextmanager
def board(agent, domain_id, name, **session_options):
    """A board's session with its participant: (session, participant id); closed after."""
    session = Session(UdpTransport("127.0.0.1", agent.port), history=8, **session_options)
    try:
        assert session.create(attempts=5, timeout_ms=1000)
        yield session, session.create_participant(domain_id=domain_id, name=name)
    finally:
        session.close()


def test_best_effort_board_publisher_and_reliable_ros_subscription(ros_peer, ros_domain):  # noqa: F811
    from std_msgs.msg import String as RosString

    with AgentProcess("udp4", "-m", "dds", "--stats-port", "0") as agent:
        port = stats_port(agent)
        with board(agent, ros_domain, "sensor_board") as (session, node):
            session.create_writer(node, "/chatter", String, reliable=False)
            assert session.run_until_all_status(5000), session.last_statuses
            # The ROS side asks for reliable delivery: no sample of the board's ever reaches it.
            ros_peer.node.create_subscription(
                RosString, "/chatter", lambda _m: None,
                QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
            assert keep_alive_until(session, lambda: mismatches(port) >= 1), fetch_stats(port)
            # More ROS activity on the topic: still one line for this pair.
            ros_peer.node.create_publisher(RosString, "/chatter", 10)
            session.run_until_timeout(1500)
            snapshot = fetch_stats(port)
            assert snapshot["agent"]["mismatches"] == 1
            row = snapshot["clients"][0]
            key = session.key.hex()
            assert row["key"] == key
            writer = [e for e in row["endpoints"] if e["kind"] == "datawriter"]
            assert len(writer) == 1 and len(writer[0]["mismatches"]) == 1, writer
            named = writer[0]["mismatches"][0]
            view = format_snapshot(snapshot)
            assert "mismatches 1" in view and "mismatches:\n  client %s: %s" % (key, named) in view
            session.delete(attempts=2, timeout_ms=500)
        assert agent.stop() == 0
    lines = warnings(agent, "incompatible QoS")
    assert len(lines) == 1, lines
    line = lines[0]
    assert re.search(r"client %s at udp4 127\.0\.0\.1:\d+, datawriter 0x[0-9A-F]{3}\(5\): "
                     r"/chatter: " % key, line), line
    assert line.endswith(named)
    assert "the board's publisher is best_effort, volatile, depth 10" in line, line
    assert "the ROS subscription of node /xrce_test_peer is reliable, volatile;" in line, \
        line
    assert "fix: make the ROS subscription best-effort (qos_profile_sensor_data) or the " \
        "board's publisher reliable" in line, line


def test_a_ros_publisher_of_another_type_on_the_boards_topic(ros_peer, ros_domain):  # noqa: F811
    from std_msgs.msg import Int32

    with AgentProcess("udp4", "-m", "dds", "--stats-port", "0") as agent:
        port = stats_port(agent)
        with board(agent, ros_domain, "display_board") as (session, node):
            session.create_reader(node, "/status", String, lambda _m: None)
            assert session.run_until_all_status(5000), session.last_statuses
            ros_peer.node.create_publisher(Int32, "/status", 10)
            assert keep_alive_until(session, lambda: mismatches(port) >= 1), fetch_stats(port)
            session.run_until_timeout(1000)
            assert mismatches(port) == 1
            session.delete(attempts=2, timeout_ms=500)
        assert agent.stop() == 0
    lines = warnings(agent, "type mismatch")
    assert len(lines) == 1, "".join(agent.output)
    assert re.search(r"client %s at udp4 127\.0\.0\.1:\d+, datareader 0x[0-9A-F]{3}\(6\): /status: "
                     r"type mismatch, nothing matches: the board's subscription has type "
                     r"std_msgs/msg/String, the ROS publisher of node /xrce_test_peer has "
                     r"std_msgs/msg/Int32; fix: " % session.key.hex(), lines[0]), lines[0]


# ------------------------------------------------------------------ samples too large for a board

class CClientReliableInput:
    """A board's reliable input stream as eProsima's C client keeps it (input_reliable_stream.c):
    ``history`` slots; a FRAGMENT is stored in its slot and nothing is handed on until the last
    fragment of the message is in; a message beyond ``last_handled + history`` is dropped (only
    remembered as announced). ACKNACK: the first message not handled, and a bit for every
    announced one it has no slot filled for."""

    def __init__(self, last_handled: int, history: int):
        self.last_handled = last_handled
        self.last_announced = last_handled
        self.history = history
        self.slots = {}  # seq -> (is a fragment, is the last one)
        self.samples = 0

    def receive(self, seq: int, fragment: bool, last: bool) -> None:
        if 0 < (seq - self.last_handled) % 0x10000 <= self.history and seq not in self.slots:
            if not fragment and seq == (self.last_handled + 1) % 0x10000:
                self.last_handled = seq
                self.samples += 1
            else:
                self.slots[seq] = (fragment, last)
                self._complete()
        if 0 < (seq - self.last_announced) % 0x10000 < 0x8000:
            self.last_announced = seq

    def _complete(self) -> None:
        seq = (self.last_handled + 1) % 0x10000
        while seq in self.slots:
            if self.slots[seq][1]:  # the last fragment: the message is whole
                for done in range(self.last_handled + 1, seq + 1):
                    self.slots.pop(done % 0x10000, None)
                self.last_handled = seq
                self.samples += 1
                return
            seq = (seq + 1) % 0x10000

    def acknack(self, stream_id: int) -> AckNack:
        first = (self.last_handled + 1) % 0x10000
        bitmap = 0
        for i in range(min(16, (self.last_announced - self.last_handled) % 0x10000)):
            if (first + i) % 0x10000 not in self.slots:
                bitmap |= 1 << i
        return AckNack(first, bitmap, stream_id)


def run_as_c_client(session, stream: CClientReliableInput, until, timeout_s=20.0) -> bool:
    """The board's side of its session from now on, as the C client with a short stream."""
    sock = session.transport._sock
    sock.settimeout(0.1)
    deadline = time.monotonic() + timeout_s
    while not until() and time.monotonic() < deadline:
        try:
            data = sock.recv(65536)
        except OSError:
            continue
        header, payloads = decode_message(data)
        if header.stream_id == session.reliable:
            fragment = data[header.size] == C.FRAGMENT
            last = fragment and bool(data[header.size + 1] & C.FLAG_LAST_FRAGMENT)
            stream.receive(header.seq, fragment, last)
        elif header.stream_id == C.STREAM_NONE and any(
                isinstance(p, Heartbeat) and p.stream_id == session.reliable for p in payloads):
            heartbeat = next(p for p in payloads if isinstance(p, Heartbeat))
            if 0 < (heartbeat.last_unacked - stream.last_announced) % 0x10000 < 0x8000:
                stream.last_announced = heartbeat.last_unacked
        else:
            continue
        key = session.key if session.session_id < 0x80 else None
        sock.send(encode_message(session.session_id, C.STREAM_NONE, 0, key,
                                 [stream.acknack(session.reliable)]))
    return until()


def test_ros_samples_larger_than_the_boards_stream(ros_peer, ros_domain):  # noqa: F811
    """A reliable reader whose stream holds 4 fragments (rmw_microxrcedds' default history) gets
    a 3000-byte String (7 fragments with MTU 512): the stream is stuck for good, as with
    eProsima's agent; a best-effort reader gets a sample larger than its MTU: dropped each time.
    One WARNING each, naming the board, the topic, the sizes and the fix."""
    from std_msgs.msg import String as RosString

    with AgentProcess("udp4", "-m", "dds", "--stats-port", "0") as agent:
        port = stats_port(agent)
        with board(agent, ros_domain, "small_board", mtu=512) as (session, node):
            session.create_reader(node, "/big_command", String, lambda _m: None, reliable=True)
            session.create_reader(node, "/big_status", String, lambda _m: None, reliable=False)
            assert session.run_until_all_status(5000), session.last_statuses
            reliable = ros_peer.node.create_publisher(
                RosString, "/big_command",
                QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
            best_effort = ros_peer.node.create_publisher(
                RosString, "/big_status",
                QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
            assert wait_until(lambda: reliable.get_subscription_count() >= 1
                              and best_effort.get_subscription_count() >= 1, 15)
            stream = CClientReliableInput(session._inputs[session.reliable].last_handled, 4)
            for _ in range(2):
                reliable.publish(RosString(data="x" * 3000))
            # Best-effort samples sent right after matching may be lost in DDS: sent until the
            # agent has dropped some (each one it gets is dropped).
            sent = []

            def both_named():
                agent_stats = fetch_stats(port)["agent"]
                if agent_stats["oversize_dropped"] < 2 and len(sent) < 100:
                    best_effort.publish(RosString(data="x" * 3000))
                    sent.append(1)
                return agent_stats["mismatches"] >= 2 and agent_stats["oversize_dropped"] >= 2

            assert run_as_c_client(session, stream, both_named), \
                ({k: v for k, v in fetch_stats(port)["agent"].items()
                  if k in ("mismatches", "oversize_dropped")}, stream.__dict__)
            run_as_c_client(session, stream, lambda: False, timeout_s=1.5)  # nothing more said
            snapshot = fetch_stats(port)
            assert snapshot["agent"]["mismatches"] == 2 and stream.samples == 0
            assert snapshot["agent"]["oversize_dropped"] >= 2  # every best-effort one
        assert agent.stop() == 0
    head = r"client %s at udp4 127\.0\.0\.1:\d+, datareader 0x[0-9A-F]{3}\(6\): " % session.key.hex()
    for topic, reason in (
            ("/big_command", r"its reliable stream holds 4 fragments of at most \d+ bytes .* fix: "
                             r"raise the board's stream history or MTU"),
            ("/big_status", r"it reads on a best-effort stream, which carries one message of at "
                            r"most \d+ bytes .*fix: read it with a reliable subscription")):
        lines = warnings(agent, topic + ": ")
        assert len(lines) == 1, "".join(agent.output)
        assert re.search(head + topic + r": a 30\d\d-byte sample from ROS cannot reach the "
                         r"board: " + reason, lines[0]), lines[0]
