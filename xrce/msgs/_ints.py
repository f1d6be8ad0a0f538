# MicroPython only (see _CHECK_INTS in __init__.py): its struct truncates an integer that does not
# fit its field instead of raising. Loaded by the first type with integer fields.
#
# `checks` is ((field position, shift, allowed), ...) for a part of fields, (shift, allowed) for an
# array (see _plan.py). Shifting a small int allocates nothing, where reading the bytes back would
# make a tuple per part.


def _check_ints(o, fields, checks):
    if fields is None:
        shift, allowed = checks
        for v in o:
            v >>= shift
            if v and v != allowed:
                raise OverflowError
        return
    for j, shift, allowed in checks:
        v = getattr(o, fields[j]) >> shift
        if v and v != allowed:
            raise OverflowError
