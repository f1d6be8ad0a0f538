# Byte-stream framing for XRCE messages: HDLC-like serial frames and the TCP length prefix.
#
# Pure: bytes in, messages out, no I/O, so the asyncio agent and the MicroPython client share it
# (FrameDecoder.receive, the client's framed links' receive loop, reads through the transport it is given).
#
# Serial frame (XRCE-WIRE.md §11)::
#
#     7E | src | dst | len_lo | len_hi | payload (len bytes) | crc_lo | crc_hi
#
# Only the leading 0x7E is a flag; there is no end flag. Every byte after it equal to 0x7E or 0x7D
# is sent as 0x7D, byte ^ 0x20. The CRC (CRC-16/ARC by default) covers the unescaped payload only.
#
# TCP (XRCE-WIRE.md §12): a 2-byte little-endian length, then the message, in both directions.

from xrce import EncodeError, const, ticks_add, ticks_diff, ticks_ms
from xrce.transports.crc import crc16_arc, crc_of_prefix

FLAG = const(0x7E)
ESCAPE = const(0x7D)
ESCAPE_XOR = const(0x20)
# The 16-bit length field caps every frame; it is also the agent's receive buffer size.
MAX_FRAME_PAYLOAD = const(65535)

_FLAG_BYTES = b"\x7e"
_ESCAPE_BYTES = b"\x7d"
_ESCAPED_FLAG = b"\x7d\x5e"
_ESCAPED_ESCAPE = b"\x7d\x5d"

# FrameDecoder states: hunting for a flag, then one state per field.
_HUNT = const(0)
_SRC = const(1)
_DST = const(2)
_LEN_LO = const(3)
_LEN_HI = const(4)
_PAYLOAD = const(5)
_CRC_LO = const(6)
_CRC_HI = const(7)


def encode_frame(payload, src, dst, crc=crc16_arc):
    # One serial frame carrying ``payload`` (one complete XRCE message) from ``src`` to ``dst``.
    length = len(payload)
    if length > MAX_FRAME_PAYLOAD:
        raise EncodeError("frame payload of %d bytes exceeds 65535" % length)
    if not (0 <= src <= 255 and 0 <= dst <= 255):
        raise EncodeError("frame addresses must be 0..255")
    check = crc(payload)
    body = (
        bytes((src, dst, length & 0xFF, length >> 8))
        + bytes(payload)
        + bytes((check & 0xFF, check >> 8))
    )
    # C-speed escaping: bytes.replace runs in C on CPython and MicroPython alike, and the common
    # case (nothing to escape) costs two scans and no copy. 0x7D must be escaped before 0x7E,
    # otherwise the escape bytes inserted for 0x7E would be escaped again.
    if _ESCAPE_BYTES in body:
        body = body.replace(_ESCAPE_BYTES, _ESCAPED_ESCAPE)
    if _FLAG_BYTES in body:
        body = body.replace(_FLAG_BYTES, _ESCAPED_FLAG)
    return _FLAG_BYTES + body


def write_frame(out, size, msg, src, dst, check, flush):
    # encode_frame's bytes for ``msg`` (``check`` its CRC), escaped into ``out`` (``size`` bytes) as
    # they are made and handed to ``flush(n)`` (``out[:n]``) a piece at a time: no frame object, so
    # nothing allocated per message. False as soon as ``flush`` is. The message's own bytes are
    # walked by iterating it (no index arithmetic per byte: this loop is where a board spends its
    # sending time). SerialTransport and CustomTransport(framing=True) send through it.
    length = len(msg)
    last = size - 1  # once: the per-byte test below is the loop's cost on a board
    out[0] = FLAG
    n = 1
    for k in range(4):
        if k == 0:
            byte = src
        elif k == 1:
            byte = dst
        elif k == 2:
            byte = length & 0xFF
        else:
            byte = length >> 8
        if byte == FLAG or byte == ESCAPE:
            out[n] = ESCAPE
            n += 1
            byte ^= ESCAPE_XOR
        out[n] = byte
        n += 1
    for byte in msg:
        if byte == FLAG or byte == ESCAPE:
            out[n] = ESCAPE
            n += 1
            byte ^= ESCAPE_XOR
        out[n] = byte
        n += 1
        if n >= last:  # an escaped byte takes two
            if not flush(n):
                return False
            n = 0
    for k in range(2):
        byte = check >> 8 if k else check & 0xFF
        if byte == FLAG or byte == ESCAPE:
            out[n] = ESCAPE
            n += 1
            byte ^= ESCAPE_XOR
        out[n] = byte
        n += 1
        if n >= last and not k:  # the check byte after it, escaped, must fit too
            if not flush(n):
                return False
            n = 0
    return flush(n)


