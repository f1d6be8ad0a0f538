"""The UDP link's compiled receive path (xrce/agent/engine/compiled/_fastpath.c, xrce/agent/engine/compiled/fastpath.py).

End to end through real agent processes, real sockets and real rclpy, once with the compiled path
and once with ``XRCE_FASTPATH=0``: both must deliver the same samples in the same order and count
the same, for in-order, stale, duplicate and Python-only datagrams on one best-effort stream, a
deleted writer and a restarted session. Then the C parser alone against hostile datagrams.
"""

import datetime
import os
import random
import time

import pytest

from agent_process import AgentProcess
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from test_observability import client_row, stats_port
from xrce.agent.observe.stats_view import fetch_stats
from xrce.client.session import Session
from xrce.msgs.geometry_msgs import Twist, Vector3
from xrce.transports.udp import UdpTransport

try:
    from xrce.agent.engine.compiled import _fastpath as fastpath
except ImportError:  # built without a compiler: only the packaging tests apply
    fastpath = None
needs_extension = pytest.mark.skipif(fastpath is None, reason="xrce.agent.engine.compiled._fastpath not built")


class CapturingTransport:
    """Keeps what the session sends instead of sending it while ``capture`` is on."""

    def __init__(self, transport):
        self.inner = transport
        self.capture = False
        self.captured = []

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def send(self, message):
        if self.capture:
            self.captured.append(bytearray(message))
            return True
        return self.inner.send(message)

    def send_from(self, buf, length):
        # The session prefers send_from: __getattr__ would otherwise give it the inner one's.
        return self.send(memoryview(buf)[:length])


def twist_datagrams(session, writer, values):
    """The exact best-effort datagram of each sample Twist(linear.x=value), not sent."""
    transport = session.transport
    transport.capture, transport.captured = True, []
    try:
        for value in values:
            session.write(writer, Twist(linear=Vector3(x=float(value))), stream_id=session.best_effort)
            session.flush()
    finally:
        transport.capture = False
    return transport.captured


def with_seq(datagram, seq):
    out = bytearray(datagram)
    out[2], out[3] = seq & 0xFF, seq >> 8
    return bytes(out)


def matched_writer(session, ros_peer, ros_domain, name, topic, message_type):  # noqa: F811
    """(node, writer): a new session's best-effort writer on ``topic``, matched by the agent's
    publisher and ``ros_peer``'s subscription."""
    assert session.create(attempts=5, timeout_ms=1000)
    node = session.create_participant(domain_id=ros_domain, name=name)
    writer = session.create_writer(node, topic, message_type, reliable=False)
    assert session.run_until_all_status(5000), session.last_statuses
    assert wait_until(lambda: ros_peer.node.count_publishers(topic) > 0, 10)
    time.sleep(0.5)  # the subscriber's matching by the agent's publisher
    return node, writer


def run_scenario(ros_peer, ros_domain, topic, env):  # noqa: F811
    """Drive one agent; returns (values received in ROS, counter deltas, agent output)."""
    received = []
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    ros_peer.node.create_subscription(Twist_ros(), topic, lambda m: received.append(m.linear.x),
                                      QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT))
    with AgentProcess("udp4", "-m", "dds", "-v", "5", "--stats-port", "0", env=env) as agent:
        port = stats_port(agent)
        session = Session(CapturingTransport(UdpTransport("127.0.0.1", agent.port)), history=8)
        try:
            node, writer = matched_writer(session, ros_peer, ros_domain, "fastpath", topic, Twist)
            before = fetch_stats(port)
            values = list(range(1, 21))
            frames = twist_datagrams(session, writer, values)
            send = session.transport.inner.send
            for seq in range(5):  # in order: the first ones take the Python path and register
                send(with_seq(frames[seq], seq))
            time.sleep(0.2)
            send(with_seq(frames[10], 10))  # a gap: best-effort takes it
            send(with_seq(frames[11], 11))
            send(with_seq(frames[15], 5))  # older: dropped
            send(with_seq(frames[16], 11))  # repeated: dropped
            unknown = bytearray(frames[17])  # a writer the client never created: Python's
            unknown[(4 if unknown[0] & 0x80 else 8) + 7] ^= 0x0F  # the object id's low byte
            send(with_seq(unknown, 12))
            send(with_seq(frames[12], 12))  # the number was used by the message before: dropped
            send(with_seq(frames[13], 13))
            for seq in range(14, 0x10010, 0x1000):  # across the 16-bit wrap, always newer
                send(with_seq(frames[14], seq & 0xFFFF))
            assert wait_until(lambda: len(received) >= 25, 10), received
            time.sleep(FOLD_WAIT_S)
            after = fetch_stats(port)

            # Deleting the writer: no publish afterwards, through any path, and the agent serves on.
            session.delete_entity(writer)
            assert session.run_until_all_status(5000)
            for seq in range(0x20, 0x28):
                send(with_seq(frames[18], seq))
            assert session.ping(timeout_ms=1000)

            # A restarted session starts its streams again at 0.
            first_part = len(received)
            assert session.create(attempts=5, timeout_ms=1000)
            writer = session.create_writer(node, topic, Twist, reliable=False)
            assert session.run_until_all_status(5000), session.last_statuses
            frames = twist_datagrams(session, writer, [100, 101, 102])
            seq = 0  # from 0 again; resent until the new publisher is matched
            # ...and until all three arrived: matching can complete in the middle of a round.
            deadline = time.monotonic() + 10
            while not {100.0, 101.0, 102.0} <= set(received[first_part:]) \
                    and time.monotonic() < deadline:
                for frame in frames:
                    send(with_seq(frame, seq))
                    seq += 1
                time.sleep(0.2)
            time.sleep(0.3)
            assert set(received[first_part:]) == {100.0, 101.0, 102.0}, received[first_part:]
            del received[first_part:]
            session.delete(attempts=2, timeout_ms=500)
        finally:
            session.close()
    output = "".join(agent.output)
    deltas = {name: after["agent"][name] - before["agent"][name]
              for name in ("messages_in", "bytes_in", "samples_in", "dropped", "decode_errors")}
    row_before, row_after = client_row(before, session), client_row(after, session)
    deltas["client_messages_in"] = row_after["messages_in"] - row_before["messages_in"]
    deltas["client_bytes_in"] = row_after["bytes_in"] - row_before["bytes_in"]
    deltas["client_last_seen_s"] = row_after["last_seen_s"]
    topic_row = [t for t in after["topics"]
                 if t["topic"].endswith(topic.lstrip("/")) and t["direction"] == "to_ros"]
    deltas["topic_samples"] = topic_row[0]["samples"] if topic_row else None
    return received, deltas, output


