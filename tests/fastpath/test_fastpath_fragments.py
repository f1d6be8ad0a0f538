"""FRAGMENTs and HEARTBEATs of a reliable stream in the compiled receive path
(xrce/agent/engine/compiled/_reliable_in.c, xrce/agent/engine/compiled/fastpath.py).

End to end through real agent processes, real sockets and real rclpy, once with the compiled path
and once with ``XRCE_FASTPATH=0``: samples cut into FRAGMENTs in order, with a gap and its
retransmission, with a duplicate, behind a HEARTBEAT that announces more than has arrived, and a
second client whose fragments outgrow ``--max-reassembly``: both paths deliver the same samples,
send the same ACKNACKs (those answering a HEARTBEAT byte for byte) and count the same. Then the C
side alone: the budget's room, a last fragment that does not publish, the buffer's one holder.
"""

import time

import pytest

from agent_process import AgentProcess
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from test_fastpath import (FOLD_WAIT_S, KEY, CapturingTransport, Twist_ros, acknack_messages,
                           mutate, needs_extension, reliable_datagrams, select_readable)
from test_observability import stats_port
from xrce.agent.observe.stats_view import fetch_stats
from xrce.client.session import Session
from xrce.transports.udp import UdpTransport

try:
    from xrce.agent.engine.compiled import _fastpath as fastpath
except ImportError:
    fastpath = None

CHUNK = 20  # bytes of submessages per FRAGMENT: a Twist's WRITE_DATA (56 bytes) takes three
MAX_REASSEMBLY = 2048


def head_size(datagram):
    return 4 if datagram[0] & 0x80 else 8


def fragments(datagram, seq, chunk=CHUNK, last=True):
    """The FRAGMENT messages the client library makes of the message ``datagram`` (its
    submessages cut into ``chunk``-byte pieces), numbered from ``seq``."""
    head, inner = bytearray(datagram[:head_size(datagram)]), datagram[head_size(datagram):]
    pieces = [inner[i:i + chunk] for i in range(0, len(inner), chunk)]
    out = []
    for index, piece in enumerate(pieces):
        head[2], head[3] = (seq + index) & 0xFF, ((seq + index) >> 8) & 0xFF
        flags = 0x01 | (0x02 if last and index == len(pieces) - 1 else 0)
        out.append(bytes(head) + bytes((0x0D, flags, len(piece) & 0xFF, len(piece) >> 8)) + piece)
    return out


def heartbeat(datagram, first, last, stream_id=0x80):
    """The client's HEARTBEAT of ``stream_id``, in the session header of ``datagram``."""
    head = bytearray(datagram[:head_size(datagram)])
    head[1:4] = b"\x00\x00\x00"
    return bytes(head) + bytes((0x0B, 0x01, 5, 0, first & 0xFF, first >> 8, last & 0xFF,
                                last >> 8, stream_id))


def acknacks(transport, wait_s=0.3):
    """(first_unacked, nack_bitmap, the message's bytes) of each ACKNACK of stream 0x80."""
    return acknack_messages(transport, 0x80, wait_s)


def new_session(agent, ros_domain, topic, name, **kwargs):  # noqa: F811
    session = Session(CapturingTransport(UdpTransport("127.0.0.1", agent.port)), history=16,
                      **kwargs)
    assert session.create(attempts=5, timeout_ms=1000)
    node = session.create_participant(domain_id=ros_domain, name=name)
    from xrce.msgs.geometry_msgs import Twist
    writer = session.create_writer(node, topic, Twist, reliable=True)
    assert session.run_until_all_status(5000), session.last_statuses
    return session, writer