class FrameDecoder:
    # Streaming decoder of serial frames, fed arbitrary chunks of the byte stream.
    #
    # ``feed(data)`` returns a list (possibly empty) of ``(src, dst, payload)`` tuples, one per complete
    # frame, payload as ``bytes``, in stream order. Chunk boundaries may fall anywhere.
    #
    # It hunts for 0x7E; a 0x7E inside a frame abandons that frame and starts a new one (``resyncs``).
    # Frames with a bad CRC (``crc_errors``), a length above ``max_payload`` (``oversize``; the decoder
    # then hunts for the next flag) or, when ``local_addr`` is not None, a dst other than
    # ``local_addr`` (``wrong_address``, counted only for frames whose CRC is good) are dropped.
    # ``dropped_bytes`` counts raw bytes discarded while hunting plus the raw bytes (flag included) of
    # every dropped or abandoned frame, ``pending_bytes`` those of the frame in progress (neither
    # returned nor dropped yet). ``frames`` counts frames returned. (All plain attributes: on a
    # board each method or property is an entry of the class's dictionary, in the heap.)
    #
    # Memory is one preallocated ``max_payload`` buffer plus the returned payloads, whatever is fed.
    #
    # ``scan(buf, start, end)`` is the same decoder without the allocations (for a board, where
    # ``feed``'s bytes copy, list, tuples and payloads are heap objects at message rate): it reads
    # ``buf[start:end]`` byte by byte up to the end of the first complete frame and returns the index
    # after what it used. ``frame_length`` is then that frame's payload length (-1: none completed),
    # the payload is ``buffer[:frame_length]`` (valid until the next call) and ``frame_src`` /
    # ``frame_dst`` its addresses. Both run one state machine (``_decode``) on one state and one set
    # of counters: a stream may mix them.

    __slots__ = (
        "local_addr",
        "max_payload",
        "frames",
        "crc_errors",
        "oversize",
        "resyncs",
        "dropped_bytes",
        "wrong_address",
        "buffer",
        "frame_length",
        "frame_src",
        "frame_dst",
        "_crc",
        "_view",
        "_state",
        "_escaped",
        "pending_bytes",
        "_src",
        "_dst",
        "_length",
        "_filled",
        "_crc_rx",
    )

    def __init__(self, local_addr=None, max_payload=MAX_FRAME_PAYLOAD, crc=crc16_arc):
        if not 0 <= max_payload <= MAX_FRAME_PAYLOAD:
            raise ValueError("max_payload must be 0..65535")
        self.local_addr = local_addr
        self.max_payload = max_payload
        self._crc = crc
        self.buffer = bytearray(max_payload)
        self._view = memoryview(self.buffer)
        self.frame_length = -1
        self.frame_src = self.frame_dst = 0
        self.frames = 0
        self.crc_errors = 0
        self.oversize = 0
        self.resyncs = 0
        self.dropped_bytes = 0
        self.wrong_address = 0
        self._state = _HUNT
        self._escaped = False
        self.pending_bytes = 0  # flag included
        self._src = 0
        self._dst = 0
        self._length = 0
        self._filled = 0
        self._crc_rx = 0

    def reset(self):
        # Forget any frame in progress (its bytes count as dropped) and hunt for the next flag.
        self.dropped_bytes += self.pending_bytes
        self.pending_bytes = 0
        self._state = _HUNT
        self._escaped = False

    def feed(self, data):
        if type(data) is not bytes:
            # bytes.find is the fast path below; MicroPython's bytearray and memoryview lack find.
            data = bytes(data)
        frames = []
        self._decode(data, 0, len(data), frames)
        return frames

    def receive(self, transport, timeout_ms):
        # The receive loop of the client's framed links (SerialTransport on CPython,
        # CustomTransport with framing), whose decoder this is: bytes from
        # ``transport._read_available(wait_ms)`` (their count, into ``transport._view``) until a
        # frame from ``transport.remote_addr`` is queued in ``transport._pending`` (frames from
        # elsewhere count in ``wrong_source``) or ``timeout_ms`` has passed: the first queued
        # payload, or None. A method rather than a function of the module: on a frozen board a
        # module global grew framing's dictionary, 96 B of heap after set-up.
        pending = transport._pending
        if pending:
            transport.received += 1
            return pending.pop(0)
        deadline = ticks_add(ticks_ms(), timeout_ms)
        remaining = timeout_ms
        while True:
            count = transport._read_available(remaining)
            if count and count > 0:
                for src, _dst, payload in self.feed(transport._view[:count]):
                    if src != transport.remote_addr:
                        transport.wrong_source += 1
                    else:
                        pending.append(payload)
                if pending:
                    transport.received += 1
                    return pending.pop(0)
            remaining = ticks_diff(deadline, ticks_ms())
            if remaining <= 0:
                return None

    def scan(self, buf, start, end):
        # See the class comment.
        return self._decode(buf, start, end, None)

    def _decode(self, buf, start, end, frames):
        # The frame grammar, counters and CRC check for both ``feed`` and ``scan``. With a list in
        # ``frames`` (``buf`` is bytes) it decodes to ``end``, appending ``(src, dst, payload)`` per
        # frame, and finds flags and copies runs of plain payload bytes with bytes.find and slices (C
        # speed on CPython, where the agent reads 64 KiB at a time). With None it stops after the
        # first frame and goes byte by byte: every value is then a small int and nothing is allocated
        # (a board's slices and bound memoryviews are heap objects). Returns the index after what it
        # used. One function on purpose, past the 80-line rule: split into methods along the
        # grammar it cost the CPython decoder 11 % and a frozen board 272 B of heap after set-up.
        runs = frames is not None
        chunk = memoryview(buf) if runs else None  # its slices are views: no copy of the run
        buffer = self.buffer
        view = self._view
        state = self._state
        escaped = self._escaped
        raw = self.pending_bytes
        src = self._src
        dst = self._dst
        length = self._length
        filled = self._filled
        crc_rx = self._crc_rx
        self.frame_length = -1
        i = start
        while i < end:
            if state == _HUNT:
                if runs:
                    flag = buf.find(_FLAG_BYTES, i, end)
                else:
                    flag = i
                    while flag < end and buf[flag] != FLAG:
                        flag += 1
                    if flag == end:
                        flag = -1
                if flag < 0:
                    self.dropped_bytes += end - i
                    i = end
                    break
                if flag > i:  # back-to-back frames: nothing to count
                    self.dropped_bytes += flag - i
                i = flag + 1
                state = _SRC
                escaped = False
                raw = 1
                continue
            if state == _PAYLOAD and runs and not escaped:
                # Copy the run of plain payload bytes up to the next flag/escape in one slice.
                stop = i + length - filled
                if stop > end:
                    stop = end
                special = buf.find(_FLAG_BYTES, i, stop)
                if special >= 0:
                    stop = special
                special = buf.find(_ESCAPE_BYTES, i, stop)
                if special >= 0:
                    stop = special
                if stop > i:
                    count = stop - i
                    view[filled : filled + count] = chunk[i:stop]
                    filled += count
                    raw += count
                    i = stop
                    if filled == length:
                        state = _CRC_LO
                    continue
            byte = buf[i]
            i += 1
            if byte == FLAG:
                self.resyncs += 1
                self.dropped_bytes += raw
                raw = 1
                state = _SRC
                escaped = False
                continue
            raw += 1
            if escaped:
                byte ^= ESCAPE_XOR
                escaped = False
            elif byte == ESCAPE:
                escaped = True
                continue
            if state == _PAYLOAD:
                buffer[filled] = byte
                filled += 1
                if filled == length:
                    state = _CRC_LO
            elif state == _SRC:
                src = byte
                state = _DST
            elif state == _DST:
                dst = byte
                state = _LEN_LO
            elif state == _LEN_LO:
                length = byte
                state = _LEN_HI
            elif state == _LEN_HI:
                length |= byte << 8
                if length > self.max_payload:
                    self.oversize += 1
                    self.dropped_bytes += raw
                    raw = 0
                    state = _HUNT
                else:
                    filled = 0
                    state = _PAYLOAD if length else _CRC_LO
            elif state == _CRC_LO:
                crc_rx = byte
                state = _CRC_HI
            else:  # _CRC_HI: the frame is complete
                crc_rx |= byte << 8
                state = _HUNT
                if runs:
                    check = self._crc(view[:length])  # crcmod's C loop on CPython
                else:
                    check = crc_of_prefix(self._crc, buffer, length)
                if check != crc_rx:
                    self.crc_errors += 1
                    self.dropped_bytes += raw
                elif self.local_addr is not None and dst != self.local_addr:
                    self.wrong_address += 1
                    self.dropped_bytes += raw
                else:
                    self.frames += 1
                    if runs:
                        frames.append((src, dst, bytes(view[:length])))
                    else:
                        self.frame_length = length
                        self.frame_src = src
                        self.frame_dst = dst
                        raw = 0
                        break
                raw = 0
        self._state = state
        self._escaped = escaped
        self.pending_bytes = raw
        self._src = src
        self._dst = dst
        self._length = length
        self._filled = filled
        self._crc_rx = crc_rx
        return i