FOLD_WAIT_S = 1.5  # the compiled path's counters reach the stats within a second


def Twist_ros():
    from geometry_msgs.msg import Twist as RosTwist
    return RosTwist


@needs_extension
def test_compiled_and_python_paths_deliver_and_count_the_same(ros_peer, ros_domain):  # noqa: F811
    compiled = run_scenario(ros_peer, ros_domain, "/fastpath_on", {"XRCE_FASTPATH": "1"})
    python = run_scenario(ros_peer, ros_domain, "/fastpath_off", {"XRCE_FASTPATH": "0"})

    expected = [1.0, 2.0, 3.0, 4.0, 5.0, 11.0, 12.0, 14.0] + [15.0] * 17
    assert python[0] == expected
    assert compiled[0] == expected
    assert "best-effort samples take the compiled path" in compiled[2]
    assert "udp4: compiled receive path" in compiled[2]
    assert "compiled receive path" not in python[2].replace("compiled receive path off", "")
    # 5 + 2 + 2 stale + unknown writer + used number + 1 + 17 across the wrap = 29 messages.
    for deltas in (compiled[1], python[1]):
        assert deltas["messages_in"] == 29 and deltas["client_messages_in"] == 29, deltas
        assert deltas["samples_in"] == 25 and deltas["topic_samples"] == 25, deltas
        assert deltas["dropped"] == 3 and deltas["decode_errors"] == 0, deltas
        assert deltas["client_last_seen_s"] < FOLD_WAIT_S + 1.0, deltas
    assert compiled[1]["bytes_in"] == python[1]["bytes_in"] == compiled[1]["client_bytes_in"]


def liveliness_events(output, key):
    """"dead" / "alive" for each line of the agent's log saying the client died or revived."""
    return ["dead" if ": dead" in line else "alive" for line in output.splitlines()
            if key.hex() in line and (": dead" in line or "alive again" in line)]


@pytest.mark.parametrize("switch", [pytest.param("1", marks=needs_extension), "0"],
                         ids=["compiled", "python"])