def run_fragment_scenario(ros_peer, ros_domain, topic, env):  # noqa: F811
    """Returns (values received in ROS, ACKNACKs per step, the HEARTBEATs' ACKNACK bytes,
    counter deltas, agent output)."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    received = []
    ros_peer.node.create_subscription(Twist_ros(), topic, lambda m: received.append(m.linear.x),
                                      QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    with AgentProcess("udp4", "-m", "dds", "-v", "5", "--stats-port", "0", "--max-reassembly",
                      str(MAX_REASSEMBLY), env=env) as agent:
        port = stats_port(agent)
        session, writer = new_session(agent, ros_domain, topic, "fastpath_fragments")
        # The hostile one: keyed (its key in every header), its own socket.
        other, other_writer = new_session(agent, ros_domain, topic, "fastpath_hostile",
                                          key=b"\x01\x02\x03\x04", session_id=0x01)
        try:
            assert wait_until(lambda: ros_peer.node.count_publishers(topic) > 0, 10)
            time.sleep(0.5)  # the subscriber's matching by the agent's publisher
            before = fetch_stats(port)
            frames = reliable_datagrams(session, writer, range(1, 9))
            first = frames[0][2] | frames[0][3] << 8
            pieces = []  # sample k's fragments, numbered on from the first sample's number
            for frame in frames:
                pieces.append(fragments(frame, first + 3 * len(pieces)))
            inner = session.transport.inner
            other_inner = other.transport.inner
            steps = []  # the first client's ACKNACKs after each of its datagrams
            answers = []  # the ACKNACKs answering its HEARTBEATs, whole
            hostile_acks = []

            def send(datagram):
                # One datagram, then its ACKNACKs: the same steps give the same ACKNACKs
                # whichever path handled them.
                inner.send(datagram)
                got = acknacks(inner)
                steps.append([((f - first) & 0xFFFF, bitmap) for f, bitmap, _ in got])
                if datagram[1] == 0:
                    answers.extend(raw for _, _, raw in got)

            for piece in pieces[0] + pieces[1]:  # in order: the first sample registers the stream
                send(piece)
            a, b, c = pieces[2]
            send(a)
            send(c)  # a gap: Python keeps it, names b missing
            send(b)  # the retransmission fills it: the sample goes out
            for piece in pieces[3]:
                send(piece)
            send(pieces[3][2])  # a duplicate: acknowledged again, nothing published
            # A HEARTBEAT announcing two messages not arrived yet: they are named missing...
            send(heartbeat(frames[0], first + 12, first + 13))
            for piece in pieces[4] + pieces[5]:  # ...and come: the first Python's, then C's
                send(piece)
            send(heartbeat(frames[0], first + 18, first + 17))  # nothing missing

            # The other client: one whole sample (its stream and writer go to C), then fragments
            # that never end, past --max-reassembly, while the first client goes on.
            other_frames = reliable_datagrams(other, other_writer, [100.0])
            other_first = other_frames[0][2] | other_frames[0][3] << 8
            big = other_frames[0][:8] + bytes(400 * 10)
            hostile = fragments(other_frames[0], other_first) + \
                fragments(big, other_first + 3, chunk=400, last=False)
            remaining = pieces[6] + pieces[7]
            for index, piece in enumerate(hostile):
                other_inner.send(piece)
                hostile_acks.extend((f - other_first) & 0xFFFF for f, _, _ in acknacks(other_inner))
                if 3 <= index < 3 + len(remaining):
                    send(remaining[index - 3])
            assert wait_until(lambda: len(received) >= 9, 10), received
            time.sleep(FOLD_WAIT_S)
            after = fetch_stats(port)
        finally:
            session.close()
            other.close()
    deltas = {name: after["agent"][name] - before["agent"][name]
              for name in ("messages_in", "bytes_in", "samples_in", "fragments_in", "dropped",
                           "duplicates", "acknacks_out", "decode_errors", "reassembly_overflows",
                           "budget_refused", "samples_compiled")}
    deltas["hostile_last_ack"] = max(hostile_acks) if hostile_acks else None
    return received, steps, answers, deltas, "".join(agent.output)


@needs_extension
def test_fragments_and_heartbeats_compiled_and_python_paths_deliver_acknowledge_and_count_the_same(
        ros_peer, ros_domain):  # noqa: F811
    compiled = run_fragment_scenario(ros_peer, ros_domain, "/fastpath_frag_on",
                                     {"XRCE_FASTPATH": "1"})
    python = run_fragment_scenario(ros_peer, ros_domain, "/fastpath_frag_off",
                                   {"XRCE_FASTPATH": "0"})

    first_client = [float(v) for v in range(1, 9)]
    for received in (compiled[0], python[0]):
        assert [v for v in received if v != 100.0] == first_client, received
        assert received.count(100.0) == 1, received  # the other client's whole sample, once
    assert compiled[1] == python[1], (compiled[1], python[1])
    steps = python[1]
    # Relative to the first fragment's number: each in order acknowledged; the gap (8 before 7)
    # names 7 missing; 7 fills it; the duplicate is acknowledged again.
    assert steps[:6] == [[(n, 0)] for n in range(1, 7)], steps
    assert steps[6:9] == [[(7, 0)], [(7, 0b1)], [(9, 0)]], steps
    assert steps[9:13] == [[(10, 0)], [(11, 0)], [(12, 0)], [(12, 0)]], steps
    assert steps[13] == [(12, 0b11)], steps  # the HEARTBEAT: 12 and 13 announced, both missing
    assert steps[14] == [(13, 0b1)], steps  # 12 came, 13 still missing
    assert steps[15:20] == [[(n, 0)] for n in range(14, 19)], steps
    assert steps[20] == [(18, 0)], steps  # the second HEARTBEAT: nothing missing
    assert steps[21:] == [[(n, 0)] for n in range(19, 25)], steps
    # The HEARTBEATs' answers, byte for byte, and what Python's encoder makes of them.
    from xrce.wire.submessages import AckNack, encode_message
    assert compiled[2] == python[2] == [encode_message(0x81, 0, 0, None, [AckNack(
        (compiled[2][0][8] | compiled[2][0][9] << 8), 0b11, 0x80)]), encode_message(
        0x81, 0, 0, None, [AckNack((compiled[2][1][8] | compiled[2][1][9] << 8), 0, 0x80)])]
    for deltas in (compiled[3], python[3]):
        # The hostile client: 3 + 10 fragments, every one acknowledged (the one past the quota
        # too: accepted, then abandoned with its message), one reassembly abandoned.
        assert deltas["reassembly_overflows"] == 1 and deltas["decode_errors"] == 0, deltas
        assert deltas["hostile_last_ack"] == 13, deltas
        assert deltas["samples_in"] == 9 and deltas["budget_refused"] == 0, deltas
        assert deltas["fragments_in"] == 24 + 13 and deltas["duplicates"] == 1, deltas
    compared = {k: v for k, v in compiled[3].items() if k != "samples_compiled"}
    assert compared == {k: v for k, v in python[3].items() if k != "samples_compiled"}, \
        (compiled[3], python[3])
    # Published in C: the first client's samples but the first (it registers the stream) and
    # the third (it fills a gap); the fourth too, its first fragment stored by Python (a
    # HEARTBEAT had announced more) and handed back to C. The other client's one sample
    # registers its stream.
    assert compiled[3]["samples_compiled"] == 6 and python[3]["samples_compiled"] == 0, \
        compiled[3]
    assert "reliable stream 0x80: samples in order take the compiled path" in compiled[4]


# ----------------------------------------------------------------------- the C side, in-process

def keyed_fragments(seq, object_id=0x0015, body=b"\x00" * 48, stream_id=0x80, chunk=CHUNK):
    """One WRITE_DATA of ``body`` to ``object_id`` as FRAGMENT messages of the keyed session 0x01."""
    length = 4 + len(body)
    whole = bytes((0x01, stream_id, 0, 0)) + KEY + bytes(
        (0x07, 0x01, length & 0xFF, length >> 8, 0x00, 0x01, object_id >> 8, object_id & 0xFF)) + body
    return fragments(whole, seq, chunk)


@needs_extension
def test_fragments_in_c_keep_to_the_budget_the_limit_and_one_holder(ros_peer):  # noqa: F811
    """A fragment is stored here only within the room Python gave and the reassembly limit; a
    last fragment whose message does not publish leaves the stream and the buffer as they were;
    the buffer is Python's once taken and C's again once put back; the bytes held are charged."""
    import ctypes

    from rclpy.qos import QoSProfile
    publisher = ros_peer.node.create_publisher(Twist_ros(), "/fastpath_frag_c", QoSProfile(depth=10))
    invalid = ctypes.create_string_buffer(64)  # an rcl_publisher_t without its implementation
    assert fastpath.resolve_rcl()
    receiver = fastpath.Receiver(-1)
    address = ("127.0.0.1", 40001)
    try:
        handle = receiver.add_client(0x01, KEY, address)
        receiver.add_stream(handle, 0x80, 0xFFFF, 0xFFFF)
        receiver.add_writer(handle, 0x0015, publisher.handle.pointer)
        receiver.set_reassembly_limit(1024)
        first, second, last = keyed_fragments(0)
        assert not receiver.handle(first, address)  # no room given yet: Python's budget decides
        receiver.set_room(handle, len(first) - 1)
        assert not receiver.handle(first, address)
        receiver.set_room(handle, 10000)
        assert receiver.handle(first, address) and receiver.handle(second, address)
        assert receiver.reliable_state(handle, 0x80) == (1, 1)
        held = 8 + 2 * CHUNK  # the header, then two chunks: what Python's buffer would hold
        assert receiver.fold_reliable() == (2, [(handle, held)])
        assert receiver.fold_reliable() is None

        # The last one, to a publisher that fails: nothing changes, Python gets it.
        receiver.add_writer(handle, 0x0015, ctypes.addressof(invalid))
        assert not receiver.handle(last, address)
        assert receiver.reliable_state(handle, 0x80) == (1, 1) and receiver.fold_reliable() is None
        partial = receiver.take_partial(handle, 0x80)
        assert partial == first[:8] + first[12:] + second[12:]
        assert receiver.take_partial(handle, 0x80) is None  # Python holds it now
        assert not receiver.handle(last, address)  # so C cannot finish it
        assert receiver.put_partial(handle, 0x80, partial)
        receiver.add_writer(handle, 0x0015, publisher.handle.pointer)
        assert receiver.handle(last, address)  # now it publishes
        assert receiver.reliable_state(handle, 0x80) == (2, 2)
        totals, _clients, writers, acks = receiver.fold()
        assert totals[:3] == (3, len(first) + len(second) + len(last), 1) and acks == [(handle, 0x80)]
        assert writers == [(handle, 0x0015, 1, 48)]
        assert receiver.fold_reliable() == (1, [(handle, -held)])  # the buffer given back

        # Past the limit: Python's (it abandons the message and counts it).
        big = keyed_fragments(3, body=bytes(2000), chunk=400)
        assert receiver.handle(big[0], address) and receiver.handle(big[1], address)
        assert not receiver.handle(big[2], address)  # 8 + 3 * 400 > 1024
        assert receiver.reliable_state(handle, 0x80) == (4, 4)
        assert len(receiver.take_partial(handle, 0x80)) == 8 + 800

        # A finished message that is not one WRITE_DATA of a registered writer: Python's.
        other = keyed_fragments(5, object_id=0x0025)
        assert receiver.handle(other[0], address) and receiver.handle(other[1], address)
        assert not receiver.handle(other[2], address)
        assert receiver.reliable_state(handle, 0x80) == (6, 6)
    finally:
        receiver.remove_writer(handle, 0x0015)
        ros_peer.node.destroy_publisher(publisher)


@needs_extension
def test_hostile_fragments_and_heartbeats_are_bounded_or_left_to_python(ros_peer):  # noqa: F811
    """Mutated FRAGMENT and HEARTBEAT datagrams: each is taken as a valid one or left to Python;
    the buffer never passes the limit, nothing crashes, the counters add up."""
    import random
    import socket

    from rclpy.qos import QoSProfile
    publisher = ros_peer.node.create_publisher(Twist_ros(), "/fastpath_frag_fuzz", QoSProfile(depth=10))
    assert fastpath.resolve_rcl()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # HEARTBEATs' answers go out of it
    sock.bind(("127.0.0.1", 0))
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", 0))
    address = peer.getsockname()
    receiver = fastpath.Receiver(sock.fileno())
    try:
        handle = receiver.add_client(0x01, KEY, address)
        receiver.add_stream(handle, 0x80, 0xFFFF, 0xFFFF)
        receiver.add_writer(handle, 0x0015, publisher.handle.pointer)
        receiver.set_reassembly_limit(512)
        receiver.set_room(handle, 1 << 30)
        rng = random.Random(31)
        valid = keyed_fragments(0, chunk=16) + [heartbeat(keyed_fragments(0)[0], 0, 3)]
        taken = fragments_taken = 0
        for index in range(20000):
            last, _announced = receiver.reliable_state(handle, 0x80)
            data = bytearray(valid[index % len(valid)])  # in turn: whole samples now and then
            if data[1]:
                data[2], data[3] = (last + 1) & 0xFF, ((last + 1) >> 8) & 0xFF  # next in order
            mutate(data, rng, rng.choice((0, 0, 1, 2)), longest_tail=299)
            if receiver.handle(bytes(data), address):
                taken += 1
            elif data[1:2] == b"\x80":  # as if Python had handled it: the stream moves on
                receiver.take_partial(handle, 0x80)
                receiver.set_reliable_state(handle, 0x80, (last + 1) & 0xFFFF, (last + 1) & 0xFFFF)
            if index % 97 == 0:  # now and then Python holds the buffer a while
                partial = receiver.take_partial(handle, 0x80)
                assert partial is None or len(partial) <= 512
                if partial is not None and rng.randrange(2):
                    assert receiver.put_partial(handle, 0x80, partial)
            folded = receiver.fold_reliable()
            if folded is not None:
                fragments_taken += folded[0]
        totals, _clients, writers, _acks = receiver.fold()
        messages, _size, samples, _stale, errors, acknacks_sent, _bytes = totals[:7]
        assert taken == messages and errors == 0 and taken > 1000, (taken, totals)
        assert samples == sum(row[2] for row in writers) and samples > 100
        assert messages == fragments_taken + acknacks_sent and acknacks_sent > 100, totals
    finally:
        receiver.remove_writer(handle, 0x0015)
        ros_peer.node.destroy_publisher(publisher)
        sock.close()
        peer.close()
