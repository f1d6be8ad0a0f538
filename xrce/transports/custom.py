# User-supplied transport callbacks, shaped like micro-ROS' ``rmw_uros_set_custom_transport``.
#
# Callbacks (``user`` is passed through untouched):
#
# - ``open_cb(user) -> bool`` and ``close_cb(user) -> bool``
# - ``write_cb(user, data) -> int``: bytes written, possibly fewer than ``len(data)`` (the rest is
#   offered again); 0 or less means the link failed. ``data`` is valid only during the call (with
#   framing it is the transport's own 64-byte piece buffer, refilled for the next piece): a
#   callback that queues bytes copies them.
# - ``read_cb(user, buf, size, timeout_ms) -> int``: fill the preallocated bytearray ``buf`` with up
#   to ``size`` bytes, return the count, 0 on timeout.
#
# ``framing=True`` (stream links: UART, USB CDC, pipes): bytes go through §11 framing with addresses
# ``local_addr``/``remote_addr``, both 0 by default as micro-ROS custom transports use them.
# ``framing=False`` (packet links): each ``read_cb`` returns one whole message and each ``send`` is
# a single ``write_cb`` call.

from xrce import EncodeError, const, ticks_add, ticks_diff, ticks_ms
from xrce.transports import TransportError

# Framing and its CRC tables load only for framing=True: a packet link never pays for them.

DEFAULT_MTU = 512
# Bytes asked of read_cb per call with framing; the C client's ring is smaller still (42).
_FRAMED_READ_SIZE = 256
# With framing a frame goes to write_cb in pieces of at most this many bytes, escaped as they are
# built (SerialTransport's scheme): a frame object per message (up to 2 * (mtu + 6) + 1 bytes in one
# piece) was what a small heap could not find once it was cut up.
_PIECE = const(64)
_SPARE = bytes(_PIECE)


class CustomTransport:
    # Synchronous transport over user callbacks; the constructor calls ``open_cb``.
    #
    # ``send(msg) -> bool`` (False when ``write_cb`` reports failure; counted in ``send_errors``);
    # ``recv(timeout_ms)`` -> bytes of one message or None after the timeout. Counters: ``sent``,
    # ``received``, ``send_errors``, ``oversize`` (packets longer than ``mtu``, framing=False),
    # ``wrong_source`` and, with framing, the decoder's counters in ``decoder``.

    __slots__ = (
        "framing",
        "mtu",
        "local_addr",
        "remote_addr",
        "user",
        "sent",
        "received",
        "send_errors",
        "oversize",
        "wrong_source",
        "decoder",
        "_open_cb",
        "_close_cb",
        "_write_cb",
        "_read_cb",
        "_crc",
        "_out",
        "_frame",
        "_flush",
        "_is_open",
        "_pending",
        "_buf",
        "_view",
    )

    def __init__(
        self,
        open_cb,
        close_cb,
        write_cb,
        read_cb,
        framing=True,
        mtu=DEFAULT_MTU,
        crc="arc",
        local_addr=0,
        remote_addr=0,
        user=None,
    ):
        self._open_cb = open_cb
        self._close_cb = close_cb
        self._write_cb = write_cb
        self._read_cb = read_cb
        self.framing = framing
        self.mtu = mtu
        self.local_addr = local_addr
        self.remote_addr = remote_addr
        self.user = user
        self.sent = 0
        self.received = 0
        self.send_errors = 0
        self.oversize = 0
        self.wrong_source = 0
        self._pending = []
        if framing:
            from xrce.transports.crc import get_crc
            from xrce.transports.framing import FrameDecoder, write_frame

            self._crc = get_crc(crc)
            self.decoder = FrameDecoder(local_addr=local_addr, max_payload=mtu, crc=self._crc)
            self._buf = bytearray(_FRAMED_READ_SIZE)
            out = self._out = bytearray(2 * _PIECE)
            out[_PIECE:] = b""  # _PIECE long, _PIECE bytes to spare in its block (see _piece)
            self._frame = write_frame  # framing.py's, loaded only here (see above)
            self._flush = self._piece  # bound once: a bound method per send is an allocation
        else:
            self._crc = self._out = self._frame = self._flush = None
            self.decoder = None
            # One spare byte so an over-long packet is detected instead of cut to a plausible one.
            self._buf = bytearray(mtu + 1)
        self._view = memoryview(self._buf)
        self._is_open = False
        self.open()

    def open(self):
        if self._is_open:
            return
        if not self._open_cb(self.user):
            raise TransportError("custom transport open callback failed")
        self._is_open = True
        self._pending = []
        if self.decoder is not None:
            self.decoder.reset()

    def close(self):
        if self._is_open:
            self._is_open = False
            self._close_cb(self.user)

    def send(self, msg):
        if len(msg) > self.mtu:
            raise EncodeError("message of %d bytes exceeds the custom transport MTU %d" % (len(msg), self.mtu))
        if not self._is_open:
            raise TransportError("custom transport is closed")
        if not self.framing:
            written = self._write_cb(self.user, msg)
            if written != len(msg):
                self.send_errors += 1
                return False
            self.sent += 1
            return True
        # encode_frame's bytes, escaped into _out and handed to write_cb a piece at a time
        # (framing.write_frame, SerialTransport's scheme too): no frame object. Inline, not a
        # method: each method is an entry of the class's dictionary in a board's heap.
        if not self._frame(self._out, _PIECE, msg, self.local_addr, self.remote_addr,
                           self._crc(msg), self._flush):
            self.send_errors += 1
            return False
        self.sent += 1
        return True

    def _piece(self, n):
        # _out[:n] to write_cb as _out itself, cut to n in place: a bytearray shortened by slice
        # assignment keeps its block, and grows back into it (it was made with _PIECE bytes to spare),
        # where a slice or memoryview of it would be an object per piece. What write_cb leaves is
        # moved to the front and offered again.
        out = self._out
        if n < _PIECE:
            out[n:] = b""
        done = True
        while out:
            written = self._write_cb(self.user, out)
            if not written or written < 0:
                done = False
                break
            out[0:written] = b""
        out[0:] = _SPARE  # back to _PIECE long (the bytes are overwritten before they are sent)
        return done

    def recv(self, timeout_ms):
        if not self._is_open:
            raise TransportError("custom transport is closed")
        if self.framing:
            return self.decoder.receive(self, timeout_ms)
        deadline = ticks_add(ticks_ms(), timeout_ms)
        remaining = timeout_ms
        while True:
            size = self._read_cb(self.user, self._buf, self.mtu + 1, remaining if remaining > 0 else 0)
            if size and 0 < size <= self.mtu:
                self.received += 1
                return bytes(self._view[:size])
            if size and size > self.mtu:
                self.oversize += 1
            remaining = ticks_diff(deadline, ticks_ms())
            if remaining <= 0:
                return None

    def _read_available(self, wait_ms):
        # FrameDecoder.receive's read: what read_cb gives within wait_ms, into _buf.
        return self._read_cb(self.user, self._buf, len(self._buf), wait_ms if wait_ms > 0 else 0)
