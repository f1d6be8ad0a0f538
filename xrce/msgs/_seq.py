# Arrays, sequences and bounded strings: the field specs that are tuples (see __init__.py), loaded
# by the first type that has one, so a board that sends Twist or String never loads this module.
# Comments rather than docstrings for the same reason as in __init__.py.

from xrce.errors import DecodeError, EncodeError
from xrce.msgs import (
    _CODES, _PACK_ERRORS, _SIZES, _bool, _default, _get_field, _get_string, _pack_into, _put,
    _put_field, _put_string, _take, _unpack_from,
)


# Sequence count, rejected before any allocation if it cannot fit in the remaining bytes.
def _count(r, bound, min_size):
    n = r.u32()
    if bound is not None and n > bound:
        raise DecodeError("sequence of %d exceeds its bound %d" % (n, bound))
    if n * min_size > r.end - r.pos:
        raise DecodeError("sequence count %d larger than the remaining %d bytes allow" % (n, r.end - r.pos))
    return n


def _get_array(r, n, code, size):
    # Fast CDR (what ROS 2 uses) does not align an empty array, so neither do we.
    if not n:
        return []
    return list(_unpack_from("<%d%s" % (n, code), r.buf, _take(r, size, n * size)))


def _put_array(w, values, code, size):
    n = len(values)
    if not n:
        return
    try:
        _pack_into("<%d%s" % (n, code), w.buf, _put(w, size, n * size), *values)
    except _PACK_ERRORS:
        raise EncodeError("cannot encode %r as %s items" % (values, code))
    if code in "bBhHiIqQ" and list(_unpack_from("<%d%s" % (n, code), w.buf, w.pos - n * size)) != list(values):
        raise EncodeError("cannot encode %r as %s items" % (values, code))  # MicroPython truncated one


def _seq_len(values, bound):
    try:
        n = len(values)
    except TypeError:
        raise EncodeError("expected a sequence, got %r" % (values,))
    if bound is not None and n > bound:
        raise EncodeError("%d items, bound is %d" % (n, bound))
    return n


def _bad_len(values, n):
    raise EncodeError("%r must have exactly %d items" % (values, n))


# The smallest encoding of one item of spec `item`: a sequence count larger than the remaining
# bytes allow is rejected before anything is allocated.
def _min_size(item):
    if type(item) is str and item != "s":
        return 1 if item == "?" else _SIZES[_CODES.find(item)]
    if type(item) is tuple or item == "s":
        return 4
    return 1


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
        if kind == "F":
            if len(value) != n:
                _bad_len(value, n)
        else:
            if n is not None and len(value) > n:
                raise EncodeError("%d bytes, bound is %d" % (len(value), n))
            w.u32(len(value))
        w.raw(value)
        return
    if kind == "F":
        if _seq_len(value, None) != n:
            _bad_len(value, n)
    else:
        w.u32(_seq_len(value, n))
    if item == "?":
        _put_array(w, [1 if b else 0 for b in value], "B", 1)
    elif type(item) is str and item != "s":
        _put_array(w, value, item, _SIZES[_CODES.find(item)])
    else:
        for v in value:
            _put_field(w, item, v)


def _get_ext(r, t):
    kind = t[0]
    if kind == "s":
        return _get_string(r, t[1])
    item = t[2]
    n = t[1] if kind == "F" else _count(r, t[1], _min_size(item))
    if item == "B":
        return r.raw(n)
    if item == "?":
        return [_bool(b) for b in r.raw(n)]
    if type(item) is str and item != "s":
        return _get_array(r, n, item, _SIZES[_CODES.find(item)])
    return [_get_field(r, item) for _ in range(n)]


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
