"""Run under MicroPython by tests/board/test_micropython_transport_heap.py: what the real client transports
allocate per message once set up, over the harness' port-like ``socket`` (tests/micropython/socket.py)
to a peer in pytest.

argv: kind port count [size]
kind: ``udp`` (UdpTransport; the peer echoes each datagram), ``tcp`` (TcpTransport; the peer echoes
each length-prefixed message), ``serial`` (SerialTransport over ``PortUart`` below, a UART whose
line is a TCP connection; the peer answers each frame with the same payload from address 0),
``custom`` (CustomTransport(framing=True) with read/write callbacks on that same line and the serial
addresses, the peer answering as for serial). To
``AWKWARD`` the peer answers with what a link may do to a message (udp: an oversize datagram first;
tcp: the message in three segments; serial: noise and a frame with a bad CRC first), then b"good".

Prints "key value" lines: ``send_bytes`` / ``recv_bytes`` are gc.mem_alloc() growth over ``count``
messages (this port collects no garbage while Python runs, so the growth is every byte allocated);
``recv_frame_bytes`` the same through recv_frame, the receive that returns the length of a message
left in the transport's buffer. Then a check that what came back is what went out.
"""

import gc
import sys

from xrce import sleep_ms

_RX_SIZE = 256


class PortUart:
    # A machine.UART as the transport uses one: any(), readinto(buf, n), write(buf, off, n), with a
    # preallocated receive buffer as a UART driver's ring (read with a byte loop: no allocation),
    # whose line is a non-blocking harness TCP socket.

    def __init__(self, sock):
        self._sock = sock
        self._rx = bytearray(_RX_SIZE)
        self._start = self._end = 0

    def any(self):
        if self._start == self._end:
            self._start = 0
            self._end = self._sock.readinto(self._rx) or 0
        return self._end - self._start

    def readinto(self, buf, count=-1):
        available = self.any()
        if count < 0 or count > len(buf):
            count = len(buf)
        if count > available:
            count = available
        start = self._start
        rx = self._rx
        for i in range(count):
            buf[i] = rx[start + i]
        self._start = start + count
        return count

    def write(self, buf, off=0, count=-1):
        return self._sock.write(buf, off, count)


def make_transport(kind, port):
    if kind == "udp":
        from xrce.transports.udp import UdpTransport

        return UdpTransport("127.0.0.1", port)
    if kind == "tcp":
        from xrce.transports.tcp import TcpTransport

        return TcpTransport("127.0.0.1", port)
    import socket

    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.connect(("127.0.0.1", port))
    sock.settimeout(0)
    if kind == "custom":
        return custom_transport(sock)
    from xrce.transports.serial import SerialTransport

    return SerialTransport(PortUart(sock))


def custom_transport(sock):
    # Callbacks as a board's would be over its own link driver: write what is offered, read what is
    # there (polled until the timeout), neither allocating.
    from xrce import ticks_add, ticks_diff, ticks_ms
    from xrce.transports.custom import CustomTransport

    def write_cb(user, data):
        return sock.write(data)

    def read_cb(user, buf, size, timeout_ms):
        deadline = ticks_add(ticks_ms(), timeout_ms)
        while True:
            count = sock.readinto(buf, size)
            if count:
                return count
            if ticks_diff(deadline, ticks_ms()) <= 0:
                return 0
            sleep_ms(1)

    return CustomTransport(lambda user: True, lambda user: True, write_cb, read_cb, framing=True,
                           local_addr=1, remote_addr=0)


def message(index, size):
    # Every byte value over the run (0x7E and 0x7D among them: escaped on a serial line).
    return bytes((index * 7 + i) & 0xFF for i in range(size))


def main():
    kind = sys.argv[1]
    port = int(sys.argv[2])
    count = int(sys.argv[3])
    size = int(sys.argv[4]) if len(sys.argv) > 4 else 200
    transport = make_transport(kind, port)
    messages = [message(i, size) for i in range(count)]
    # Set-up: one exchange each way loads and builds whatever a first message needs.
    assert transport.send(messages[0])
    first = transport.recv(5000)
    assert first == messages[0], first
    # and one wait that times out: a port's first poll that times out allocates 32 bytes once.
    assert transport.recv(10) is None
    recv_frame = getattr(transport, "recv_frame", None)

    gc.collect()
    before = gc.mem_alloc()
    for msg in messages:
        if not transport.send(msg):
            print("send_failed", 1)
    print("send_bytes", gc.mem_alloc() - before)

    if recv_frame is not None:
        if kind == "tcp" or kind == "serial":
            # All answers in: a TCP message still arriving is read in two, and its rest through a
            # memoryview (16 bytes); a serial frame is decoded byte by byte, wherever it is cut.
            sleep_ms(1000)
        got = [0] * count  # filled in place: a growing list would count its own allocations
        before = gc.mem_alloc()
        for i in range(count):
            got[i] = recv_frame(5000)
        print("recv_frame_bytes", gc.mem_alloc() - before)
        frame = transport.decoder.buffer
        last = messages[-1]
        same = got[-1] == len(last)
        for i in range(len(last)):
            same = same and frame[i] == last[i]
        print("recv_frame_lengths", ",".join(str(n) for n in set(got)))
        print("recv_frame_last_ok", same)
        for msg in messages:
            assert transport.send(msg)
    if kind != "udp":
        sleep_ms(1000)
    received = [None] * count
    before = gc.mem_alloc()
    for i in range(count):
        received[i] = transport.recv(5000)
    print("recv_bytes", gc.mem_alloc() - before)
    print("recv_ok", received == messages)
    # Waiting with nothing there: the peer sends nothing until asked.
    before = gc.mem_alloc()
    for _ in range(count):
        if transport.recv(0) is not None or (recv_frame is not None and recv_frame(0) >= 0):
            print("unexpected", 1)
    for _ in range(3):
        transport.recv(20)
    print("timeout_bytes", gc.mem_alloc() - before)
    # Hostile or awkward input the peer sends when asked: what comes back is the good message only.
    assert transport.send(b"AWKWARD")
    print("awkward", transport.recv(3000))
    if kind == "udp":
        print("oversize", transport.oversize)
    elif kind != "tcp":
        print("crc_errors", transport.decoder.crc_errors)
    print("counters", transport.sent, transport.received)
    transport.close()
    print("done", True)


main()
