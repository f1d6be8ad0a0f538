"""The framed sends that write through a piece buffer (SerialTransport over a stream object,
CustomTransport with framing) put on the line exactly the bytes ``encode_frame`` makes, wherever
the escapes fall against the piece boundaries: in the message, in the header and in the CRC, with
the piece buffer full to its last byte or one short. (The bare-metal board met a frame whose CRC
needed escaping with the buffer one byte short of full: an IndexError before this test.)"""

import pytest

from xrce.transports.crc import crc16_arc
from xrce.transports.custom import CustomTransport
from xrce.transports.framing import ESCAPE, FLAG, encode_frame
from xrce.transports.serial import SerialTransport


class Line:
    """A stream object (SerialTransport) and write callback (CustomTransport) that keeps every byte
    and takes at most ``bite`` of them per call."""

    def __init__(self, bite=10**6):
        self.data = bytearray()
        self.bite = bite
        self.calls = 0

    def any(self):
        return 0

    def readinto(self, buf, n):
        return 0

    def write(self, buf, off, n):
        take = min(n, self.bite)
        self.data += bytes(buf[off:off + take])
        self.calls += 1
        return take

    def write_cb(self, user, data):
        take = min(len(data), self.bite)
        self.data += bytes(data[:take])
        self.calls += 1
        return take


def _messages():
    # Every length up to two pieces and a half, with escapes nowhere, everywhere, and a last byte
    # chosen so that the CRC itself has a byte to escape.
    for length in range(1, 170):
        yield bytes(((i * 37) & 0x7F) | 0x80 for i in range(length))  # 0x80..0xFF: nothing to escape
        yield bytes([FLAG, ESCAPE] * length)[:length]
        head = bytes((i * 11) & 0xFF for i in range(length - 1))
        for last in range(256):
            check = crc16_arc(head + bytes([last]))
            if {check & 0xFF, check >> 8} & {FLAG, ESCAPE}:
                yield head + bytes([last])
                break


def _transports(line, addresses):
    local, remote = addresses
    yield "serial", SerialTransport(line, local_addr=local, remote_addr=remote)
    yield "custom", CustomTransport(lambda u: True, lambda u: True, line.write_cb, lambda u, b, s, t: 0,
                                    framing=True, local_addr=local, remote_addr=remote)


@pytest.mark.parametrize("addresses", [(1, 0), (FLAG, ESCAPE)])
@pytest.mark.parametrize("bite", [10**6, 1, 7])
def test_framed_sends_match_encode_frame(addresses, bite):
    messages = list(_messages())
    escaped_checks = sum(1 for m in messages if {crc16_arc(m) & 0xFF, crc16_arc(m) >> 8} & {FLAG, ESCAPE})
    assert escaped_checks > 150
    for name in ("serial", "custom"):
        line = Line(bite)
        transport = dict(_transports(line, addresses))[name]
        expected = bytearray()
        for message in messages:
            assert transport.send(message), (name, len(message))
            expected += encode_frame(message, addresses[0], addresses[1])
        assert line.data == expected, name
        assert transport.sent == len(messages) and transport.send_errors == 0


def test_a_failed_write_fails_the_send_and_the_next_frame_is_whole():
    line = Line()
    alive = [False]

    def write_cb(user, data):
        return line.write_cb(user, data) if alive[0] else 0

    custom = CustomTransport(lambda u: True, lambda u: True, write_cb, lambda u, b, s, t: 0, framing=True)
    assert not custom.send(bytes(100)) and custom.send_errors == 1
    alive[0] = True
    assert custom.send(b"\x81\x00\x00\x00")
    assert line.data == encode_frame(b"\x81\x00\x00\x00", 0, 0)