def test_a_client_heard_only_through_the_compiled_path_stays_alive(ros_peer, ros_domain, switch):  # noqa: F811
    """Liveliness judges the time C last heard a client: samples that never reach Python keep it
    alive; silence makes it dead; its next sample revives it through Python and is delivered."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    received = []
    topic = "/fastpath_alive_" + switch
    ros_peer.node.create_subscription(Twist_ros(), topic, lambda m: received.append(m.linear.x),
                                      QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT))
    with AgentProcess("udp4", "-m", "dds", "-v", "5", "--client-dead-time", "400",
                      env={"XRCE_FASTPATH": switch}) as agent:
        session = Session(CapturingTransport(UdpTransport("127.0.0.1", agent.port)), history=8)
        try:
            assert session.create(attempts=5, timeout_ms=1000)
            node = session.create_participant(domain_id=ros_domain, name="alive")
            writer = session.create_writer(node, topic, Twist, reliable=False)
            assert session.run_until_all_status(5000), session.last_statuses
            assert wait_until(lambda: ros_peer.node.count_publishers(topic) > 0, 10)
            time.sleep(0.5)
            frames = twist_datagrams(session, writer, [1, 2])
            send = session.transport.inner.send
            send(with_seq(frames[0], 0))  # revives it if the set-up took longer than a dead time
            # (and the agent has said so before the window starts, however loaded the machine)
            assert wait_until(lambda: liveliness_events("".join(agent.output), session.key)[-1:]
                              != ["dead"], 10)
            time.sleep(0.1)
            sending = datetime.datetime.now()
            for seq in range(1, 61):  # 1.2 s at 50 Hz, three dead times
                send(with_seq(frames[0], seq))
                time.sleep(0.02)
            sent = datetime.datetime.now()
            time.sleep(0.9)  # silent: dead
            send(with_seq(frames[1], 61))
            assert wait_until(lambda: 2.0 in received, 5), received
            time.sleep(0.2)
        finally:
            session.close()
    output = "".join(agent.output)
    key = session.key.hex()
    events = [(datetime.datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S,%f"),
               "dead" if "dead" in line else "alive")
              for line in output.splitlines()
              if key in line and (": dead" in line or "alive again" in line)]
    assert not [e for e in events if sending <= e[0] <= sent], events  # heard all along
    assert [kind for when, kind in events if when > sent] == ["dead", "alive"], events
    assert received.count(1.0) >= 55
    if switch == "1":
        assert "best-effort samples take the compiled path" in output


PAD = b"\xee"  # padding bytes are not read: a value no String sample of the test ends with


def run_padded_scenario(ros_peer, ros_domain, topic, env):  # noqa: F811
    """PX4's client pads every datagram to a multiple of 4 bytes: best-effort String samples of
    odd CDR length, each datagram with its padding. Returns (raw CDR received in ROS, the
    CDR sent, counter deltas)."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String as RosString
    from xrce.msgs.std_msgs import String
    received = []
    ros_peer.node.create_subscription(RosString, topic, received.append,
                                      QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT),
                                      raw=True)
    with AgentProcess("udp4", "-m", "dds", "--stats-port", "0", env=env) as agent:
        port = stats_port(agent)
        session = Session(CapturingTransport(UdpTransport("127.0.0.1", agent.port)), history=8)
        try:
            _node, writer = matched_writer(session, ros_peer, ros_domain, "fastpath_padded", topic,
                                           String)
            before = fetch_stats(port)
            transport = session.transport
            transport.capture, transport.captured = True, []
            for index in range(10):  # CDR of 5 + 2 * index bytes ("s" * ..., its 0, its length)
                session.write(writer, String(data="s" * (2 * index)), stream_id=session.best_effort)
                session.flush()
            transport.capture = False
            sent = []
            for seq, frame in enumerate(transport.captured):
                start = 4 if frame[0] & 0x80 else 8
                end = start + 4 + (frame[start + 2] | frame[start + 3] << 8)
                assert end % 4, "the scenario needs unaligned samples"
                sent.append(bytes(frame[start + 8:end]))
                # (xrce.client pads as PX4's client does; padded here whatever it did)
                transport.inner.send(with_seq(bytes(frame[:end]) + PAD * (-end % 4), seq))
                if seq == 1:  # the first opens the stream, the second registers the writer
                    time.sleep(0.3)
            assert wait_until(lambda: len(received) >= 10, 10), received
            time.sleep(FOLD_WAIT_S)
            after = fetch_stats(port)
        finally:
            session.close()
    deltas = {name: after["agent"][name] - before["agent"][name]
              for name in ("messages_in", "samples_in", "dropped", "decode_errors",
                           "samples_compiled")}
    return [bytes(raw[4:]) for raw in received], sent, deltas


@pytest.mark.parametrize("switch", [pytest.param("1", marks=needs_extension), "0"],
                         ids=["compiled", "python"])
def test_padded_datagrams_as_px4_sends_them_publish_the_sample_alone(ros_peer, ros_domain, switch):  # noqa: F811
    """The padding after a datagram's one WRITE_DATA is not part of the sample, on either path;
    and such samples take the compiled path as unpadded ones do (PX4's samples and xrce.client's
    did not: the Python path's shortcut, which registers a writer with C, refused padded
    datagrams)."""
    received, sent, deltas = run_padded_scenario(ros_peer, ros_domain, "/fastpath_pad_" + switch,
                                                 {"XRCE_FASTPATH": switch})
    assert len(received) == len(sent)
    for got, cdr in zip(received, sent):
        # Fast DDS delivers the payload zero-padded to 4 bytes; a PAD byte would be the agent's
        assert got[:len(cdr)] == cdr and got[len(cdr):] == bytes(len(got) - len(cdr)), (got, cdr)
    assert deltas["messages_in"] == deltas["samples_in"] == 10, deltas
    assert deltas["dropped"] == deltas["decode_errors"] == 0, deltas
    if switch == "1":  # two samples through Python, C publishes the rest
        assert deltas["samples_compiled"] == 8, deltas
    else:
        assert deltas["samples_compiled"] == 0, deltas


