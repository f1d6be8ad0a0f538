# TCP client transport: each message preceded by its 2-byte LE length, both ways (XRCE-WIRE.md §12).
#
# No reconnection: after a broken stream or the agent closing, the session is gone anyway (the agent
# ties it to the connection), so errors surface as TransportError and the owner starts over.

try:
    import socket
except ImportError:  # pragma: no cover - MicroPython ports that name it usocket
    import usocket as socket

from xrce import EncodeError, IS_MICROPYTHON, sleep_ms, ticks_add, ticks_diff, ticks_ms
from xrce.transports import TransportError, is_timeout_error
from xrce.transports.framing import LengthPrefixDecoder, encode_length_prefixed

DEFAULT_MTU = 512


class TcpTransport:
    # Synchronous TCP link to one agent; the constructor connects.
    #
    # ``send(msg) -> bool``; ``recv(timeout_ms)`` -> bytes of one message, or None after the timeout;
    # raises TransportError when the agent closed the connection or the stream lost sync. One segment
    # may carry several messages: the extra ones are queued and returned by the next recv calls.
    # Counters: ``sent``, ``received``, ``send_errors``, and the decoder's in ``decoder``.
    #
    # ``recv_frame(timeout_ms)`` -> the length of the message now in ``decoder.buffer`` (valid
    # until the next receive), or -1 after the timeout. On MicroPython it is how the transport
    # receives, allocating nothing: the socket is non-blocking and ``readinto`` takes the 2-byte
    # prefix, then exactly that message, into preallocated buffers (the rest stays in the socket);
    # only a message the network split mid-way costs a memoryview (~16 bytes) to read its rest.
    # It waits with ``select.poll().ipoll`` (allocation-free; a socket object that cannot be
    # polled, 1 ms sleeps). ``send`` copies the prefix and message into a preallocated buffer and
    # writes it with ``sock.write(buf, off, n)``. ``recv`` returns a copy of the frame.

    __slots__ = (
        "host",
        "port",
        "mtu",
        "family",
        "connect_timeout_ms",
        "send_timeout_ms",
        "sent",
        "received",
        "send_errors",
        "decoder",
        "_sock",
        "_pending",
        "_buf",
        "_view",
        "_out",
        "_prefix",
        "_poller",
        "_length",
        "_filled",
    )

    def __init__(self, host, port, mtu=DEFAULT_MTU, family=0, connect_timeout_ms=5000, send_timeout_ms=1000):
        self.host = host
        self.port = port
        self.mtu = mtu
        self.family = family
        self.connect_timeout_ms = connect_timeout_ms
        self.send_timeout_ms = send_timeout_ms
        self.sent = 0
        self.received = 0
        self.send_errors = 0
        self.decoder = None
        self._sock = None
        self._pending = []
        # A read takes at most one whole message with its prefix. MicroPython's sockets have no
        # recv_into: there recv() allocates anyway, so a board keeps no buffer for it.
        self._buf = self._view = self._out = self._prefix = self._poller = None
        if IS_MICROPYTHON:
            self._out = bytearray(mtu + 2)
            self._prefix = bytearray(2)
        else:
            self._buf = bytearray(mtu + 2)
            self._view = memoryview(self._buf)
        self._length = self._filled = 0  # a board's message being read: its length (0: the prefix)
        self.open()

    def open(self):
        if self._sock is not None:
            return
        try:
            if IS_MICROPYTHON:
                info = socket.getaddrinfo(self.host, self.port)[0]
            else:
                info = socket.getaddrinfo(self.host, self.port, self.family, socket.SOCK_STREAM)[0]
            sock = socket.socket(info[0], socket.SOCK_STREAM)
            try:
                sock.settimeout(self.connect_timeout_ms / 1000)
                sock.connect(info[-1])
                nodelay = getattr(socket, "TCP_NODELAY", None)
                if nodelay is not None and hasattr(socket, "IPPROTO_TCP"):
                    # XRCE messages are small and latency-bound; Nagle would hold them back.
                    sock.setsockopt(socket.IPPROTO_TCP, nodelay, 1)
            except BaseException:
                sock.close()
                raise
        except OSError as error:
            raise TransportError("cannot connect TCP to %s:%s: %s" % (self.host, self.port, error))
        self._sock = sock
        self.decoder = LengthPrefixDecoder(self.mtu)
        self._pending = []
        self._length = self._filled = 0
        if IS_MICROPYTHON:
            sock.settimeout(0)
            self._poller = None
            try:
                import select

                poller = select.poll()
                poller.register(sock, select.POLLIN)
                self._poller = poller
            except (ImportError, AttributeError, OSError, TypeError, ValueError):
                pass

    def close(self):
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def _fail(self, reason):
        self.close()
        raise TransportError(reason)

    def _send_failed(self, position, reason, detail=None):
        # Counts a failed send. Nothing of the message on the wire yet: False, the caller may try
        # again. Part of it sent: the peer's framing is lost, so the connection closes (raises).
        self.send_errors += 1
        if position == 0:
            return False
        self._fail(reason if detail is None else reason % (detail,))

    def send(self, msg):
        if len(msg) > self.mtu:
            raise EncodeError("message of %d bytes exceeds the TCP MTU %d" % (len(msg), self.mtu))
        sock = self._sock
        if sock is None:
            raise TransportError("TCP transport is closed")
        if IS_MICROPYTHON:
            return self._send_mp(sock, msg)
        data = memoryview(encode_length_prefixed(msg))
        sock.settimeout(self.send_timeout_ms / 1000)
        position = 0
        while position < len(data):
            try:
                written = sock.send(data[position:])
            except OSError as error:
                return self._send_failed(position, "TCP send failed mid-message: %s", error)
            if not written:
                self.send_errors += 1
                self._fail("TCP connection closed while sending")
            position += written
        self.sent += 1
        return True

    def _send_mp(self, sock, msg):
        out = self._out
        length = len(msg)
        if not length:
            raise EncodeError("length-prefixed message must be 1..65535 bytes, not 0")
        out[0] = length & 0xFF
        out[1] = length >> 8
        for i in range(length):  # a slice assignment would make a slice object
            out[i + 2] = msg[i]
        total = length + 2
        position = 0
        deadline = ticks_add(ticks_ms(), self.send_timeout_ms)
        while position < total:
            try:
                written = sock.write(out, position, total - position)
            except OSError as error:
                if not is_timeout_error(error):
                    return self._send_failed(position, "TCP send failed mid-message: %s", error)
                written = None
            if written is None:  # non-blocking socket, send buffer full
                if ticks_diff(deadline, ticks_ms()) <= 0:
                    return self._send_failed(position, "TCP send timed out mid-message")
                sleep_ms(1)
                continue
            if not written:
                self.send_errors += 1
                self._fail("TCP connection closed while sending")
            position += written
        self.sent += 1
        return True

    def _wait_readable(self, wait_ms):
        if self._poller is None:
            sleep_ms(1 if wait_ms > 0 else 0)
            return
        for _ in self._poller.ipoll(wait_ms):
            break

    def _read(self, sock, buf, count):
        # readinto of up to ``count`` bytes: their number, None when nothing is there yet.
        try:
            got = sock.readinto(buf, count)
        except OSError as error:
            if is_timeout_error(error):
                return None
            self._fail("TCP receive failed: %s" % (error,))
        if got == 0:
            self._fail("agent closed the TCP connection")
        return got

    def recv_frame(self, timeout_ms):
        if not IS_MICROPYTHON:
            data = self.recv(timeout_ms)
            if data is None:
                return -1
            self.decoder.buffer[: len(data)] = data
            return len(data)
        sock = self._sock
        if sock is None:
            raise TransportError("TCP transport is closed")
        decoder = self.decoder
        deadline = ticks_add(ticks_ms(), timeout_ms)
        while True:
            length = self._length
            if not length:
                first = self._filled  # 0, or 0x100 | the prefix's first byte when it came alone
                if first:
                    got = self._read(sock, self._prefix, 1)
                    if got is not None:
                        self._prefix[1] = self._prefix[0]
                        self._prefix[0] = first & 0xFF
                else:
                    got = self._read(sock, self._prefix, 2)
                    if got == 1:
                        self._filled = 0x100 | self._prefix[0]
                        got = None
                if got is not None:
                    self._filled = 0
                    length = self._prefix[0] | (self._prefix[1] << 8)
                    if not decoder.accepts_length(length):
                        self._fail("TCP stream lost sync (bad length prefix)")
                    self._length = length
            if length:
                filled = self._filled
                if filled:
                    got = self._read(sock, memoryview(decoder.buffer)[filled:], length - filled)
                else:
                    got = self._read(sock, decoder.buffer, length)
                if got is not None:
                    filled += got
                    if filled == length:
                        self._length = self._filled = 0
                        decoder.messages += 1
                        self.received += 1
                        return length
                    self._filled = filled
                    continue
            remaining = ticks_diff(deadline, ticks_ms())
            if remaining <= 0:
                return -1
            self._wait_readable(remaining)

    def recv(self, timeout_ms):
        if IS_MICROPYTHON:
            length = self.recv_frame(timeout_ms)
            return None if length < 0 else bytes(memoryview(self.decoder.buffer)[:length])
        if self._pending:
            self.received += 1
            return self._pending.pop(0)
        sock = self._sock
        if sock is None:
            raise TransportError("TCP transport is closed")
        deadline = ticks_add(ticks_ms(), timeout_ms)
        remaining = timeout_ms
        while True:
            sock.settimeout(remaining / 1000 if remaining > 0 else 0)
            try:
                if IS_MICROPYTHON:
                    chunk = sock.recv(self.mtu + 2)
                else:
                    chunk = self._view[: sock.recv_into(self._buf)]
            except OSError as error:
                if is_timeout_error(error):
                    return None
                self._fail("TCP receive failed: %s" % (error,))
            if not len(chunk):
                self._fail("agent closed the TCP connection")
            messages = self.decoder.feed(chunk)
            if self.decoder.broken:
                self._fail("TCP stream lost sync (bad length prefix)")
            if messages:
                self._pending.extend(messages[1:])
                self.received += 1
                return messages[0]
            remaining = ticks_diff(deadline, ticks_ms())
            if remaining <= 0:
                return None
