# UDP client transport: one XRCE message per datagram, no extra header (XRCE-WIRE.md §12).
#
# The socket is connect()ed to the agent so the kernel drops datagrams from anyone else, as the C
# client does. The agent keys sessions >= 0x80 on the source port, so a new UdpTransport needs a new
# CREATE_CLIENT.

try:
    import socket
except ImportError:  # pragma: no cover - MicroPython ports that name it usocket
    import usocket as socket

from xrce import EncodeError, IS_MICROPYTHON, const, ticks_add, ticks_diff, ticks_ms
from xrce.transports import TransportError, is_timeout_error

DEFAULT_MTU = 512
_ECONNREFUSED = const(111)

try:
    _ConnectionRefused = ConnectionRefusedError
except NameError:  # MicroPython reports it as a plain OSError(ECONNREFUSED): the errno check finds it
    _ConnectionRefused = ()


class UdpTransport:
    # Synchronous UDP link to one agent; the constructor opens it.
    #
    # ``family`` is ``socket.AF_INET``, ``socket.AF_INET6`` or 0 (whatever ``host`` resolves to first).
    # ``send(msg) -> bool``; ``recv(timeout_ms)`` -> bytes of one message, or None after the timeout.
    # Counters: ``sent``, ``received``, ``send_errors``, ``oversize`` (datagrams longer than ``mtu``,
    # dropped), ``refused`` (ICMP port unreachable while no agent listens; recv keeps waiting),
    # ``recv_errors`` (other socket errors; recv returns None).

    __slots__ = (
        "host",
        "port",
        "mtu",
        "family",
        "sent",
        "received",
        "send_errors",
        "oversize",
        "refused",
        "recv_errors",
        "_sock",
        "_buf",
        "_view",
        "_poller",
    )

    def __init__(self, host, port, mtu=DEFAULT_MTU, family=0):
        self.host = host
        self.port = port
        self.mtu = mtu
        self.family = family
        self.sent = 0
        self.received = 0
        self.send_errors = 0
        self.oversize = 0
        self.refused = 0
        self.recv_errors = 0
        self._sock = None
        # One spare byte so that a datagram longer than the MTU is seen (and dropped) rather than
        # silently truncated into something that might parse.
        #
        # MicroPython's sockets have no recv_into, and their readinto (py/stream.c, every port:
        # unix, the lwIP ports, esp32) reads until the buffer is full: on a UDP socket it runs
        # datagrams together and waits a timeout for the next. So a board receives with
        # recv(mtu + 1), which allocates per datagram: a block of mtu + 1 bytes (the unix port
        # frees it on return, lwIP shrinks it to the datagram) and the bytes it returns (the
        # datagram, 16 bytes of object). It does so only once poll says a datagram is there
        # (select.poll().ipoll, which allocates nothing): a recv that times out would leave the
        # mtu + 1 block and an OSError behind, on every pass of a firmware's idle loop; and the
        # socket stays non-blocking, so no float timeout is made per call either.
        self._buf = self._view = self._poller = None
        if not IS_MICROPYTHON:
            self._buf = bytearray(mtu + 1)
            self._view = memoryview(self._buf)
        self.open()

    def open(self):
        if self._sock is not None:
            return
        try:
            if IS_MICROPYTHON:
                info = socket.getaddrinfo(self.host, self.port)[0]
                sock = socket.socket(info[0], socket.SOCK_DGRAM)
            else:
                info = socket.getaddrinfo(self.host, self.port, self.family, socket.SOCK_DGRAM)[0]
                sock = socket.socket(info[0], socket.SOCK_DGRAM)
            try:
                sock.connect(info[-1])
            except BaseException:
                sock.close()
                raise
        except OSError as error:
            raise TransportError("cannot open UDP to %s:%s: %s" % (self.host, self.port, error))
        self._sock = sock
        self._poller = None
        if IS_MICROPYTHON:
            try:
                import select

                poller = select.poll()
                poller.register(sock, select.POLLIN)
                sock.settimeout(0)
                self._poller = poller
            except (ImportError, AttributeError, OSError, TypeError, ValueError):
                pass  # a port without poll: recv waits in the socket (settimeout) as before

    def close(self):
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def send(self, msg):
        return self.send_from(msg, len(msg))

    def send_from(self, buf, length):
        # send(buf[:length]) without making that slice: the session sends its messages from the
        # buffers they were built in, and a board's socket writes them from there
        # (stream.write(buf, off, n), which the lwIP and unix ports give their sockets: one
        # datagram on a connected UDP socket, nothing allocated).
        if length > self.mtu:
            raise EncodeError("message of %d bytes exceeds the UDP MTU %d" % (length, self.mtu))
        if self._sock is None:
            raise TransportError("UDP transport is closed")
        try:
            if IS_MICROPYTHON:
                written = self._sock.write(buf, 0, length)
            else:
                written = self._sock.send(buf if length == len(buf) else memoryview(buf)[:length])
        except OSError:
            # A connected UDP socket reports an earlier ICMP error on the next send; the message
            # is lost, as any datagram may be, and the session's retries deal with it.
            self.send_errors += 1
            return False
        if written != length:
            self.send_errors += 1
            return False
        self.sent += 1
        return True

    def recv(self, timeout_ms):
        sock = self._sock
        if sock is None:
            raise TransportError("UDP transport is closed")
        deadline = ticks_add(ticks_ms(), timeout_ms)
        remaining = timeout_ms
        poller = self._poller
        while True:
            if poller is not None:
                ready = False
                for _ in poller.ipoll(remaining if remaining > 0 else 0):
                    ready = True
                    break
                if not ready:
                    return None
            else:
                sock.settimeout(remaining / 1000 if remaining > 0 else 0)
            try:
                if IS_MICROPYTHON:
                    data = sock.recv(self.mtu + 1)
                    size = len(data)
                else:
                    size = sock.recv_into(self._buf)
                    data = None
            except OSError as error:
                if isinstance(error, _ConnectionRefused) or (error.args and error.args[0] == _ECONNREFUSED):
                    # ICMP port unreachable from an earlier send: no agent yet. Keep waiting, the
                    # session retries its request and the agent may come up.
                    self.refused += 1
                    size = -1
                elif is_timeout_error(error):
                    return None
                else:
                    # Other errors (e.g. a network going down) end the wait the same way: datagram
                    # loss is normal for XRCE and the session's timeouts handle it.
                    self.recv_errors += 1
                    return None
            if 0 < size <= self.mtu:
                self.received += 1
                return data if data is not None else bytes(self._view[:size])
            if size > self.mtu:
                self.oversize += 1
            remaining = ticks_diff(deadline, ticks_ms())
            if remaining <= 0:
                return None