def reliable_datagrams(session, writer, values):
    """The exact datagrams of Twist(linear.x=value) on the session's built-in reliable stream,
    each the next in order, not sent (the session counts them as sent)."""
    transport = session.transport
    transport.capture, transport.captured = True, []
    try:
        for value in values:
            session.write(writer, Twist(linear=Vector3(x=float(value))), stream_id=session.reliable)
            session.flush()
    finally:
        transport.capture = False
    return transport.captured


def mutate(data: bytearray, rng, times: int, longest_tail: int) -> None:
    """``times`` random damages to a datagram: a byte changed, the end cut, up to ``longest_tail``
    bytes added, or a length field claiming more or less than there is."""
    for _ in range(times):
        kind = rng.randrange(4)
        if kind == 0 and data:
            data[rng.randrange(len(data))] = rng.randrange(256)
        elif kind == 1:
            del data[rng.randrange(len(data) + 1):]
        elif kind == 2:
            data += bytes(rng.randrange(256) for _ in range(rng.randrange(1, longest_tail + 1)))
        elif len(data) > 11:
            data[10], data[11] = rng.randrange(256), rng.randrange(256)


def acknack_messages(transport, stream_id, wait_s=0.3):
    """(first_unacked, nack_bitmap, the message's bytes) of each ACKNACK of ``stream_id`` the
    agent sends within ``wait_s``."""
    from xrce.wire.submessages import AckNack, decode_message
    out = []
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline:
        data = transport.recv(max(1, int((deadline - time.monotonic()) * 1000)))
        if data is None:
            continue
        for payload in decode_message(bytes(data))[1]:
            if isinstance(payload, AckNack) and payload.stream_id == stream_id:
                out.append((payload.first_unacked, payload.nack_bitmap, bytes(data)))
    return out


def acknacks_after(transport, stream_id, wait_s=0.3):
    """(first_unacked, nack_bitmap) of each ACKNACK of ``stream_id`` the agent sends within
    ``wait_s``."""
    return [(first, bitmap) for first, bitmap, _ in acknack_messages(transport, stream_id, wait_s)]


