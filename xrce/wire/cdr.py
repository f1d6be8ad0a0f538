# Plain CDR (XCDR1) reader and writer with an explicit alignment origin.
#
# Alignment of 2/4/8-byte primitives is counted from ``origin`` (XRCE-WIRE.md §0, §14): the message
# start for XRCE structures, the first byte for binary blobs and topic samples. Little-endian by
# default; a reader built with ``little=False`` decodes big-endian payloads (the E flag cleared).
#
# MicroPython-safe: only ``struct`` with explicit byte order, no ``?`` type code (MicroPython lacks it).
# Every read is bounds-checked first, so hostile input raises only ``DecodeError``.
#
# The classes here hold what the client core calls; the values it never writes or reads (int8, int16,
# int32, int64, float, octets, a writer's bool; a reader's uint16, remaining() and rest()) are
# defined in xrce.wire.cdr_more, which the first use of one of them loads (``_more``): each method costs a
# board heap for as long as its class lives, and a firmware that only publishes and subscribes never
# pays for those. On CPython (the agent, the tools) they are attached at import, so both classes are
# complete from the start.

import struct

from xrce import DecodeError, EncodeError, IS_MICROPYTHON

# Value written into alignment padding. Only tests change it: encoding twice with different fills
# reveals which bytes are padding, the bytes a byte-exact comparison with captures must mask.
PAD_FILL = 0

_LE = ("<h", "<H", "<i", "<I", "<q", "<Q", "<f", "<d")
_BE = (">h", ">H", ">i", ">I", ">q", ">Q", ">f", ">d")


# __getattr__ of both classes: a method named in xrce.wire.cdr_more is attached to the classes on first use.
# xrce.wire.cdr_more is handed the classes rather than importing this module, so neither imports the other.
def _more(self, name):
    from xrce.wire.cdr_more import lookup

    return lookup(self, name, CdrWriter, CdrReader)


class CdrWriter:
    # Appends CDR values to a bytearray, growing it as needed.
    #
    # ``buf`` may be a preallocated bytearray (reused between messages: call ``reset``); ``pos`` is
    # where writing starts and ``origin`` the offset alignment is counted from.

    if not IS_MICROPYTHON:  # a board ignores __slots__ and would keep the tuple
        __slots__ = ("buf", "pos", "origin")

    def __init__(self, buf=None, pos=0, origin=None):
        self.buf = bytearray(64) if buf is None else buf
        self.pos = pos
        self.origin = pos if origin is None else origin

    __getattr__ = _more

    def reset(self, pos=0, origin=None):
        self.pos = pos
        self.origin = pos if origin is None else origin

    def reserve(self, n):
        need = self.pos + n - len(self.buf)
        if need > 0:
            self.buf.extend(bytes(need if need > len(self.buf) else len(self.buf)))

    def align(self, n):
        pad = (self.origin - self.pos) % n
        if pad:
            self.reserve(pad)
            fill = PAD_FILL
            for i in range(self.pos, self.pos + pad):
                self.buf[i] = fill
            self.pos += pad

    def _put(self, fmt, size, value):
        self.align(size)
        self.reserve(size)
        try:
            struct.pack_into(fmt, self.buf, self.pos, value)
        except (OverflowError, ValueError, TypeError):
            raise EncodeError("cannot encode %r as %s" % (value, fmt))
        self.pos += size

    def u8(self, value):
        if not 0 <= value <= 255:
            raise EncodeError("octet out of range: %r" % (value,))
        self.reserve(1)
        self.buf[self.pos] = value
        self.pos += 1

    def u16(self, value):
        self._put("<H", 2, value)

    def u32(self, value):
        self._put("<I", 4, value)

    def raw(self, data):
        # Bytes copied verbatim, no alignment (ObjectId, RequestId, keys, blobs).
        n = len(data)
        self.reserve(n)
        self.buf[self.pos:self.pos + n] = data
        self.pos += n

    def string(self, text):
        # uint32 length including the NUL, the bytes, the NUL.
        data = text.encode() if isinstance(text, str) else bytes(text)
        self.u32(len(data) + 1)
        self.raw(data)
        self.u8(0)

    def getvalue(self):
        # Through a memoryview: slicing the bytearray would first copy the bytes into a second,
        # transient bytearray (on a board, a reliable message's size in garbage per message).
        return bytes(memoryview(self.buf)[:self.pos])


class CdrReader:
    # Reads CDR values from ``buf[pos:end]``; alignment counted from ``origin``.

    if not IS_MICROPYTHON:  # a board ignores __slots__ and would keep the tuple
        __slots__ = ("buf", "pos", "end", "origin", "_fmt")

    def __init__(self, buf, pos=0, end=None, origin=None, little=True):
        self.buf = buf
        self.pos = pos
        self.end = len(buf) if end is None else end
        if self.end > len(buf) or pos > self.end:
            raise DecodeError("reader bounds outside the buffer")
        self.origin = pos if origin is None else origin
        self._fmt = _LE if little else _BE

    __getattr__ = _more

    def align(self, n):
        self.pos += (self.origin - self.pos) % n
        if self.pos > self.end:
            raise DecodeError("truncated: alignment past the end")

    def _need(self, n):
        if self.pos + n > self.end:
            raise DecodeError("truncated: need %d bytes at offset %d, have %d" % (n, self.pos, self.end - self.pos))

    def _get(self, index, size):
        self.align(size)
        self._need(size)
        value = struct.unpack_from(self._fmt[index], self.buf, self.pos)[0]
        self.pos += size
        return value

    def u8(self):
        self._need(1)
        value = self.buf[self.pos]
        self.pos += 1
        return value

    def boolean(self):
        value = self.u8()
        if value > 1:
            raise DecodeError("bool must be 0 or 1, got %d" % value)
        return value == 1

    def u32(self):
        return self._get(3, 4)

    def raw(self, n):
        if n < 0:
            raise DecodeError("negative length")
        self._need(n)
        data = bytes(self.buf[self.pos:self.pos + n])
        self.pos += n
        return data

    def string(self):
        n = self.u32()
        if n == 0:
            # Fast CDR and Micro-CDR both accept a zero length as the empty string.
            return ""
        data = self.raw(n)
        if data[n - 1] != 0:
            raise DecodeError("string not NUL-terminated")
        try:
            return data[:n - 1].decode()
        except UnicodeError:
            raise DecodeError("string is not valid UTF-8")


if not IS_MICROPYTHON:
    from xrce.wire.cdr_more import bind  # noqa: E402

    bind(CdrWriter, CdrReader)
