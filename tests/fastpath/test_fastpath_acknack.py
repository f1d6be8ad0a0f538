"""The client's ACKNACKs for the agent's reliable output stream in the compiled receive path
(xrce/agent/engine/compiled/_reliable_out.c, xrce.agent.engine.compiled.streams.CompiledOutputStream).

End to end through real agent processes, real sockets and real rclpy, once with the compiled path
(which also sends the reader's samples itself, xrce/agent/engine/compiled/_reader_out.c) and once with
``XRCE_FASTPATH=0``: a client reads a ROS topic on its reliable stream and answers the agent's
DATA with hand-made ACKNACKs: each acknowledged at once (the window wraps twice), a
NACK naming two messages (retransmitted, byte for byte), a window left to fill with a CREATE's
STATUS and a reader's samples waiting behind it, then the ACKNACK that frees it. Both paths send
the same messages and count the same. Then the C side and the stream object alone.
"""

import socket
import struct
import time

import pytest

from agent_process import AgentProcess
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from test_fastpath import (ADDRESS, FOLD_WAIT_S, KEY, CapturingTransport, Twist_ros,
                           needs_extension, reliable_datagrams)
from test_observability import client_row, stats_port
from xrce.agent.observe.stats_view import fetch_stats
from xrce.client.entities import create_reader, create_topic
from xrce.client.session import Session
from xrce.msgs.geometry_msgs import Twist
from xrce.wire.streams import OutputReliableStream
from xrce.wire.submessages import AckNack, Data, Status, decode_message, encode_message
from xrce.transports.udp import UdpTransport

try:
    from xrce.agent.engine.compiled import _fastpath as fastpath
    from xrce.agent.engine.compiled.streams import CompiledOutputStream
except ImportError:
    fastpath = None

WINDOW = 16  # the agent's STREAM_WINDOW


def acknack(session, first, bitmap=0, stream_id=0x80):
    return encode_message(session.session_id, 0, 0, None if session.session_id >= 0x80 else
                          session.key, [AckNack(first & 0xFFFF, bitmap, stream_id)])


def messages_from_agent(transport, wait_s, until=None):
    """(seq, kind, the message's bytes) of what the agent sends on stream 0x80 within ``wait_s``
    (sooner once ``until(list)`` holds); kind is "data" or "status"."""
    out = []
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline and not (until and until(out)):
        data = transport.recv(max(1, int((deadline - time.monotonic()) * 1000)))
        if data is None or data[1] != 0x80:
            continue
        for payload in decode_message(bytes(data))[1]:
            if isinstance(payload, (Data, Status)):
                kind = "data" if isinstance(payload, Data) else "status"
                out.append((data[2] | data[3] << 8, kind, bytes(data)))
    return out


