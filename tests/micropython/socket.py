"""A ``socket`` module for MicroPython's WebAssembly port, which has none, built on run.mjs' nodeudp
bridge, that allocates what a port's socket allocates, so that a capped run shows a board's figures.

It offers what a client uses on a board (getaddrinfo, socket(AF_INET, SOCK_DGRAM | SOCK_STREAM),
connect, settimeout, setblocking, send, write, recv, readinto, close) with the semantics and the
heap use of MicroPython 1.27's unix port (ports/unix/modsocket.c and py/stream.c), which the issue's
runs on a real socket used:

- ``recv(n)`` allocates an n-byte buffer, receives into it and returns a new ``bytes`` of what came
  (one datagram, cut to n; on a stream, what is there up to n). The port frees its n-byte buffer at
  once (m_del); here it is garbage until the next collection, so a capped run counts ~n bytes more
  per receive than a board's peak: stricter, never looser. lwIP ports (rp2, esp8266, stm32)
  allocate n + 1 and shrink it in place to the datagram.
- ``readinto(buf[, nbytes])`` fills the caller's buffer and allocates nothing, but, as
  ``mp_stream_rw`` does on every port, it keeps reading until ``nbytes`` are in: on a UDP socket
  it runs datagrams together and waits a timeout for the next one before it returns what it has
  (None when nothing came). This is why UdpTransport cannot use it.
- ``send(data)`` and ``write(buf[, off, n])`` read the caller's buffer in place and allocate
  nothing (nodeudp.send_at).
- A timeout, or nothing there on a non-blocking socket, is OSError(EAGAIN), as SO_RCVTIMEO gives
  on the unix port (whose recv leaves its n-byte buffer behind as garbage then, as this one does).
- ``select.poll`` works on it (an ``io.IOBase`` whose ``ioctl`` answers MP_STREAM_POLL, waiting up
  to 1 ms for input each time poll asks, so a poll with a timeout does not spin the CPU), and
  ``ipoll`` then allocates nothing, as on a port.

SOCK_STREAM is a real TCP connection in run.mjs' worker (nodeudp.open_tcp), read as one byte
stream; ``readinto`` then returns 0 at the end of the stream, as the port's does.
"""

import gc
import io

from uctypes import addressof

import nodeudp

AF_INET = 2
AF_INET6 = 10
SOCK_STREAM = 1
SOCK_DGRAM = 2
IPPROTO_TCP = 6
TCP_NODELAY = 1
_EAGAIN = 11
_EIO = 5
_ECONNREFUSED = 111
_EBADF = 9
_MP_STREAM_POLL = 3
_POLLIN = 1
_POLLOUT = 4


# Every byte recv() has allocated (gc.mem_alloc() growth inside it): the socket's own garbage, which
# tests/micropython/session_alloc.py subtracts from what a session allocates.
recv_allocated = 0


def getaddrinfo(host, port, af=0, type=0, proto=0, flags=0):
    return [(AF_INET, type or SOCK_DGRAM, 0, "", (host, port))]


class socket(io.IOBase):
    def __init__(self, af=AF_INET, type=SOCK_DGRAM, proto=0):
        self._handle = None
        self._timeout_ms = None  # None: blocking
        self._stream = type == SOCK_STREAM

    def connect(self, address):
        handle = (nodeudp.open_tcp if self._stream else nodeudp.open)(address[0], address[1])
        if handle < 0:
            raise OSError(_ECONNREFUSED)
        self._handle = handle

    def setsockopt(self, level, option, value):
        pass

    def settimeout(self, seconds):
        self._timeout_ms = None if seconds is None else int(seconds * 1000)

    def setblocking(self, flag):
        self._timeout_ms = None if flag else 0

    def _check(self):
        if self._handle is None:
            raise OSError(_EBADF)

    def send(self, data):
        self._check()
        written = nodeudp.send_at(self._handle, addressof(data), len(data))
        if written < 0:
            raise OSError(_EIO)
        return written

    def write(self, buf, off=0, count=-1):
        # py/stream.c: write(buf), write(buf, max_len), write(buf, off, max_len).
        self._check()
        size = len(buf) - off
        if count >= 0 and count < size:
            size = count
        written = nodeudp.send_at(self._handle, addressof(buf) + off, size)
        if written < 0:
            raise OSError(_EIO)
        return written

    def _read(self, address, size, wait):
        count = nodeudp.recv_into(self._handle, address, size, self._timeout_ms if wait else 0, self._stream)
        if count is not None and count < 0:
            raise OSError(_EIO)
        return count

    def recv(self, size):
        global recv_allocated
        self._check()
        before = gc.mem_alloc()
        buf = bytearray(size)  # the port's m_new(byte, size)
        count = self._read(addressof(buf), size, True)
        if count is None:
            recv_allocated += gc.mem_alloc() - before
            raise OSError(_EAGAIN)
        data = bytes(memoryview(buf)[:count])
        recv_allocated += gc.mem_alloc() - before
        return data

    def readinto(self, buf, nbytes=-1):
        self._check()
        size = len(buf) if nbytes < 0 or nbytes > len(buf) else nbytes
        address = addressof(buf)
        done = 0
        count = None
        while done < size:
            # Every read waits as the socket's timeout says, as the port's read() does.
            count = self._read(address + done, size - done, True)
            if not count:  # nothing in time, or the end of a stream
                break
            done += count
        if not done and count is None:
            return None  # EAGAIN: mp_stream_rw's "nothing read" on a non-blocking stream
        return done

    def ioctl(self, request, arg):
        if request != _MP_STREAM_POLL or self._handle is None:
            return 0
        ready = arg & _POLLOUT
        if arg & _POLLIN and nodeudp.readable(self._handle, 1) > 0:
            ready |= _POLLIN
        return ready

    def close(self):
        if self._handle is not None:
            nodeudp.close(self._handle)
            self._handle = None
