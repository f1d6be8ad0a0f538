# Helpers for array, sequence and byte-array fields, imported only by the generated modules whose
# types have such fields: a board that sends Twist or String never loads them. Comments rather than
# docstrings for the same reason as in __init__.py.

from xrce.errors import DecodeError, EncodeError
from xrce.msgs import _PACK_ERRORS, _pack_into, _put, _take, _unpack_from


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


def _seq_len(values, bound, name):
    try:
        n = len(values)
    except TypeError:
        raise EncodeError("%s must be a sequence, got %r" % (name, values))
    if bound is not None and n > bound:
        raise EncodeError("%s has %d items, bound is %d" % (name, n, bound))
    return n


def _put_octets(w, data, fixed, bound, name):
    if not isinstance(data, (bytes, bytearray)):
        try:
            data = bytes(data)
        except _PACK_ERRORS:
            raise EncodeError("%s must be bytes or a list of 0..255, got %r" % (name, data))
    n = len(data)
    if fixed is not None:
        if n != fixed:
            _bad_len(name, fixed)
    else:
        if bound is not None and n > bound:
            raise EncodeError("%s has %d bytes, bound is %d" % (name, n, bound))
        w.u32(n)
    w.raw(data)


def _bad_len(name, n):
    raise EncodeError("%s must have exactly %d items" % (name, n))
