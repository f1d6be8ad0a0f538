"""CRC-16 functions, serial stream framing and the TCP length prefix (XRCE-WIRE.md §11, §12)."""

import importlib.util
import json
import os
import random
import sys
import tracemalloc

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xrce import EncodeError
from xrce.transports import crc as crc_module
from xrce.transports.crc import CRC_FUNCTIONS, crc16_arc, crc16_x25, get_crc
from xrce.transports.framing import (
    FrameDecoder,
    LengthPrefixDecoder,
    encode_frame,
    encode_length_prefixed,
)

CAPTURES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "golden", "wire_captures.json")

CREATE_CLIENT = bytes.fromhex("80000000000110005852434501000" "10FAABBCCDD8100FC01")
CREATE_CLIENT_FRAME = bytes.fromhex(
    "7E01001800" "80000000000110005852434501000" "10FAABBCCDD8100FC01" "3E8F"
)
STATUS_AGENT = bytes.fromhex("810000000401 0B00 0000 5852434501000 10F00".replace(" ", ""))
STATUS_AGENT_FRAME = bytes.fromhex("7E00011300") + STATUS_AGENT + bytes.fromhex("00EC")
ESCAPED_KEY = bytes.fromhex("80000000000110005852434501000" "10F7E7D01028100FC01")
ESCAPED_KEY_FRAME = bytes.fromhex(
    "7E01001800800000000001100058524345010001" "0F7D5E7D5D01028100FC0111E2"
)
ACKNACK = bytes.fromhex("810000000A01050001000000" "80")
ACKNACK_FRAME = bytes.fromhex("7E01000D00") + ACKNACK + bytes.fromhex("2B4C")


def load_fallback_crc_module(monkeypatch):
    """A private copy of crc.py imported while crcmod is unimportable (what MicroPython sees)."""
    monkeypatch.setitem(sys.modules, "crcmod", None)
    monkeypatch.setitem(sys.modules, "crcmod.predefined", None)
    spec = importlib.util.spec_from_file_location("crc_without_crcmod", crc_module.__file__)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def split_at(data, cuts):
    cuts = sorted(set(c for c in cuts if 0 < c < len(data)))
    pieces, previous = [], 0
    for cut in cuts:
        pieces.append(data[previous:cut])
        previous = cut
    pieces.append(data[previous:])
    return pieces


def feed_all(decoder, pieces):
    out = []
    for piece in pieces:
        out.extend(decoder.feed(piece))
    return out


# --- CRC ------------------------------------------------------------------------------------------


def test_check_values_of_both_implementations():
    assert crc16_arc(b"123456789") == 0xBB3D
    assert crc_module.crc16_arc_table(b"123456789") == 0xBB3D
    assert crc16_x25(b"123456789") == 0x906E
    assert crc_module.crc16_x25_table(b"123456789") == 0x906E


def test_worked_example_crcs():
    assert crc16_arc(CREATE_CLIENT) == 0x8F3E
    assert crc16_x25(CREATE_CLIENT) == 0x7709
    assert crc16_arc(STATUS_AGENT) == 0xEC00
    assert crc16_arc(ESCAPED_KEY) == 0xE211
    assert crc16_arc(ACKNACK) == 0x4C2B


def test_arc_table_matches_the_published_table_entry():
    assert crc_module._ARC_TABLE[1] == 0xC0C1


def test_forced_fallback_is_used_and_agrees_with_crcmod(monkeypatch):
    fallback = load_fallback_crc_module(monkeypatch)
    assert crc_module.HAVE_CRCMOD, "crcmod is a project dependency and should be importable here"
    assert not fallback.HAVE_CRCMOD
    assert fallback.crc16_arc is fallback.crc16_arc_table
    assert fallback.get_crc("ccitt") is fallback.crc16_x25_table
    rng = random.Random(1234)
    for size in list(range(0, 40)) + [255, 256, 1000, 4096]:
        data = bytes(rng.getrandbits(8) for _ in range(size))
        assert fallback.crc16_arc(data) == crc16_arc(data)
        assert fallback.crc16_x25(data) == crc16_x25(data)
        assert fallback.crc16_arc(memoryview(bytearray(data))) == crc16_arc(data)