def run_reliable_scenario(ros_peer, ros_domain, topic, env):  # noqa: F811
    """One agent, one reliable stream: in order, a gap and the retransmission filling it, a
    duplicate, in order again. Returns (values received in ROS, ACKNACKs per step, counter
    deltas, agent output)."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    received = []
    ros_peer.node.create_subscription(Twist_ros(), topic, lambda m: received.append(m.linear.x),
                                      QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    with AgentProcess("udp4", "-m", "dds", "-v", "5", "--stats-port", "0", env=env) as agent:
        port = stats_port(agent)
        session = Session(CapturingTransport(UdpTransport("127.0.0.1", agent.port)), history=16)
        try:
            assert session.create(attempts=5, timeout_ms=1000)
            node = session.create_participant(domain_id=ros_domain, name="fastpath_reliable")
            writer = session.create_writer(node, topic, Twist, reliable=True)
            assert session.run_until_all_status(5000), session.last_statuses
            assert wait_until(lambda: ros_peer.node.count_publishers(topic) > 0, 10)
            time.sleep(0.5)  # the subscriber's matching by the agent's publisher
            before = fetch_stats(port)
            frames = reliable_datagrams(session, writer, range(1, 11))
            first = frames[0][2] | frames[0][3] << 8
            inner = session.transport.inner
            acks = []
            # One datagram per step, its ACKNACKs collected before the next: the same steps give
            # the same ACKNACKs whichever path handled them.
            for index in (0, 1, 2, 4, 5, 3, 5, 6, 7, 8, 9):
                inner.send(frames[index])
                acks.append([((f - first) & 0xFFFF, bitmap)
                             for f, bitmap in acknacks_after(inner, session.reliable)])
            assert wait_until(lambda: len(received) >= 10, 10), received
            time.sleep(FOLD_WAIT_S)
            after = fetch_stats(port)
        finally:
            session.close()
    deltas = {name: after["agent"][name] - before["agent"][name]
              for name in ("messages_in", "bytes_in", "samples_in", "dropped", "duplicates",
                           "acknacks_out", "decode_errors", "samples_compiled")}
    row_before, row_after = client_row(before, session), client_row(after, session)
    deltas["client_messages_in"] = row_after["messages_in"] - row_before["messages_in"]
    deltas["client_bytes_in"] = row_after["bytes_in"] - row_before["bytes_in"]
    topic_row = [t for t in after["topics"]
                 if t["topic"].endswith(topic.lstrip("/")) and t["direction"] == "to_ros"]
    deltas["topic_samples"] = topic_row[0]["samples"] if topic_row else None
    return received, acks, deltas, "".join(agent.output)


@needs_extension
def test_reliable_stream_compiled_and_python_paths_deliver_acknowledge_and_count_the_same(
        ros_peer, ros_domain):  # noqa: F811
    compiled = run_reliable_scenario(ros_peer, ros_domain, "/fastpath_rel_on", {"XRCE_FASTPATH": "1"})
    python = run_reliable_scenario(ros_peer, ros_domain, "/fastpath_rel_off", {"XRCE_FASTPATH": "0"})

    assert python[0] == compiled[0] == [float(v) for v in range(1, 11)]
    # Relative to the first sample's number: each in-order one acknowledged; the gap (4 and 5
    # before 3) named missing; 3 fills it and all three go out; the duplicate acknowledged again.
    expected = [[(1, 0)], [(2, 0)], [(3, 0)], [(3, 0b1)], [(3, 0b1)], [(6, 0)], [(6, 0)],
                [(7, 0)], [(8, 0)], [(9, 0)], [(10, 0)]]
    assert python[1] == expected, python[1]
    assert compiled[1] == expected, compiled[1]
    for deltas in (compiled[2], python[2]):
        assert deltas["messages_in"] == 11 and deltas["client_messages_in"] == 11, deltas
        assert deltas["samples_in"] == 10 and deltas["topic_samples"] == 10, deltas
        assert deltas["duplicates"] == 1 and deltas["dropped"] == 0, deltas
        assert deltas["acknacks_out"] == 11 and deltas["decode_errors"] == 0, deltas
    assert compiled[2]["bytes_in"] == python[2]["bytes_in"] == compiled[2]["client_bytes_in"]
    assert "reliable stream 0x80: samples in order take the compiled path" in compiled[3]
    # The first goes through Python and registers the stream (the session's CREATEs came on it
    # before); the gap, its filling and the duplicate too: 1, 2, 6, 7, 8 and 9 were published in C.
    assert compiled[2]["samples_compiled"] == 6 and python[2]["samples_compiled"] == 0


@needs_extension
def test_a_reliable_sample_that_does_not_publish_is_left_to_python_unchanged(ros_peer):  # noqa: F811
    """A failed publish changes nothing here: the stream's numbers stay, nothing is counted or
    owed an ACKNACK, and Python gets the datagram byte for byte as it came, so it decides (and
    acknowledges) exactly as for any message it handles."""
    import ctypes
    import socket

    from rclpy.qos import QoSProfile
    publisher = ros_peer.node.create_publisher(Twist_ros(), "/fastpath_rel_fail", QoSProfile(depth=10))
    invalid = ctypes.create_string_buffer(64)  # an rcl_publisher_t without its implementation
    assert fastpath.resolve_rcl()
    server = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    server.bind(("127.0.0.1", 0))
    client.bind(("127.0.0.1", 0))
    receiver = fastpath.Receiver(server.fileno())
    wake = os.eventfd(0, os.EFD_NONBLOCK)
    try:
        address = client.getsockname()
        handle = receiver.add_client(0x01, KEY, address)
        receiver.add_stream(handle, 0x80, 4, 4)
        receiver.add_writer(handle, 0x0015, ctypes.addressof(invalid))
        receiver.start(wake)  # the receive thread reads the socket from now on
        datagram = keyed_datagram(5, stream_id=0x80)
        client.sendto(datagram, server.getsockname())
        assert wait_until(lambda: select_readable(wake), 5)  # the thread handed it over
        os.eventfd_read(wake)
        assert receiver.take() == [(datagram, address)]
        assert receiver.resume()  # nothing else waits: the thread may take datagrams again
        assert receiver.reliable_state(handle, 0x80) == (4, 4)
        assert receiver.fold() == ((0,) * 9, [], [], [])

        receiver.add_writer(handle, 0x0015, publisher.handle.pointer)  # now it publishes
        assert receiver.handle(datagram, address)
        assert receiver.reliable_state(handle, 0x80) == (5, 5)
        totals, clients, writers, acks = receiver.fold()
        assert totals == (1, len(datagram), 1, 0, 0, 0, 0, 0, 0) and acks == [(handle, 0x80)]

        # Taken by the thread: the ACKNACK owed is sent there at the end of its batch, byte for
        # byte what Python sends, and counted; none is left for Python, nothing handed over.
        from xrce.wire.submessages import AckNack, encode_message
        receiver.set_reliable_state(handle, 0x80, 4, 4)
        client.sendto(datagram, server.getsockname())
        acknack = encode_message(0x01, 0, 0, KEY, [AckNack(6, 0, 0x80)])
        client.settimeout(5)
        assert client.recv(64) == acknack
        assert not select_readable(wake) and receiver.take() == []
        totals, clients, writers, acks = receiver.fold()
        assert totals == (1, len(datagram), 1, 0, 0, 1, len(acknack), 0, 0) and acks == []
        assert clients[0][4:] == (1, len(acknack), None)

        # Paused (Python is deciding which clients C may serve): the same datagram is handed
        # over untouched, and so is the next one until Python has taken both and resumed.
        receiver.set_reliable_state(handle, 0x80, 4, 4)
        receiver.pause()
        client.sendto(datagram, server.getsockname())
        assert wait_until(lambda: select_readable(wake), 5)
        assert not receiver.resume()  # one waits for Python: the thread keeps handing over
        following = keyed_datagram(6, stream_id=0x80)
        client.sendto(following, server.getsockname())
        taken = []
        assert wait_until(lambda: taken.extend(receiver.take()) or len(taken) == 2, 5)
        assert taken == [(datagram, address), (following, address)]
        assert receiver.resume() and receiver.reliable_state(handle, 0x80) == (4, 4)
        receiver.stop()
        receiver.set_reliable_state(handle, 0x80, 5, 5)  # as the thread left it before the pause
        assert not receiver.handle(datagram, address)  # the duplicate is Python's to count
        assert not receiver.handle(keyed_datagram(7, stream_id=0x80), address)  # a gap: Python's
        receiver.set_reliable_state(handle, 0x80, 5, 7)  # Python holds 7, waits for 6
        assert not receiver.handle(keyed_datagram(6, stream_id=0x80), address)
        receiver.set_reliable_state(handle, 0x80, 7, 7)  # 6 and 7 delivered by Python
        assert receiver.handle(keyed_datagram(8, stream_id=0x80), address)
        assert receiver.handle(keyed_datagram(9, stream_id=0x80), address)
        assert receiver.reliable_state(handle, 0x80) == (9, 9)
        both = keyed_datagram(10, stream_id=0x80) + keyed_datagram(10)[8:]  # two WRITE_DATA
        assert not receiver.handle(both, address)  # several submessages: Python's
        assert receiver.reliable_state(handle, 0x80) == (9, 9)
    finally:
        receiver.stop()
        receiver.remove_writer(handle, 0x0015)
        ros_peer.node.destroy_publisher(publisher)
        os.close(wake)
        server.close()
        client.close()


def select_readable(fd):
    import select
    return bool(select.select([fd], [], [], 0)[0])


# ------------------------------------------------------------------------ hostile input, C alone

KEY = b"\x0a\x0b\x0c\x0d"
ADDRESS = ("127.0.0.1", 40000)


def keyed_datagram(seq, object_id=0x0015, body=b"\x00" * 48, session_id=0x01, stream_id=0x01):
    length = 4 + len(body)
    return bytes((session_id, stream_id, seq & 0xFF, seq >> 8)) + KEY + bytes(
        (0x07, 0x01, length & 0xFF, length >> 8, 0x00, 0x01, object_id >> 8, object_id & 0xFF)) + body


@needs_extension
def test_hostile_datagrams_are_left_to_python_or_published(ros_peer):  # noqa: F811
    """Mutations of a valid datagram (bytes changed, cut, extended, lying lengths): each is either
    published here, as a valid fast datagram, or left to Python; nothing crashes and the
    counters add up."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    publisher = ros_peer.node.create_publisher(
        Twist_ros(), "/fastpath_fuzz", QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
    assert fastpath.resolve_rcl()
    receiver = fastpath.Receiver(-1)  # no socket: handle() runs read()'s check on one datagram
    try:
        handle = receiver.add_client(0x01, KEY, ADDRESS)
        receiver.add_stream(handle, 0x01, 0xFFFF)
        receiver.add_writer(handle, 0x0015, publisher.handle.pointer)
        rng = random.Random(9)
        valid = keyed_datagram(0)
        taken = 0
        for index in range(20000):
            data = bytearray(valid)
            data[2], data[3] = index & 0xFF, (index >> 8) & 0xFF
            mutate(data, rng, rng.randrange(1, 4), longest_tail=15)
            taken += receiver.handle(bytes(data), ADDRESS)
        totals, clients, writers, _acks = receiver.fold()
        messages, _size, samples, stale, errors = totals[:5]
        assert taken == messages == clients[0][1] and errors == 0
        assert samples == sum(row[2] for row in writers) and samples + stale >= taken > 1000
    finally:
        receiver.remove_writer(handle, 0x0015)
        ros_peer.node.destroy_publisher(publisher)


