# MicroPython only (see _CHECK_INTS in __init__.py): its struct truncates an integer that does not
# fit its field instead of raising. Loaded by the first type with integer fields.
#
# `checks` (see _plan.py) holds, four bits per field position (the lowest for the part's first
# field, or for every item of an array), 0 for a field that is no integer, else the position of its
# struct code in _CODES plus one. A value fits when shifting out its field's bits leaves 0 (or -1,
# signed: the even codes). Shifting a small int allocates nothing, where reading the bytes back would
# make a tuple per part, and a plan holding one int per part instead of a tuple per field saves
# 32 bytes of heap per integer field.

from xrce.msgs import _SIZES


def _check_ints(o, fields, checks):
    if fields is None:
        k = checks - 1
        shift = _SIZES[k] * 8 - 1 + (k & 1)
        allowed = (k & 1) - 1
        for v in o:
            v >>= shift
            if v and v != allowed:
                raise OverflowError
        return
    j = 0
    while checks:
        k = (checks & 15) - 1
        if k >= 0:
            v = getattr(o, fields[j]) >> (_SIZES[k] * 8 - 1 + (k & 1))
            if v and v != (k & 1) - 1:
                raise OverflowError
        checks >>= 4
        j += 1