@given(st.binary(max_size=300), st.binary(max_size=300))
def test_arc_continues_a_running_crc(first, second):
    assert crc16_arc(second, crc16_arc(first)) == crc16_arc(first + second)
    assert crc_module.crc16_arc_table(second, crc_module.crc16_arc_table(first)) == crc16_arc(first + second)


def test_crc_name_mapping():
    assert CRC_FUNCTIONS["arc"] is crc16_arc
    assert get_crc() is crc16_arc
    assert get_crc("arc") is crc16_arc
    assert get_crc("ccitt") is crc16_x25
    assert get_crc(crc16_x25) is crc16_x25
    with pytest.raises(ValueError):
        get_crc("crc32")


# --- encode_frame ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "payload, src, dst, frame",
    [
        (CREATE_CLIENT, 1, 0, CREATE_CLIENT_FRAME),
        (STATUS_AGENT, 0, 1, STATUS_AGENT_FRAME),
        (ESCAPED_KEY, 1, 0, ESCAPED_KEY_FRAME),
        (ACKNACK, 1, 0, ACKNACK_FRAME),
    ],
)
def test_worked_example_frames_byte_for_byte(payload, src, dst, frame):
    assert encode_frame(payload, src, dst) == frame
    assert encode_frame(bytearray(payload), src, dst) == frame
    assert encode_frame(memoryview(payload), src, dst) == frame
    assert FrameDecoder(local_addr=dst).feed(frame) == [(src, dst, payload)]


def test_x25_frames_round_trip_and_differ_from_arc():
    frame = encode_frame(CREATE_CLIENT, 1, 0, crc=crc16_x25)
    assert frame[-2:] == bytes((0x09, 0x77))
    assert FrameDecoder(crc=crc16_x25).feed(frame) == [(1, 0, CREATE_CLIENT)]
    arc_decoder = FrameDecoder()
    assert arc_decoder.feed(frame) == []
    assert arc_decoder.crc_errors == 1


def load_serial_captures():
    with open(CAPTURES) as handle:
        return json.load(handle)["serial"]


def test_every_captured_serial_frame_decodes_and_reencodes():
    entries = load_serial_captures()
    assert len(entries) >= 10
    stream = b""
    for entry in entries:
        raw = bytes.fromhex(entry["raw"])
        payload = bytes.fromhex(entry["payload"])
        assert FrameDecoder().feed(raw) == [(entry["src_addr"], entry["dst_addr"], payload)]
        assert encode_frame(payload, entry["src_addr"], entry["dst_addr"]) == raw
        stream += raw
    assert any(entry["escaped_bytes"] for entry in entries), "captures should exercise escaping"
    decoder = FrameDecoder()
    decoded = feed_all(decoder, [stream[i : i + 7] for i in range(0, len(stream), 7)])
    assert [payload for _, _, payload in decoded] == [bytes.fromhex(e["payload"]) for e in entries]
    assert decoder.dropped_bytes == 0 and decoder.resyncs == 0 and decoder.pending_bytes == 0


def test_length_126_has_its_low_byte_escaped():
    payload = bytes(range(126))
    frame = encode_frame(payload, 1, 0)
    assert frame[:6] == bytes((0x7E, 0x01, 0x00, 0x7D, 0x5E, 0x00))
    assert FrameDecoder().feed(frame) == [(1, 0, payload)]


