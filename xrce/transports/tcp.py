# TCP client transport: each message preceded by its 2-byte LE length, both ways (XRCE-WIRE.md §12).
#
# No reconnection: after a broken stream or the agent closing, the session is gone anyway (the agent
# ties it to the connection), so errors surface as TransportError and the owner starts over.

try:
    import socket
except ImportError:  # pragma: no cover - MicroPython ports that name it usocket
    import usocket as socket

from xrce import EncodeError, IS_MICROPYTHON, ticks_add, ticks_diff, ticks_ms
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
        self._buf = self._view = None
        if not IS_MICROPYTHON:
            self._buf = bytearray(mtu + 2)
            self._view = memoryview(self._buf)
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

    def close(self):
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def _fail(self, reason):
        self.close()
        raise TransportError(reason)

    def send(self, msg):
        if len(msg) > self.mtu:
            raise EncodeError("message of %d bytes exceeds the TCP MTU %d" % (len(msg), self.mtu))
        sock = self._sock
        if sock is None:
            raise TransportError("TCP transport is closed")
        data = memoryview(encode_length_prefixed(msg))
        sock.settimeout(self.send_timeout_ms / 1000)
        position = 0
        while position < len(data):
            try:
                written = sock.send(data[position:])
            except OSError as error:
                self.send_errors += 1
                if position == 0:
                    return False
                # Part of a length-prefixed message is on the wire: the peer's framing is lost.
                self._fail("TCP send failed mid-message: %s" % (error,))
            if not written:
                self.send_errors += 1
                self._fail("TCP connection closed while sending")
            position += written
        self.sent += 1
        return True

    def recv(self, timeout_ms):
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