def encode_length_prefixed(msg):
    # ``msg`` preceded by its 2-byte little-endian length (the TCP mapping).
    length = len(msg)
    if not 0 < length <= 0xFFFF:
        raise EncodeError("length-prefixed message must be 1..65535 bytes, not %d" % length)
    return bytes((length & 0xFF, length >> 8)) + bytes(msg)


class LengthPrefixDecoder:
    # Streaming decoder of 2-byte-LE-length-prefixed messages (TCP), fed arbitrary chunks.
    #
    # ``feed(data)`` returns a list (possibly empty) of complete messages as ``bytes``, in order.
    #
    # A length of zero (``zero_length``) or above ``max_len`` (``oversize``) means the peer is not
    # speaking this framing or the stream lost sync. A byte stream has no flag to hunt for, so there
    # is no way to find the next message boundary: the decoder sets ``broken = True``, counts every
    # later byte in ``dropped_bytes`` and returns nothing more; the owner should close the connection.
    #
    # Memory is one preallocated ``max_len`` buffer plus the returned messages.

    __slots__ = (
        "max_len",
        "messages",
        "zero_length",
        "oversize",
        "broken",
        "dropped_bytes",
        "buffer",
        "_view",
        "_header_lo",
        "_header_filled",
        "_length",
        "_filled",
    )

    def __init__(self, max_len=0xFFFF):
        if not 0 < max_len <= 0xFFFF:
            raise ValueError("max_len must be 1..65535")
        self.max_len = max_len
        self.buffer = bytearray(max_len)  # a board's TcpTransport reads whole messages straight into it
        self._view = memoryview(self.buffer)
        self.messages = 0
        self.zero_length = 0
        self.oversize = 0
        self.broken = False
        self.dropped_bytes = 0
        self._header_lo = 0
        self._header_filled = 0
        self._length = 0  # 0 while reading the length prefix
        self._filled = 0

    def accepts_length(self, length):
        # True for a length prefix of 1..max_len. Otherwise counts it (``zero_length``/``oversize``),
        # marks the stream broken and returns False. A board's TcpTransport reads prefixes itself.
        if 0 < length <= self.max_len:
            return True
        if length == 0:
            self.zero_length += 1
        else:
            self.oversize += 1
        self.broken = True
        return False

    def feed(self, data):
        messages = []
        size = len(data)
        if self.broken:
            self.dropped_bytes += size
            return messages
        chunk = memoryview(data)
        view = self._view
        length = self._length
        filled = self._filled
        i = 0
        while i < size:
            if length == 0:
                if self._header_filled == 0 and size - i >= 2:
                    length = chunk[i] | (chunk[i + 1] << 8)
                    i += 2
                elif self._header_filled == 0:
                    self._header_lo = chunk[i]
                    self._header_filled = 1
                    i += 1
                    continue
                else:
                    length = self._header_lo | (chunk[i] << 8)
                    self._header_filled = 0
                    i += 1
                if not self.accepts_length(length):
                    self.dropped_bytes += size - i + 2
                    length = 0
                    break
                filled = 0
                if size - i >= length:
                    # Whole message in this chunk: one copy straight out of it.
                    messages.append(bytes(chunk[i : i + length]))
                    self.messages += 1
                    i += length
                    length = 0
                    continue
            count = length - filled
            if count > size - i:
                count = size - i
            view[filled : filled + count] = chunk[i : i + count]
            filled += count
            i += count
            if filled == length:
                messages.append(bytes(view[:length]))
                self.messages += 1
                length = 0
        self._length = length
        self._filled = filled
        return messages