def test_addresses_and_crc_bytes_are_escaped():
    payload = b"\x00" * 125  # length 125 = 0x7D
    frame = encode_frame(payload, 0x7E, 0x7D)
    assert frame[:7] == bytes((0x7E, 0x7D, 0x5E, 0x7D, 0x5D, 0x7D, 0x5D))
    assert FrameDecoder().feed(frame) == [(0x7E, 0x7D, payload)]
    # Find a one-byte payload whose CRC contains 0x7E so the CRC escaping path is covered.
    value = next(v for v in range(256) if 0x7E in crc16_arc(bytes((v,))).to_bytes(2, "little"))
    frame = encode_frame(bytes((value,)), 1, 0)
    assert b"\x7d\x5e" in frame[6:]
    assert FrameDecoder().feed(frame) == [(1, 0, bytes((value,)))]


def test_encode_frame_rejects_bad_input():
    with pytest.raises(EncodeError):
        encode_frame(bytes(65536), 1, 0)
    with pytest.raises(EncodeError):
        encode_frame(b"x", 256, 0)
    with pytest.raises(EncodeError):
        encode_frame(b"x", 0, -1)


def test_empty_payload_frame():
    frame = encode_frame(b"", 1, 0)
    assert frame == bytes((0x7E, 1, 0, 0, 0, 0, 0))
    assert FrameDecoder().feed(frame) == [(1, 0, b"")]


# --- FrameDecoder ---------------------------------------------------------------------------------


def test_decoder_split_at_every_position():
    stream = ESCAPED_KEY_FRAME + CREATE_CLIENT_FRAME
    expected = [(1, 0, ESCAPED_KEY), (1, 0, CREATE_CLIENT)]
    for cut in range(len(stream) + 1):
        decoder = FrameDecoder()
        assert feed_all(decoder, [stream[:cut], stream[cut:]]) == expected, cut
        assert decoder.pending_bytes == 0


def test_decoder_byte_by_byte():
    stream = ESCAPED_KEY_FRAME + STATUS_AGENT_FRAME + ACKNACK_FRAME
    decoder = FrameDecoder()
    out = feed_all(decoder, [stream[i : i + 1] for i in range(len(stream))])
    assert out == [(1, 0, ESCAPED_KEY), (0, 1, STATUS_AGENT), (1, 0, ACKNACK)]
    assert decoder.frames == 3
    assert decoder.dropped_bytes == 0


def test_decoder_accepts_bytearray_and_memoryview():
    decoder = FrameDecoder()
    assert decoder.feed(bytearray(ACKNACK_FRAME)) == [(1, 0, ACKNACK)]
    assert decoder.feed(memoryview(ACKNACK_FRAME)) == [(1, 0, ACKNACK)]


def test_garbage_before_and_between_frames_is_dropped_and_counted():
    garbage = b"\x00\x11\x7d\x5e hello \xff"
    decoder = FrameDecoder()
    out = decoder.feed(garbage + ACKNACK_FRAME + garbage + CREATE_CLIENT_FRAME + garbage)
    assert out == [(1, 0, ACKNACK), (1, 0, CREATE_CLIENT)]
    assert decoder.dropped_bytes == 3 * len(garbage)
    assert decoder.resyncs == 0 and decoder.crc_errors == 0


def test_flag_inside_a_frame_resyncs_to_the_next_frame():
    truncated = CREATE_CLIENT_FRAME[:15]
    decoder = FrameDecoder()
    assert decoder.feed(truncated + ACKNACK_FRAME) == [(1, 0, ACKNACK)]
    assert decoder.resyncs == 1
    assert decoder.dropped_bytes == len(truncated)
    # The same with the flag arriving in the middle of an escape sequence and byte by byte.
    decoder = FrameDecoder()
    cut = ESCAPED_KEY_FRAME.index(b"\x7d\x5e") + 1
    stream = ESCAPED_KEY_FRAME[:cut] + ACKNACK_FRAME
    assert feed_all(decoder, [stream[i : i + 1] for i in range(len(stream))]) == [(1, 0, ACKNACK)]
    assert decoder.resyncs == 1


def test_bad_crc_is_counted_and_the_next_frame_still_decodes():
    corrupted = bytearray(CREATE_CLIENT_FRAME)
    corrupted[10] ^= 0x01
    decoder = FrameDecoder()
    assert decoder.feed(bytes(corrupted) + ACKNACK_FRAME) == [(1, 0, ACKNACK)]
    assert decoder.crc_errors == 1
    assert decoder.dropped_bytes == len(corrupted)
    assert decoder.frames == 1


