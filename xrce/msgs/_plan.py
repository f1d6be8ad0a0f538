# The encode/decode plan of a message type, built once by _define from its field specs (see
# __init__.py). On a board this module is dropped again once a type and its dependencies are defined
# (_type_attr, lookup): the plans stay, the builder's code does not.
#
# A plan is a tuple of ops in field order. An op is either a field position (a string, a bool, a
# sequence, an array of anything but numbers, or a nested message that is not one run: encoded on its
# own) or a run: a stretch of fixed-size numbers that needs no padding once its start is aligned, so
# the runtime aligns and bound-checks it once. Each later item of a run is no wider than the first
# and lands on its own alignment; CDR alignment counts from the sample start and a run's start is
# aligned to its widest item, so the offsets inside it are the same on every sample. A run is a
# tuple (align, size, part, part, ...), each part a tuple for one struct call:
#   None, None, fmt, offset, field names, checks        up to four of the type's own fields
#   field, item count, fmt, offset, None, checks        a fixed array of numbers (a list)
#   field, class, fmt, offset, field names, checks      a nested message that is one part itself
# so Twist is one run of two "<3d" parts and never calls into Vector3, and Imu's quaternion, vectors
# and covariances are one run of six parts. `checks` is None, or on MicroPython (whose struct
# truncates integers silently) what _ints.check_ints needs to find an integer that does not fit.
# Few objects and shared strings because every object a plan holds stays on a board's heap: a
# format built here that equals a string constant the board already holds is that constant (see
# _FORMATS), a part of a type's own fields reuses __slots__ when it covers them all.

import sys

from xrce.compat import const
from xrce.msgs import _CHECK_INTS, _CODES, _SIZES

# _pack in __init__.py passes values as arguments, one case per count.
_PART_FIELDS = const(4)

# The formats shipped types use most. Loading this module makes them constants (MicroPython interns
# them), and a format string built equal to one of them is that constant, not a new heap object.
_FORMATS = ("<3d", "<4d", "<9d", "<36d", "<2d", "<2I", "<iI", "<4f", "<3f", "<3fB", "<2f")


# A struct format with repeated codes counted: "ddd" -> "<3d".
def _format(codes):
    fmt = "<"
    i = 0
    while i < len(codes):
        n = 1
        while i + n < len(codes) and codes[i + n] == codes[i]:
            n += 1
        fmt += codes[i] if n == 1 else "%d%s" % (n, codes[i])
        i += n
    return fmt


def _plan(names, specs):
    ops = []
    run = None  # [align, size, [part, ...]] while it can grow
    formats = {}  # the same format string once per type (Imu's three covariances)
    for i in range(len(names)):
        t = specs[i]
        piece = None  # (field or None, count or class, codes or fmt, align, size, fields)
        if type(t) is str:
            if t != "s" and t != "?":
                size = _SIZES[_CODES.find(t)]
                piece = (None, None, t, size, size, i)
        elif type(t) is tuple:
            if t[0] == "F" and type(t[2]) is str and t[2] not in "Bs?":  # octets stay bytes: not here
                size = _SIZES[_CODES.find(t[2])]
                piece = (names[i], t[1], t[2] * t[1], size, size * t[1], None)
        else:
            inner = t._P
            if len(inner) == 1 and type(inner[0]) is tuple and len(inner[0]) == 3 and inner[0][2][0] is None:
                piece = (names[i], t, inner[0][2], inner[0][0], inner[0][1], None)
        if piece is None:
            run = None
            ops.append(i)
            continue
        name, kind, codes, align, size, first = piece
        if run is None or align > run[0] or run[1] % align:
            run = [align, 0, []]
            ops.append(run)
        parts = run[2]
        last = parts[-1] if parts else None
        if name is None and last is not None and last[0] is None and len(last[2]) < _PART_FIELDS:
            last[2] += codes
        elif name is None:
            parts.append([None, None, codes, run[1], first])
        else:
            parts.append([name, kind, codes, run[1], None])
        run[1] += size
    for n in range(len(ops)):
        op = ops[n]
        if type(op) is not list:
            continue
        run = [op[0], op[1]]
        for name, kind, codes, offset, first in op[2]:
            if type(codes) is tuple:  # a nested message's own part, shared with it
                fmt, fields, checks = codes[2], codes[4], codes[5]
            else:
                fmt = formats.setdefault(codes, _format(codes))
                if name is None:
                    fields = names if first == 0 and len(codes) == len(names) else names[first:first + len(codes)]
                else:
                    fields = None
                checks = None
                if _CHECK_INTS:
                    # (position, shift, allowed) per integer field; (shift, allowed) for an array. A
                    # value fits when shifting out its field's bits leaves 0 (or -1, signed).
                    checks = []
                    for j in range(1 if fields is None else len(codes)):
                        k = _CODES.find(codes[j])
                        if k < 8:
                            shift = _SIZES[k] * 8 - (0 if k & 1 else 1)
                            checks.append((j, shift, 0 if k & 1 else -1))
                    checks = (checks[0][1:] if fields is None else tuple(checks)) if checks else None
                    if checks is not None:
                        from xrce.msgs._ints import check_ints

                        sys.modules["xrce.msgs"]._check_ints = check_ints
            run.append((name, kind, fmt, offset, fields, checks))
        ops[n] = tuple(run)
    return tuple(ops)