@needs_extension
def test_registration_sequence_numbers_and_removal(ros_peer):  # noqa: F811
    from rclpy.qos import QoSProfile
    publisher = ros_peer.node.create_publisher(Twist_ros(), "/fastpath_order", QoSProfile(depth=10))
    assert fastpath.resolve_rcl()
    receiver = fastpath.Receiver(-1)
    try:
        handle = receiver.add_client(0x01, KEY, ADDRESS)
        receiver.add_stream(handle, 0x01, 0xFFFF)
        receiver.add_writer(handle, 0x0015, publisher.handle.pointer)
        assert not receiver.handle(keyed_datagram(0, object_id=0x0025), ADDRESS)  # unknown writer
        assert not receiver.handle(keyed_datagram(0, session_id=0x02), ADDRESS)  # other session
        assert not receiver.handle(keyed_datagram(0, stream_id=0x02), ADDRESS)  # other stream
        assert not receiver.handle(keyed_datagram(0, stream_id=0x81), ADDRESS)  # reliable
        # Python handles seq 0 and 1 itself, against the number kept here.
        assert receiver.stream_accept(handle, 0x01, 0) and receiver.stream_accept(handle, 0x01, 1)
        assert not receiver.stream_accept(handle, 0x01, 1)
        # The key from another source (a stranger outside --allow-from who knows it): Python's.
        assert not receiver.handle(keyed_datagram(2), ("127.0.0.2", 40000))
        assert not receiver.handle(keyed_datagram(2), ("127.0.0.1", 40001))
        assert receiver.handle(keyed_datagram(2), ADDRESS)
        assert receiver.handle(keyed_datagram(2), ADDRESS)  # taken, as a repeat: dropped
        assert receiver.handle(keyed_datagram(1), ADDRESS)  # older: dropped
        assert receiver.stream_seq(handle, 0x01) == 2
        totals, clients, writers, _acks = receiver.fold()
        assert totals == (3, 3 * len(keyed_datagram(2)), 1, 2, 0, 0, 0, 0, 0)  # one published, two stale
        assert writers == [(handle, 0x0015, 1, 48)] and clients[0][:3] == (handle, 3, 3 * 64)
        receiver.set_client_enabled(handle, False)  # e.g. dead: Python must revive it
        assert not receiver.handle(keyed_datagram(3), ADDRESS)
        receiver.set_client_enabled(handle, True)
        receiver.set_enabled(False)  # the capture tap or the trace on
        assert not receiver.handle(keyed_datagram(3), ADDRESS)
        receiver.set_enabled(True)
        assert receiver.handle(keyed_datagram(3), ADDRESS)
        assert receiver.remove_writer(handle, 0x0015) == (1, 48)
        assert not receiver.handle(keyed_datagram(4), ADDRESS)  # no writer: Python's
        receiver.remove_client(handle)
        assert receiver.stream_seq(handle, 0x01) is None
    finally:
        receiver.remove_writer(handle, 0x0015)
        ros_peer.node.destroy_publisher(publisher)