def run_acknack_scenario(ros_peer, ros_domain, topic, env):  # noqa: F811
    """Returns (the steps' messages relative to the first DATA's number, retransmissions byte
    for byte equal to the originals, counter deltas, agent output)."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    publisher = ros_peer.node.create_publisher(
        Twist_ros(), topic, QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    with AgentProcess("udp4", "-m", "dds", "-v", "5", "--stats-port", "0", env=env) as agent:
        port = stats_port(agent)
        session = Session(CapturingTransport(UdpTransport("127.0.0.1", agent.port)), history=16)
        try:
            assert session.create(attempts=5, timeout_ms=1000)
            node = session.create_participant(domain_id=ros_domain, name="fastpath_acknack")
            writer = session.create_writer(node, topic + "_up", Twist, reliable=True)
            create_reader(session, node, topic, Twist, lambda m: None, reliable=True)
            assert session.run_until_all_status(5000), session.last_statuses
            assert wait_until(lambda: publisher.get_subscription_count() > 0, 10)
            time.sleep(0.5)
            inner = session.transport.inner
            # One sample up the client's reliable stream: the client (and with it the agent's
            # output stream, there since the CREATEs' STATUS) goes to the compiled path.
            for frame in reliable_datagrams(session, writer, [1.0]):
                inner.send(frame)
            time.sleep(0.3)
            while inner.recv(50) is not None:  # its ACKNACK
                pass
            before = fetch_stats(port)
            steps = []
            value = [0.0]

            def publish(count):
                for _ in range(count):
                    value[0] += 1
                    message = Twist_ros()()
                    message.linear.x = value[0]
                    publisher.publish(message)

            # 1: each DATA acknowledged at once, 40 of them (the window wraps twice).
            first = None
            for _ in range(40):
                publish(1)
                got = messages_from_agent(inner, 5, lambda out: out)
                assert got and got[0][1] == "data", got
                if first is None:
                    first = got[0][0]
                inner.send(acknack(session, got[0][0] + 1))
                steps.append([((s - first) & 0xFFFF, kind) for s, kind, _ in got])
            # 2: three unacknowledged, then a NACK of the first and the third: both again.
            sent = []
            for _ in range(3):
                publish(1)
                sent += messages_from_agent(inner, 5, lambda out: out)
            steps.append([((s - first) & 0xFFFF, kind) for s, kind, _ in sent])
            inner.send(acknack(session, sent[0][0], 0b101))
            again = messages_from_agent(inner, 1.0, lambda out: len(out) >= 2)
            steps.append([((s - first) & 0xFFFF, kind) for s, kind, _ in again])
            same = [raw for _, _, raw in again] == [sent[0][2], sent[2][2]]
            inner.send(acknack(session, sent[2][0] + 1))
            # 3: the window filled (16 DATA), three samples left in the reader's queue, and a
            # CREATE whose STATUS waits for room: nothing of them goes out...
            window = []
            for _ in range(WINDOW):  # one at a time: the reader's depth (10) keeps them all
                publish(1)
                window += messages_from_agent(inner, 5, lambda out: out)
            steps.append([((s - first) & 0xFFFF, kind) for s, kind, _ in window])
            for _ in range(3):
                publish(1)
                time.sleep(0.1)
            create_topic(session, node, "rt/fastpath_acknack_more", Twist.TYPE_NAME)
            session.flush()
            steps.append([((s - first) & 0xFFFF, kind)
                          for s, kind, _ in messages_from_agent(inner, 0.5)])
            # ...until the ACKNACK that frees the window: the STATUS first, then the samples.
            inner.send(acknack(session, window[-1][0] + 1))
            rest = messages_from_agent(inner, 5, lambda out: len(out) >= 4)
            steps.append([((s - first) & 0xFFFF, kind) for s, kind, _ in rest])
            assert rest, steps
            inner.send(acknack(session, rest[-1][0] + 1))
            time.sleep(FOLD_WAIT_S)
            after = fetch_stats(port)
        finally:
            session.close()
            ros_peer.node.destroy_publisher(publisher)
    deltas = {name: after["agent"][name] - before["agent"][name]
              for name in ("messages_in", "bytes_in", "samples_out", "retransmissions", "dropped",
                           "decode_errors", "handler_errors", "samples_out_compiled")}
    row_before, row_after = client_row(before, session), client_row(after, session)
    for name in ("messages_in", "bytes_in", "retransmissions"):
        deltas["client_" + name] = row_after[name] - row_before[name]
    return steps, same, deltas, "".join(agent.output)


@needs_extension
def test_acknacks_compiled_and_python_paths_send_retransmit_unblock_and_count_the_same(
        ros_peer, ros_domain):  # noqa: F811
    compiled = run_acknack_scenario(ros_peer, ros_domain, "/fastpath_ack_on",
                                    {"XRCE_FASTPATH": "1"})
    python = run_acknack_scenario(ros_peer, ros_domain, "/fastpath_ack_off",
                                  {"XRCE_FASTPATH": "0"})
    steps = python[0]
    assert steps[:40] == [[(n, "data")] for n in range(40)], steps
    assert steps[40] == [(40, "data"), (41, "data"), (42, "data")], steps
    assert steps[41] == [(40, "data"), (42, "data")], steps  # the NACK's two, again
    assert steps[42] == [(n, "data") for n in range(43, 43 + WINDOW)], steps
    assert steps[43] == [], steps  # the window is full: the STATUS and 3 samples wait
    assert steps[44] == [(59, "status"), (60, "data"), (61, "data"), (62, "data")], steps
    assert compiled[0] == python[0], (compiled[0], python[0])
    assert compiled[1] and python[1]  # retransmitted byte for byte
    for deltas in (compiled[2], python[2]):
        # 40 + 2 + 1 + 1 ACKNACKs, the CREATE; 62 samples out, 2 of them twice.
        assert deltas["messages_in"] == 45 and deltas["client_messages_in"] == 45, deltas
        assert deltas["samples_out"] == 62 and deltas["retransmissions"] == 2, deltas
        assert deltas["client_retransmissions"] == 2 and deltas["dropped"] == 0, deltas
        assert deltas["decode_errors"] == 0 and deltas["handler_errors"] == 0, deltas
    compiled_out = compiled[2].pop("samples_out_compiled")
    assert python[2].pop("samples_out_compiled") == 0
    assert compiled_out >= 40, compiled  # the acknowledged-at-once ones at least went out from C
    assert compiled[2] == python[2], (compiled[2], python[2])
    assert "reliable output stream 0x80: plain ACKNACKs take the compiled path" in compiled[3]
    assert "plain ACKNACKs take the compiled path" not in python[3]
    # The samples went out from C (the receive thread), the NACKed two from C's history.
    assert ": samples from ROS take the compiled path" in compiled[3]
    assert "samples from ROS take the compiled path" not in python[3]


# ----------------------------------------------------------------------- the C side, in-process

def keyed_acknack(first, bitmap=0, stream_id=0x80, flags=0x01, session_id=0x01):
    return bytes((session_id, 0, 0, 0)) + KEY + bytes(
        (0x0A, flags, 5, 0, first & 0xFF, first >> 8, bitmap >> 8, bitmap & 0xFF, stream_id))


@needs_extension
def test_plain_acknacks_move_the_acknowledged_point_in_c_and_the_rest_is_python(
        ros_peer):  # noqa: F811
    assert fastpath.resolve_rcl()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver = fastpath.Receiver(sock.fileno())
    try:
        handle = receiver.add_client(0x01, KEY, ADDRESS)
        stream = CompiledOutputStream(receiver, handle, OutputReliableStream(0x80, WINDOW), False)
        messages = [bytes(20 + n) for n in range(5)]
        for seq, message in enumerate(messages):
            assert stream.next_seq() == seq  # taken from C, which may send on the stream too
            stream.commit(seq, message)
        assert stream.stored_bytes == sum(map(len, messages))
        assert not receiver.handle(keyed_acknack(3, 0b1), ADDRESS)  # a NACK: Python's
        assert not receiver.handle(keyed_acknack(6), ADDRESS)  # more than was sent: Python's
        assert not receiver.handle(keyed_acknack(3, flags=0), ADDRESS)  # big-endian
        assert not receiver.handle(keyed_acknack(3, stream_id=0x81), ADDRESS)  # unknown stream
        assert not receiver.handle(keyed_acknack(3), ("127.0.0.1", 40001))  # another source
        assert not receiver.handle(keyed_acknack(3)[:-1], ADDRESS)  # cut short
        assert not receiver.handle(keyed_acknack(3) + b"\0", ADDRESS)  # something behind it
        receiver.set_probing(handle, True)  # Python times a HEARTBEAT's answer
        assert not receiver.handle(keyed_acknack(3), ADDRESS)
        receiver.set_probing(handle, False)
        assert stream.last_acknowledged == 0xFFFF and stream.stored_bytes == 100 + 10
        assert receiver.handle(keyed_acknack(3), ADDRESS)  # 0, 1, 2 acknowledged
        assert receiver.handle(keyed_acknack(2), ADDRESS)  # an older one: nothing moves
        assert stream.last_acknowledged == 2
        assert stream.in_flight() == 2  # the slots are freed as the window is looked at...
        assert stream.slots[:3] == [None] * 3 and stream.slots[3:5] == messages[3:]
        assert stream.stored_bytes == len(messages[3]) + len(messages[4])
        assert stream.release() == 20 + 21 + 22 and stream.release() == 0  # ...charged once
        totals, clients, _writers, _acks = receiver.fold()
        assert totals[:2] == (2, 2 * 17) and clients[0][1:3] == (2, 34)
        # A NACK (Python's) retransmits from Python's slots, the acknowledged point C's.
        assert stream.on_acknack(3, 0b11) == messages[3:]
        # The window full: the ACKNACK that frees it is Python's (a STATUS or a reader waits).
        for seq in range(5, 3 + WINDOW):
            assert stream.next_seq() == seq
            stream.commit(seq, b"x" * 8)
        assert not stream.has_room() and stream.next_seq() is None
        assert not receiver.handle(keyed_acknack(4), ADDRESS)
        assert stream.on_acknack(4, 0) == () and stream.has_room()
        assert receiver.handle(keyed_acknack(3 + WINDOW), ADDRESS)
        assert stream.in_flight() == 0 and stream.slots == [None] * WINDOW
        assert stream.stored_bytes == 0 and stream.release() == 24 + 8 * (WINDOW - 2)
        # Handed back to Python: a plain stream in the same state.
        plain = stream.detached()
        assert type(plain) is OutputReliableStream
        assert (plain.last_sent, plain.last_acknowledged, plain.stored_bytes) == \
            (2 + WINDOW, 2 + WINDOW, 0)
        receiver.remove_client(handle)
        assert not receiver.handle(keyed_acknack(3 + WINDOW), ADDRESS)
    finally:
        sock.close()


def timestamp_datagram(session_id, sec, nsec, flags=0x01):
    header = bytes((session_id, 0, 0, 0)) + (KEY if session_id < 0x80 else b"")
    return header + bytes((0x0E, flags, 8, 0)) + struct.pack("<iI", sec, nsec)


@needs_extension
@pytest.mark.parametrize("session_id", [0x01, 0x81], ids=["key in header", "no key"])
def test_a_timestamp_is_answered_in_c_with_the_python_paths_bytes(ros_peer, session_id):  # noqa: F811
    """PX4's time sync: a registered client's TIMESTAMP gets its TIMESTAMP_REPLY from C, the
    message the Python path encodes for the same three times; anything else stays Python's."""
    from xrce.wire.submessages import TimestampReply
    assert fastpath.resolve_rcl()  # the compiled path runs only once rcl is there
    agent = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    board = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    agent.bind(("127.0.0.1", 0))
    board.bind(("127.0.0.1", 0))
    board.settimeout(5)
    address = board.getsockname()
    receiver = fastpath.Receiver(agent.fileno())
    try:
        handle = receiver.add_client(session_id, KEY if session_id < 0x80 else bytes(4), address)
        assert not receiver.handle(timestamp_datagram(session_id, 7, 5, flags=0), address)  # BE
        assert not receiver.handle(timestamp_datagram(session_id, 7, 10 ** 9), address)
        assert not receiver.handle(timestamp_datagram(session_id, 7, 5) + b"\0" * 4, address)
        assert not receiver.handle(timestamp_datagram(session_id, 7, 5), ("127.0.0.1", 1))
        before = time.time_ns()
        assert receiver.handle(timestamp_datagram(session_id, -3, 112000000), address)
        after = time.time_ns()
        reply = board.recv(100)
        header, payloads = decode_message(reply)
        (answer,) = payloads
        assert isinstance(answer, TimestampReply) and header.stream_id == 0
        assert answer.originate_ns == -3 * 10 ** 9 + 112000000
        assert before <= answer.receive_ns <= answer.transmit_ns <= after
        assert reply == encode_message(session_id, 0, 0, KEY if session_id < 0x80 else None,
                                       [TimestampReply(answer.transmit_ns, answer.receive_ns,
                                                       answer.originate_ns)])
        totals, clients, _writers, _acks = receiver.fold()
        assert totals[:2] == (1, len(timestamp_datagram(session_id, 0, 0)))
        assert totals[7:] == (1, len(reply))
        assert clients == [(handle, 1, totals[1], clients[0][3], 1, len(reply),
                            answer.receive_ns - answer.originate_ns)]
        receiver.set_client_enabled(handle, False)  # a client Python attends to: Python answers
        assert not receiver.handle(timestamp_datagram(session_id, 7, 5), address)
    finally:
        receiver.remove_client(handle)
        agent.close()
        board.close()
