# The CdrWriter and CdrReader methods the client core never calls, attached to both classes when this
# module loads: at import of xrce.cdr on CPython, at the first call of one of them on MicroPython (see
# xrce.cdr's _more). Each is defined here only, so encoding and decoding still live in one place.

from xrce import EncodeError
from xrce.cdr import CdrReader, CdrWriter


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

for _name, _method in _WRITER:
    setattr(CdrWriter, _name, _method)
for _name, _method in _READER:
    setattr(CdrReader, _name, _method)