@needs_extension
def test_keyless_sessions_are_told_apart_by_source_address(ros_peer):  # noqa: F811
    from rclpy.qos import QoSProfile
    publisher = ros_peer.node.create_publisher(Twist_ros(), "/fastpath_keyless", QoSProfile(depth=10))
    assert fastpath.resolve_rcl()
    receiver = fastpath.Receiver(-1)
    try:
        for address in (ADDRESS, ("::1", 40000, 0, 0)):
            handle = receiver.add_client(0x81, b"\0\0\0\0", address)
            receiver.add_stream(handle, 0x01, 0xFFFF)
            receiver.add_writer(handle, 0x0015, publisher.handle.pointer)
            datagram = bytes((0x81, 0x01, 0, 0, 0x07, 0x01, 52, 0, 0, 1, 0x00, 0x15)) + bytes(48)
            assert receiver.handle(datagram, address)
            other_port = (address[0], 40001) + tuple(address[2:])
            assert not receiver.handle(datagram, other_port)
            assert not receiver.handle(datagram, ("127.0.0.2", 40000))
            receiver.remove_writer(handle, 0x0015)
            receiver.remove_client(handle)
    finally:
        ros_peer.node.destroy_publisher(publisher)


# ------------------------------------------------------------------------------------ packaging

@pytest.mark.parametrize("env, compiled", [({}, True), ({"CC": "false"}, False),
                                           ({"XRCE_FASTPATH": "0"}, False)],
                         ids=["with-a-compiler", "without-a-compiler", "left-out"])
