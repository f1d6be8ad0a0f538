"""What the real client transports allocate per message on a board, measured under real MicroPython
1.27 (WebAssembly) over the harness' port-like socket (tests/micropython/socket.py: recv(n) makes
a new n-byte buffer and a new bytes, readinto fills the caller's buffer and reads until it is full,
as MicroPython's unix port does) to peers on real sockets here.

Once set up: nothing allocated per sent datagram, frame or message (UDP, TCP, serial, and
CustomTransport with framing, which writes its frames through a piece buffer as serial does); nothing per
received TCP message or serial frame through ``recv_frame`` (the message stays in the transport's
buffer); nothing while waiting with nothing there. A UDP datagram received costs what the port's
recv(mtu + 1) allocates: MicroPython has no recv_into, and readinto on a UDP socket runs datagrams
together (tests/micropython/transport_heap.py, xrce/transports/udp.py).
"""

import socket
import threading
import time
from pathlib import Path

from mp_harness import run_micropython
from xrce.transports.framing import FrameDecoder, LengthPrefixDecoder, encode_frame, encode_length_prefixed

SCRIPT = Path(__file__).resolve().parents[1] / "micropython" / "transport_heap.py"
COUNT = 20
SIZE = 200
MTU = 512
# A UDP datagram of SIZE bytes received by UdpTransport.recv on MicroPython, as this port lays the
# heap out (16-byte blocks, 32-bit): the harness socket's recv(mtu + 1) buffer (a 16-byte
# bytearray object and 513 bytes -> 528) and what it returns (a 16-byte bytes object and
# SIZE + 1 bytes -> 208), and two memoryviews the harness makes to slice it (16 + 32). A board's
# recv allocates the same two blocks (the unix port frees the first on return, lwIP ports shrink
# it to the datagram) and no memoryview.
UDP_RECV_BYTES = 16 + 528 + 16 + 208 + 16 + 16


def _blocks(size):
    return (size + 15) // 16 * 16


class Peer(threading.Thread):
    """Echoes messages back the way each transport frames them; answers AWKWARD awkwardly."""

    def __init__(self, kind):
        super().__init__(daemon=True)
        self.kind = kind
        self.raw = bytearray()  # every byte the client sent (TCP, serial, custom)
        if kind == "udp":
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        else:
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.bind(("127.0.0.1", 0))
        if kind != "udp":
            self.sock.listen(1)
        self.sock.settimeout(60)
        self.port = self.sock.getsockname()[1]

    def run(self):
        try:
            if self.kind == "udp":
                self._run_udp()
            else:
                self._run_stream()
        except OSError:
            pass  # closed at the end of the test

    def _run_udp(self):
        while True:
            data, address = self.sock.recvfrom(4096)
            if data == b"AWKWARD":
                self.sock.sendto(bytes(MTU + 1), address)  # one byte over the MTU: dropped
                self.sock.sendto(b"good", address)
            else:
                self.sock.sendto(data, address)

    def _run_stream(self):
        conn, _ = self.sock.accept()
        with conn:
            serial = self.kind in ("serial", "custom")
            decoder = FrameDecoder(local_addr=0) if serial else LengthPrefixDecoder()
            while True:
                data = conn.recv(65536)
                if not data:
                    return
                self.raw += data
                for item in decoder.feed(data):
                    message = item[2] if serial else item
                    if message == b"AWKWARD":
                        self._awkward(conn)
                    elif serial:
                        conn.sendall(encode_frame(message, 0, 1))
                    else:
                        conn.sendall(encode_length_prefixed(message))

    def _awkward(self, conn):
        if self.kind == "tcp":
            frame = encode_length_prefixed(b"good")
            for piece in (frame[:1], frame[1:3], frame[3:]):
                conn.sendall(piece)
                time.sleep(0.05)
        else:
            bad = bytearray(encode_frame(b"bad!", 0, 1))
            bad[-1] ^= 0xFF
            conn.sendall(b"\x00noise\x7d" + bytes(bad) + encode_frame(b"good", 0, 1))

    def close(self):
        self.sock.close()
        self.join(5)


def _run(kind):
    peer = Peer(kind)
    peer.start()
    try:
        result = run_micropython(SCRIPT, kind, peer.port, COUNT, SIZE, timeout=120)
    finally:
        peer.close()
    assert result.returncode == 0, result.stdout + result.stderr
    lines = dict(line.split(" ", 1) for line in result.stdout.splitlines() if " " in line)
    assert lines.get("done") == "True", result.stdout
    assert lines["recv_ok"] == "True", result.stdout
    assert lines["send_bytes"] == "0", result.stdout
    assert lines["timeout_bytes"] == "0", result.stdout
    assert lines["awkward"] == "b'good'", result.stdout
    assert "unexpected" not in lines and "send_failed" not in lines, result.stdout
    return lines, peer


def _messages():
    return [bytes((index * 7 + i) & 0xFF for i in range(SIZE)) for index in range(COUNT)]


def test_udp_sends_without_allocating_and_a_datagram_received_costs_the_ports_recv():
    lines, _ = _run("udp")
    assert int(lines["recv_bytes"]) == COUNT * UDP_RECV_BYTES, lines
    assert lines["oversize"] == "1", lines
    print("udp per datagram received:", int(lines["recv_bytes"]) // COUNT, "bytes")


def test_tcp_sends_and_receives_frames_without_allocating():
    lines, peer = _run("tcp")
    assert lines["recv_frame_bytes"] == "0", lines
    assert lines["recv_frame_lengths"] == str(SIZE) and lines["recv_frame_last_ok"] == "True", lines
    # recv returns a copy: the bytes (16 + SIZE + 1) and the memoryviews it is cut through.
    assert int(lines["recv_bytes"]) == COUNT * (16 + _blocks(SIZE + 1) + 32), lines
    # The wire is what CPython's encoder writes: the warm-up, COUNT twice, AWKWARD.
    messages = _messages()
    expected = b"".join(encode_length_prefixed(m) for m in [messages[0]] + messages + messages + [b"AWKWARD"])
    assert bytes(peer.raw) == expected


def test_serial_sends_and_receives_frames_without_allocating():
    lines, peer = _run("serial")
    assert lines["recv_frame_bytes"] == "0", lines
    assert lines["recv_frame_lengths"] == str(SIZE) and lines["recv_frame_last_ok"] == "True", lines
    assert int(lines["recv_bytes"]) == COUNT * (16 + _blocks(SIZE + 1) + 32), lines
    assert lines["crc_errors"] == "1", lines
    messages = _messages()
    expected = b"".join(encode_frame(m, 1, 0) for m in [messages[0]] + messages + messages + [b"AWKWARD"])
    assert bytes(peer.raw) == expected


def test_custom_transport_with_framing_sends_without_allocating():
    # Its receive side copies each message out of the decoder (as recv does on every transport);
    # only sending was the per-message frame object that failed a small heap (issue 44).
    lines, peer = _run("custom")
    assert lines["crc_errors"] == "1", lines
    assert lines["counters"] == "%d %d" % (2 + COUNT, 2 + COUNT), lines
    messages = _messages()
    expected = b"".join(encode_frame(m, 1, 0) for m in [messages[0]] + messages + [b"AWKWARD"])
    assert bytes(peer.raw) == expected
