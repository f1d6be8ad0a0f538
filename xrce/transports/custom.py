# User-supplied transport callbacks, shaped like micro-ROS' ``rmw_uros_set_custom_transport``.
#
# Callbacks (``user`` is passed through untouched):
#
# - ``open_cb(user) -> bool`` and ``close_cb(user) -> bool``
# - ``write_cb(user, data) -> int``: bytes written, possibly fewer than ``len(data)`` (the rest is
#   offered again); 0 or less means the link failed.
# - ``read_cb(user, buf, size, timeout_ms) -> int``: fill the preallocated bytearray ``buf`` with up
#   to ``size`` bytes, return the count, 0 on timeout.
#
# ``framing=True`` (stream links: UART, USB CDC, pipes): bytes go through §11 framing with addresses
# ``local_addr``/``remote_addr``, both 0 by default as micro-ROS custom transports use them.
# ``framing=False`` (packet links): each ``read_cb`` returns one whole message and each ``send`` is
# a single ``write_cb`` call.

from xrce import EncodeError, ticks_add, ticks_diff, ticks_ms
from xrce.transports import TransportError

# Framing and its CRC tables load only for framing=True: a packet link never pays for them.

DEFAULT_MTU = 512
# Bytes asked of read_cb per call with framing; the C client's ring is smaller still (42).
_FRAMED_READ_SIZE = 256


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
        "_encode_frame",
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
            from xrce.transports.framing import FrameDecoder, encode_frame

            self._crc = get_crc(crc)
            self._encode_frame = encode_frame
            self.decoder = FrameDecoder(local_addr=local_addr, max_payload=mtu, crc=self._crc)
            self._buf = bytearray(_FRAMED_READ_SIZE)
        else:
            self._crc = self._encode_frame = None
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
        frame = memoryview(self._encode_frame(msg, self.local_addr, self.remote_addr, self._crc))
        position = 0
        while position < len(frame):
            written = self._write_cb(self.user, frame[position:])
            if not written or written < 0:
                self.send_errors += 1
                return False
            position += written
        self.sent += 1
        return True

    def recv(self, timeout_ms):
        if not self._is_open:
            raise TransportError("custom transport is closed")
        if self._pending:
            self.received += 1
            return self._pending.pop(0)
        deadline = ticks_add(ticks_ms(), timeout_ms)
        if not self.framing:
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
        remaining = timeout_ms
        while True:
            size = self._read_cb(self.user, self._buf, len(self._buf), remaining if remaining > 0 else 0)
            if size and size > 0:
                for src, _dst, payload in self.decoder.feed(self._view[:size]):
                    if src != self.remote_addr:
                        self.wrong_source += 1
                    else:
                        self._pending.append(payload)
                if self._pending:
                    self.received += 1
                    return self._pending.pop(0)
            remaining = ticks_diff(deadline, ticks_ms())
            if remaining <= 0:
                return None