def test_the_extensions_are_optional_when_pip_builds_xrce(tmp_path, env, compiled):
    """A plain ``pip install`` builds both compiled extensions (the engine's receive path, the ROS
    type supports) when it can and installs xrce anyway when it cannot (no compiler);
    XRCE_FASTPATH=0 leaves both out: a pure, platform-independent wheel."""
    import os
    import shutil
    import subprocess
    import sys
    import zipfile

    import sysconfig

    from agent_process import REPO

    if compiled and not shutil.which((sysconfig.get_config_var("CC") or "cc").split()[0]):
        pytest.skip("no C compiler here")
    # A copy without the checkout's own build products (an in-place .so, build/) to mislead it.
    source = tmp_path / "src"
    shutil.copytree(REPO, source, ignore=shutil.ignore_patterns(
        ".venv", "node_modules", "build", "*.so", ".git", "__pycache__", "*.egg-info", ".*cache"))
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", tmp_path,
                            source],
                           env=dict(os.environ, **env), stdout=subprocess.PIPE,
                           stderr=subprocess.STDOUT, text=True, timeout=300)
    assert build.returncode == 0, build.stdout[-3000:]
    (wheel,) = tmp_path.glob("xrce-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for extension in ("xrce/agent/engine/compiled/_fastpath.", "xrce/agent/middleware/ros/_rostypes.",
                      "xrce/agent/_heap."):
        assert any(n.startswith(extension) and n.endswith(".so") for n in names) == compiled, \
            (extension, names)
    assert "xrce/agent/engine/compiled/fastpath.py" in names
    assert "xrce/agent/middleware/ros/compiled.py" in names
    if env.get("XRCE_FASTPATH") == "0":
        assert wheel.name.endswith("-py3-none-any.whl"), wheel.name


def test_a_build_from_another_source_is_left_unused():
    """The installed extension is built from the C sources beside it (the suite's own install
    rebuilt it); a module built from another version of that file is told apart, and attach()
    leaves it unused, logging why, instead of publishing by the old rules."""
    import types

    from xrce.agent.engine.compiled import fastpath

    if fastpath._fastpath is None:
        pytest.fail("the compiled receive path is not built: the suite's install compiles it")
    assert fastpath.stale_build(fastpath._fastpath) is None, fastpath.stale_build(fastpath._fastpath)
    older = types.SimpleNamespace(SOURCE_CRC="00000000")
    assert "built from other C sources" in fastpath.stale_build(older)
    assert "built from other C sources" in fastpath.stale_build(types.SimpleNamespace())


def test_attach_leaves_a_stale_build_unused(monkeypatch, caplog):
    import types

    from xrce.agent.engine.compiled import fastpath

    if fastpath._fastpath is None:
        pytest.fail("the compiled receive path is not built: the suite's install compiles it")
    monkeypatch.delenv("XRCE_FASTPATH", raising=False)
    monkeypatch.setattr(fastpath._fastpath, "SOURCE_CRC", "00000000")
    link = types.SimpleNamespace(name="udp")
    with caplog.at_level("WARNING", logger="xrce.agent"):
        assert fastpath.attach(link, sock=None, engine=None) is None
    assert "built from other C sources" in caplog.text and "pip install -e ." in caplog.text


def test_the_ros_type_supports_are_an_extension_of_their_own(monkeypatch, caplog):
    """The ROS type-support C is the middleware's extension, not the engine's; it too is built
    from the sources beside it, and a build from others is left unused, with a warning, and named
    as the reason when a type known only by name is refused."""
    import importlib

    from xrce.agent.engine.compiled import fastpath
    from xrce.agent.middleware import UnknownTypeError
    from xrce.agent.middleware.ros import compiled, raw_types

    if fastpath._fastpath is None:
        pytest.fail("the compiled receive path is not built: the suite's install compiles it")
    assert not hasattr(fastpath._fastpath, "named_message_type")
    assert not hasattr(fastpath._fastpath, "message_type_support")
    monkeypatch.setattr(compiled, "_helper", compiled._UNSET)
    helper = compiled.helper()
    if helper is None:
        pytest.fail("the ROS type supports are not built (%s): the suite's install compiles them"
                    % compiled.missing)
    assert helper is importlib.import_module(compiled.MODULE) and hasattr(helper, "named_message_type")

    monkeypatch.setattr(compiled, "_helper", compiled._UNSET)
    monkeypatch.setattr(helper, "SOURCE_CRC", "00000000")
    with caplog.at_level("WARNING", logger="xrce.agent"):
        assert compiled.helper() is None
    assert "built from other C sources" in caplog.text and "pip install -e ." in caplog.text
    # A name no other test makes: a type made by name earlier in this process is cached.
    with pytest.raises(UnknownTypeError, match="which is built from other C sources"):
        raw_types.named_message_type("stale_helper_msgs::msg::dds_::T_", "stale_helper_msgs",
                                     "msg", "T")