def test_oversize_length_is_counted_and_the_next_frame_still_decodes():
    big = encode_frame(bytes(600), 1, 0)
    decoder = FrameDecoder(max_payload=512)
    assert decoder.feed(big + ACKNACK_FRAME + big) == [(1, 0, ACKNACK)]
    assert decoder.oversize == 2
    assert decoder.dropped_bytes == 2 * len(big)
    assert FrameDecoder(max_payload=600).feed(big) == [(1, 0, bytes(600))]


def test_frames_for_another_address_are_dropped():
    decoder = FrameDecoder(local_addr=1)
    out = decoder.feed(CREATE_CLIENT_FRAME + STATUS_AGENT_FRAME)
    assert out == [(0, 1, STATUS_AGENT)]
    assert decoder.wrong_address == 1
    assert decoder.dropped_bytes == len(CREATE_CLIENT_FRAME)


def test_reset_abandons_the_frame_in_progress():
    decoder = FrameDecoder()
    decoder.feed(CREATE_CLIENT_FRAME[:10])
    assert decoder.pending_bytes == 10
    decoder.reset()
    assert decoder.dropped_bytes == 10
    assert decoder.feed(CREATE_CLIENT_FRAME[10:] + ACKNACK_FRAME) == [(1, 0, ACKNACK)]


NOISE = st.binary(max_size=40).map(lambda b: b.replace(b"\x7e", b""))
ADDRESS = st.integers(0, 255)


@settings(max_examples=200, deadline=None)
@given(
    frames=st.lists(st.tuples(ADDRESS, ADDRESS, st.binary(max_size=300)), max_size=12),
    noise=st.lists(NOISE, min_size=13, max_size=13),
    data=st.data(),
)
def test_random_frames_with_noise_and_chunking_come_out_intact_and_in_order(frames, noise, data):
    stream = b""
    for index, (src, dst, payload) in enumerate(frames):
        stream += noise[index] + encode_frame(payload, src, dst)
    stream += noise[-1]
    cuts = data.draw(st.lists(st.integers(0, max(len(stream), 1)), max_size=30))
    decoder = FrameDecoder()
    assert feed_all(decoder, split_at(stream, cuts)) == frames
    assert decoder.frames == len(frames)
    assert decoder.dropped_bytes == sum(len(n) for n in noise[: len(frames)]) + len(noise[-1])
    assert decoder.crc_errors == decoder.resyncs == decoder.oversize == 0


@settings(max_examples=300, deadline=None)
@given(chunks=st.lists(st.binary(max_size=200), max_size=20), max_payload=st.integers(0, 300))
def test_arbitrary_bytes_never_raise_and_state_stays_bounded(chunks, max_payload):
    decoder = FrameDecoder(local_addr=0, max_payload=max_payload)
    total = 0
    for chunk in chunks:
        for src, dst, payload in decoder.feed(chunk):
            assert dst == 0 and len(payload) <= max_payload
        total += len(chunk)
        assert decoder.pending_bytes <= 1 + 2 * (max_payload + 6)
        assert len(decoder._view) == max_payload
    assert decoder.dropped_bytes + decoder.pending_bytes <= total


def test_decoder_memory_is_bounded_under_a_long_hostile_stream():
    rng = random.Random(7)
    decoder = FrameDecoder(max_payload=512)
    # A stream that keeps opening long frames and escape sequences, plus random bytes.
    hostile = (b"\x7e\x01\x00\xff\x01" + b"\x7d\x5d" * 200 + bytes(rng.getrandbits(8) for _ in range(3000))) * 4
    decoder.feed(hostile)
    tracemalloc.start()
    try:
        baseline = tracemalloc.get_traced_memory()[0]
        for _ in range(200):
            decoder.feed(hostile)
        current, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak - baseline < 64 * 1024
    assert current - baseline < 4 * 1024
    assert decoder.dropped_bytes > 0


