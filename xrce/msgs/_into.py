# decode_into(msg, r): a sample decoded into an existing message instance, in place, nested messages and
# number arrays too, so that a board allocates no message objects per sample
# (Session.create_reader's ``into``), only the values themselves where they are objects (a float, a
# string, a sequence) and one tuple per struct call. Its own module: a firmware that never decodes
# in place never loads it.

from xrce.msgs import _get_field, _planned, _take, _unpack_from


def decode_into(msg, r):
    cls = type(msg)
    names = cls.__slots__
    specs = cls._S
    if not names:
        r.u8()
    buf = r.buf
    plan = cls._P
    if plan is None:
        plan = _planned(cls)
    for step in plan:
        if type(step) is int:
            t = specs[step]
            if type(t) is str or type(t) is tuple:
                setattr(msg, names[step], _get_field(r, t))
            else:
                decode_into(getattr(msg, names[step]), r)
            continue
        start = _take(r, step[0], step[1])
        for i in range(2, len(step)):
            name, kind, fmt, offset, fields, checks = step[i]
            o = msg if name is None else getattr(msg, name)
            if checks is not None and fields is not None and _ints(o, fields, checks, buf, start + offset):
                continue
            values = _unpack_from(fmt, buf, start + offset)
            if fields is None:
                for j in range(len(values)):
                    o[j] = values[j]
                continue
            for j in range(len(fields)):
                setattr(o, fields[j], values[j])


# Integer fields of at most 32 bits read byte by byte (little-endian, as the session decodes):
# small ints, and no tuple as struct.unpack_from makes per call. ``checks`` (a MicroPython plan's,
# see _plan.py) gives each field's width and sign, seven bits a field: 0 for a float, 8 * size - 1
# signed, 8 * size unsigned. False, with nothing read, unless every field is such an integer.
def _ints(o, fields, checks, buf, pos):
    n = len(fields)
    c = checks
    for j in range(n):
        size = ((c & 0x7F) + 1) >> 3
        if size == 0 or size == 8:
            return False
        c >>= 7
    c = checks
    for j in range(n):
        width = c & 0x7F
        size = (width + 1) >> 3
        value = buf[pos + size - 1]
        if width & 1 and value > 127:
            value -= 256
        k = size - 2
        while k >= 0:
            value = (value << 8) + buf[pos + k]
            k -= 1
        setattr(o, fields[j], value)
        pos += size
        c >>= 7
    return True
