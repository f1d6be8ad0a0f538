# MicroPython only (see _CHECK_INTS in __init__.py): its struct truncates an integer that does not
# fit its field instead of raising. Loaded by the first type with integer fields.
#
# `checks` (see _plan.py) holds, seven bits per field position (the lowest for the part's first
# field; an array's items all share the one), 0 for a field that is no integer, else the number of
# bits to shift out: the field's width, less one when it is signed (so an odd shift means signed).
# A value fits when that shift leaves 0, or -1 when signed. Shifting a small int allocates nothing,
# where reading the bytes back would make a tuple per part, and one int per part instead of a tuple
# per integer field saves a plan 32 bytes of heap per integer field.


def _check_ints(o, fields, checks):
    if fields is None:
        allowed = -(checks & 1)
        for v in o:
            v >>= checks
            if v and v != allowed:
                raise OverflowError
        return
    for name in fields:
        shift = checks & 127
        if shift:
            v = getattr(o, name) >> shift
            if v and v != -(shift & 1):
                raise OverflowError
        checks >>= 7