# --- Length prefix (TCP) --------------------------------------------------------------------------


def test_length_prefix_encoding_matches_the_tcp_capture():
    assert encode_length_prefixed(CREATE_CLIENT) == b"\x18\x00" + CREATE_CLIENT
    assert encode_length_prefixed(bytearray(STATUS_AGENT)) == b"\x13\x00" + STATUS_AGENT
    with pytest.raises(EncodeError):
        encode_length_prefixed(b"")
    with pytest.raises(EncodeError):
        encode_length_prefixed(bytes(65536))


def test_length_prefix_split_at_every_position_and_byte_by_byte():
    messages = [CREATE_CLIENT, STATUS_AGENT, ACKNACK]
    stream = b"".join(encode_length_prefixed(m) for m in messages)
    for cut in range(len(stream) + 1):
        decoder = LengthPrefixDecoder(512)
        assert feed_all(decoder, [stream[:cut], stream[cut:]]) == messages, cut
    decoder = LengthPrefixDecoder(512)
    assert feed_all(decoder, [stream[i : i + 1] for i in range(len(stream))]) == messages
    assert decoder.messages == 3 and not decoder.broken


def test_length_prefix_zero_length_breaks_the_stream():
    decoder = LengthPrefixDecoder(512)
    stream = encode_length_prefixed(ACKNACK) + b"\x00\x00" + encode_length_prefixed(ACKNACK)
    assert decoder.feed(stream) == [ACKNACK]
    assert decoder.broken and decoder.zero_length == 1
    assert decoder.dropped_bytes == 2 + len(ACKNACK) + 2
    assert decoder.feed(encode_length_prefixed(ACKNACK)) == []
    assert decoder.dropped_bytes == 2 * (2 + len(ACKNACK)) + 2


def test_length_prefix_oversize_breaks_the_stream_even_split_in_the_prefix():
    decoder = LengthPrefixDecoder(100)
    stream = encode_length_prefixed(bytes(101))
    assert decoder.feed(stream[:1]) == []
    assert not decoder.broken
    assert decoder.feed(stream[1:]) == []
    assert decoder.broken and decoder.oversize == 1
    assert LengthPrefixDecoder(101).feed(stream) == [bytes(101)]


@settings(max_examples=200, deadline=None)
@given(messages=st.lists(st.binary(min_size=1, max_size=300), max_size=12), data=st.data())
def test_length_prefix_random_messages_and_chunking(messages, data):
    stream = b"".join(encode_length_prefixed(m) for m in messages)
    cuts = data.draw(st.lists(st.integers(0, max(len(stream), 1)), max_size=30))
    decoder = LengthPrefixDecoder(300)
    assert feed_all(decoder, split_at(stream, cuts)) == messages
    assert decoder.messages == len(messages)


@settings(max_examples=300, deadline=None)
@given(chunks=st.lists(st.binary(max_size=200), max_size=20), max_len=st.integers(1, 300))
def test_length_prefix_arbitrary_bytes_never_raise(chunks, max_len):
    decoder = LengthPrefixDecoder(max_len)
    total = 0
    for chunk in chunks:
        for message in decoder.feed(chunk):
            assert 0 < len(message) <= max_len
        total += len(chunk)
    assert decoder.dropped_bytes <= total
    assert len(decoder._view) == max_len


def test_table_crcs_under_micropython():
    # A board has no crcmod: the table versions give the catalogue check values there too, the
    # X.25 table built by its first use.
    from mp_harness import run_micropython

    result = run_micropython(
        "from xrce.transports import crc\n"
        "print(crc._X25_TABLE is None, hex(crc.crc16_x25(b'123456789')), hex(crc.crc16_x25(b'123456789')),\n"
        "      hex(crc.crc16_arc(b'123456789')), crc.HAVE_CRCMOD)\n",
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["True", "0x906e", "0x906e", "0xbb3d", "False"]
