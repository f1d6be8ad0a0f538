"""The allocation-free receive paths a board uses (FrameDecoder.scan, crc_of_prefix,
SerialTransport.recv_frame) decode exactly what the allocating ones do, and Session's output
buffers can be sized at set-up. Their heap figures under MicroPython: test_micropython_transport_heap.py."""

import os
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xrce.client.session import Session
from xrce.transports.crc import crc16_arc, crc16_arc_table, crc16_x25, crc16_x25_table, crc_of_prefix
from xrce.transports.framing import FrameDecoder, encode_frame
from xrce.transports.serial import SerialTransport
from xrce.transports.udp import UdpTransport

COUNTERS = ("frames", "crc_errors", "oversize", "resyncs", "dropped_bytes", "wrong_address")


def _scan_all(decoder, data, cuts):
    # Feed ``data`` to scan() in pieces cut at ``cuts``, collecting every completed frame.
    frames = []
    buf = bytearray(data)
    start = 0
    for end in sorted(set(cuts)) + [len(buf)]:
        pos = start
        while pos < end:
            pos = decoder.scan(buf, pos, end)
            if decoder.frame_length >= 0:
                payload = bytes(decoder.buffer[: decoder.frame_length])
                frames.append((decoder.frame_src, decoder.frame_dst, payload))
        start = end
    return frames


def _stream(rng, count):
    # Frames (some with 0x7E/0x7D inside, some for another address, some corrupted) and noise.
    parts = []
    for index in range(count):
        payload = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 90)))
        frame = bytearray(encode_frame(payload, rng.choice((0, 0, 3)), rng.choice((1, 1, 2))))
        roll = rng.random()
        if roll < 0.1 and len(frame) > 6:
            frame[rng.randrange(5, len(frame))] ^= 0x41  # corrupted
        elif roll < 0.15:
            frame = frame[: rng.randrange(1, len(frame))]  # cut short: the next flag resyncs
        parts.append(bytes(frame))
        if rng.random() < 0.2:
            parts.append(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 8))))
    return b"".join(parts)


@pytest.mark.parametrize("seed", range(20))
def test_scan_decodes_what_feed_decodes_with_the_same_counters(seed):
    rng = random.Random(seed)
    data = _stream(rng, 40)
    cuts = [rng.randrange(len(data) + 1) for _ in range(rng.randrange(0, 30))]
    fed, scanned = FrameDecoder(local_addr=1, max_payload=64), FrameDecoder(local_addr=1, max_payload=64)
    expected = []
    start = 0
    for end in sorted(set(cuts)) + [len(data)]:
        expected += fed.feed(data[start:end])
        start = end
    assert _scan_all(scanned, data, cuts) == expected
    assert expected  # the stream had good frames in it
    for name in COUNTERS:
        assert getattr(scanned, name) == getattr(fed, name), name
    assert scanned.pending_bytes == fed.pending_bytes


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300), st.integers(0, 300))
def test_crc_of_prefix_is_the_crc_of_the_slice(data, length):
    length = min(length, len(data))
    buf = bytearray(data) + b"\xaa\x55"  # bytes past ``length`` must not count
    for crc in (crc16_arc, crc16_arc_table, crc16_x25, crc16_x25_table):
        assert crc_of_prefix(crc, buf, length) == crc(bytes(data[:length]))
    assert crc_of_prefix(lambda view: len(view), buf, length) == length  # any other function: a slice


def test_serial_recv_frame_leaves_each_message_in_the_decoders_buffer():
    master, slave = os.openpty()
    transport = SerialTransport(os.ttyname(slave))
    try:
        messages = [b"\x7e\x7d" + bytes(range(40)), b"second", bytes(200)]
        frames = b"".join(encode_frame(m, 0, 1) for m in messages)
        os.write(master, b"noise" + encode_frame(b"from 3", 3, 1) + frames)
        for message in messages:
            length = transport.recv_frame(1000)
            assert bytes(transport.decoder.buffer[:length]) == message
        assert transport.recv_frame(50) == -1
        assert transport.wrong_source == 1 and transport.received == 3
    finally:
        transport.close()
        os.close(slave)
        os.close(master)


def test_output_buffers_are_sized_at_set_up_for_the_largest_sample():
    transport = UdpTransport("127.0.0.1", 9)  # nothing is sent
    try:
        session = Session(transport, session_id=0x81, largest_sample=720)
        reliable, best_effort = session._outputs[session.reliable], session._outputs[session.best_effort]
        # A 720-byte sample alone in a message: 4-byte header, subheader, request and object ids,
        # in the reliable stream's large buffer; the history's buffers and the writer's are a
        # message's (the fragments are built there), as the best-effort stream's (never more).
        assert len(reliable.big) == 4 + 4 + 4 + 720
        assert len(reliable.buf) == session.max_message
        assert {len(buf) for buf in reliable.state.slots} == {session.max_message}
        assert len(best_effort.buf) == session.max_message
        small = Session(transport, session_id=0x81)
        assert len(small._outputs[small.reliable].buf) == 64  # unsized: starts small and grows
        small.size_output_buffers(100)
        assert len(small._outputs[small.reliable].buf) == len(small._outputs[small.best_effort].buf) == 112
        small.size_output_buffers(10)  # never shrinks
        assert len(small._outputs[small.reliable].buf) == 112
    finally:
        transport.close()
