# Arrays, sequences and bounded strings: the field specs that are tuples (see __init__.py), loaded
# by the first type that has one, so a board that sends Twist or String never loads this module.
# Comments rather than docstrings for the same reason as in __init__.py.

from xrce import DecodeError, EncodeError
from xrce.msgs import (
    _CODES, _PACK_ERRORS, _SIZES, _default, _get_field, _get_string, _pack_into, _put,
    _put_field, _put_string, _take, _unpack_from,
)


def _put_ext(w, t, value):
    kind = t[0]
    if kind == "s":
        _put_string(w, value, t[1])
        return
    n = t[1]
    item = t[2]
    if item == "B":  # octets, carried as bytes
        if not isinstance(value, (bytes, bytearray)):
            try:
                value = bytes(value)
            except _PACK_ERRORS:
                raise EncodeError("expected bytes or a list of 0..255, got %r" % (value,))
    try:
        count = len(value)
    except TypeError:
        raise EncodeError("expected a sequence, got %r" % (value,))
    if kind == "F":
        if count != n:
            raise EncodeError("%r must have exactly %d items" % (value, n))
    else:
        if n is not None and count > n:
            raise EncodeError("%d items, bound is %d" % (count, n))
        w.u32(count)
    if item == "B":
        w.raw(value)
        return
    if item == "?":
        value = [1 if b else 0 for b in value]
        item = "B"
    if type(item) is not str or item == "s":
        for v in value:
            _put_field(w, item, v)
        return
    # Numbers: one struct call. Fast CDR (what ROS 2 uses) does not align an empty array.
    if not count:
        return
    size = _SIZES[_CODES.find(item)]
    fmt = "<%d%s" % (count, item)
    pos = _put(w, size, count * size)
    try:
        _pack_into(fmt, w.buf, pos, *value)
    except _PACK_ERRORS:
        raise EncodeError("cannot encode %r as %s items" % (value, item))
    # MicroPython's struct truncates integers that do not fit instead of raising.
    if item in "bBhHiIqQ" and list(_unpack_from(fmt, w.buf, pos)) != list(value):
        raise EncodeError("cannot encode %r as %s items" % (value, item))


def _get_ext(r, t):
    kind = t[0]
    if kind == "s":
        return _get_string(r, t[1])
    n = t[1]
    item = t[2]
    number = type(item) is str and item != "s"
    if kind == "S":
        # Rejected before anything is allocated if it cannot fit in the remaining bytes.
        count = r.u32()
        if n is not None and count > n:
            raise DecodeError("sequence of %d exceeds its bound %d" % (count, n))
        smallest = (1 if item == "?" else _SIZES[_CODES.find(item)]) if number else (
            4 if item == "s" or type(item) is tuple else 1)
        if count * smallest > r.end - r.pos:
            raise DecodeError("sequence count %d larger than the remaining %d bytes allow" % (count, r.end - r.pos))
        n = count
    if item == "B":
        return r.raw(n)
    if item == "?":
        r._need(n)
        return [r.boolean() for _ in range(n)]
    if not number:
        return [_get_field(r, item) for _ in range(n)]
    if not n:
        return []
    size = _SIZES[_CODES.find(item)]
    return list(_unpack_from("<%d%s" % (n, item), r.buf, _take(r, size, n * size)))


def _default_ext(t):
    kind = t[0]
    if kind == "s":
        return ""
    item = t[2]
    if kind == "S":
        return b"" if item == "B" else []
    if item == "B":
        return bytes(t[1])
    if type(item) is str or type(item) is tuple:  # immutable items: one list of the right size
        return [_default(item)] * t[1]
    return [item() for _ in range(t[1])]
