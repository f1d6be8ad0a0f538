# The CdrWriter and CdrReader methods the client core never calls, which xrce.wire.cdr attaches to both
# classes with ``bind``: at its import on CPython, at the first call of one of them on MicroPython
# (see xrce.wire.cdr's _more). Each is defined here only, so encoding and decoding still live in one place.
# This module is handed the classes instead of importing xrce.wire.cdr, so the two do not import each other.

from xrce import EncodeError


def _write_i8(self, value):
    if not -128 <= value <= 127:
        raise EncodeError("int8 out of range: %r" % (value,))
    self.u8(value & 0xFF)


def _write_boolean(self, value):
    self.u8(1 if value else 0)


def _write_i16(self, value):
    self._put("<h", 2, value)


def _write_i32(self, value):
    self._put("<i", 4, value)


def _write_octets(self, data):
    # sequence<octet>: uint32 count then the bytes.
    self.u32(len(data))
    self.raw(data)


def _write_i64(self, value):
    self._put("<q", 8, value)


def _write_u64(self, value):
    self._put("<Q", 8, value)


def _write_f32(self, value):
    self._put("<f", 4, value)


def _write_f64(self, value):
    self._put("<d", 8, value)


def _read_i8(self):
    value = self.u8()
    return value - 256 if value > 127 else value


def _read_i16(self):
    return self._get(0, 2)


def _read_u16(self):
    return self._get(1, 2)


def _read_i32(self):
    return self._get(2, 4)


def _read_i64(self):
    return self._get(4, 8)


def _read_u64(self):
    return self._get(5, 8)


def _read_f32(self):
    return self._get(6, 4)


def _read_f64(self):
    return self._get(7, 8)


def _read_octets(self):
    return self.raw(self.u32())


def _read_remaining(self):
    return self.end - self.pos


def _read_rest(self):
    data = bytes(self.buf[self.pos:self.end])
    self.pos = self.end
    return data


_WRITER = (("i8", _write_i8), ("boolean", _write_boolean), ("i16", _write_i16), ("i32", _write_i32),
           ("octets", _write_octets), ("i64", _write_i64), ("u64", _write_u64), ("f32", _write_f32),
           ("f64", _write_f64))
_READER = (("i8", _read_i8), ("i16", _read_i16), ("u16", _read_u16), ("i32", _read_i32), ("i64", _read_i64),
           ("u64", _read_u64), ("f32", _read_f32), ("f64", _read_f64), ("octets", _read_octets),
           ("remaining", _read_remaining), ("rest", _read_rest))


def bind(writer_class, reader_class):
    for name, method in _WRITER:
        setattr(writer_class, name, method)
    for name, method in _READER:
        setattr(reader_class, name, method)


def lookup(codec, name, writer_class, reader_class):
    # xrce.wire.cdr's _more, the classes' __getattr__ (a board's first call of one of these methods loads
    # this module through it): attach the methods, then answer.
    # Dunder names (``__dict__`` of a slotted instance, ``__length_hint__``...) are never this
    # module's, and the class may hold one the instance lacks: asking again would recurse.
    bind(writer_class, reader_class)
    if name[0] == "_" or getattr(type(codec), name, None) is None:
        raise AttributeError(name)
    return getattr(codec, name)
