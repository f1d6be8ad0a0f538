"""A ``socket`` module for MicroPython's WebAssembly port, which has none, built on run.mjs' nodeudp
bridge. It offers what a UDP client uses on a board (getaddrinfo, socket(AF_INET, SOCK_DGRAM),
connect, settimeout, send, recv, close) with MicroPython's error behaviour (OSError(ETIMEDOUT) on a
timeout), so that ``xrce.transports.udp.UdpTransport`` runs its MicroPython path unchanged here."""

import nodeudp

AF_INET = 2
AF_INET6 = 10
SOCK_STREAM = 1
SOCK_DGRAM = 2
_ETIMEDOUT = 110
_EIO = 5
_ECONNREFUSED = 111
_EOPNOTSUPP = 95


def getaddrinfo(host, port, af=0, type=0, proto=0, flags=0):
    return [(AF_INET, SOCK_DGRAM, 0, "", (host, port))]


class socket:
    def __init__(self, af=AF_INET, type=SOCK_DGRAM, proto=0):
        if type != SOCK_DGRAM:
            raise OSError(_EOPNOTSUPP)
        self._handle = None
        self._timeout = None

    def connect(self, address):
        handle = nodeudp.open(address[0], address[1])
        if handle < 0:
            raise OSError(_ECONNREFUSED)
        self._handle = handle

    def settimeout(self, seconds):
        self._timeout = seconds

    def setblocking(self, flag):
        self._timeout = None if flag else 0

    def send(self, data):
        written = nodeudp.send(self._handle, data)
        if written < 0:
            raise OSError(_EIO)
        return written

    def recv(self, size):
        timeout_ms = None if self._timeout is None else int(self._timeout * 1000)
        data = nodeudp.recv(self._handle, timeout_ms)
        if data is None:
            raise OSError(_ETIMEDOUT)
        if isinstance(data, int):
            raise OSError(_EIO)
        return data[:size]

    def close(self):
        if self._handle is not None:
            nodeudp.close(self._handle)
            self._handle = None
