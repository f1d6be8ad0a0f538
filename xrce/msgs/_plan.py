# The encode/decode plan of a message type, built from its field specs on the type's first encode or
# decode (_planned in __init__.py). On a board this module is dropped again once the plan is built:
# the plans stay, the builder's code does not.
#
# A plan is a tuple of steps in field order. A step is either a field position (a string, a bool, a
# sequence, an array of anything but numbers, or a nested message that is not one run: encoded on its
# own) or a run: a stretch of fixed-size numbers that needs no padding once its start is aligned, so
# the runtime aligns and bound-checks it once. Each later item of a run is no wider than the first
# and lands on its own alignment; CDR alignment counts from the sample start and a run's start is
# aligned to its widest item, so the offsets inside it are the same on every sample. A run is a
# tuple (align, size, part, part, ...), each part a tuple for one struct call:
#   (None, None, fmt, offset, field names, checks)      up to four of the type's own fields
#   (field, item count, fmt, offset, None, checks)      a fixed array of numbers (a list)
#   (field, class, fmt, offset, field names, checks)    a nested message that is one part itself
# so Twist is one run of two "<3d" parts and never calls into Vector3, and Imu's quaternion, vectors
# and covariances are one run of six parts. `checks` is None, or on MicroPython (whose struct
# truncates integers silently) an int that tells _ints._check_ints which values are integers of
# which width, to find one that does not fit.
#
# Every object a plan holds stays on a board's heap, and every name this module uses stays in its
# string pool (from .py, local names too): few objects (a part of a type's own fields reuses
# __slots__ when it covers them all, a nested part is the nested type's own, a format is a qstr
# shared by every plan that has it) and few new names.

import sys

from xrce.msgs import _CHECK_INTS, _CODES, _SIZES, _intern


# The plan of `cls`, kept on the class; `nested`: asked for by a parent's plan, which packs a nested
# type that is one part itself, so that type keeps no plan of its own until it is sent or received.
def _plan(cls, nested=False):
    names = cls.__slots__
    specs = cls._S
    steps = []
    run = None  # [align, size, [[field, kind, codes or nested part, offset, first field], ...]]
    for i in range(len(names)):
        t = specs[i]
        kind = None
        first = None
        align = 0  # stays 0 for a field that is no run item
        if type(t) is str:
            if t != "s" and t != "?":
                align = size = _SIZES[_CODES.find(t)]
                name = None
                first = i
        elif type(t) is tuple:
            # A fixed array of numbers; octets stay bytes and are not run items.
            if t[0] == "F" and type(t[2]) is str and _CODES.find(t[2]) not in (-1, 1):
                align = _SIZES[_CODES.find(t[2])]
                size = align * t[1]
                name = names[i]
                kind = t[1]
                t = t[2] * kind
        else:
            kind = t
            t = t._P or _plan(t, True)
            if len(t) == 1 and type(t[0]) is tuple and len(t[0]) == 3 and t[0][2][0] is None:
                align, size, t = t[0]  # the nested type's one part
                name = names[i]
        if not align:
            run = None
            steps.append(i)
            continue
        if run is None or align > run[0] or run[1] % align:
            run = [align, 0, []]
            steps.append(run)
        last = run[2][-1] if run[2] else None
        # _pack in __init__.py takes up to four fields.
        if name is None and last is not None and last[0] is None and len(last[2]) < 4:
            last[2] += t
        else:
            run[2].append([name, kind, t, run[1], first])
        run[1] += size
    for i in range(len(steps)):
        run = steps[i]
        if type(run) is not list:
            continue
        step = [run[0], run[1]]
        for name, kind, t, offset, first in run[2]:
            if type(t) is tuple:  # a nested message's own part: fmt, fields and checks are its
                step.append((name, kind, t[2], offset, t[4], t[5]))
                continue
            # Repeated codes counted: "ddd" -> "<3d".
            fmt = "<"
            j = 0
            while j < len(t):
                n = 1
                while j + n < len(t) and t[j + n] == t[j]:
                    n += 1
                fmt += t[j] if n == 1 else str(n) + t[j]
                j += n
            fmt = _intern(fmt)  # one qstr for every part with this format, not a str per part
            fields = None
            if name is None:
                fields = names if first == 0 and len(t) == len(names) else names[first:first + len(t)]
            checks = None
            if _CHECK_INTS:
                # One small int, so a plan holds no object for it: per integer field (or once for
                # an array) the shift that _check_ints applies, seven bits per field position.
                checks = 0
                for j in range(1 if fields is None else len(t)):
                    k = _CODES.find(t[j])
                    if k < 8:
                        checks |= (_SIZES[k] * 8 - 1 + (k & 1)) << 7 * j
                if checks:
                    from xrce.msgs._ints import _check_ints

                    sys.modules["xrce.msgs"]._check_ints = _check_ints
                else:
                    checks = None
            step.append((name, kind, fmt, offset, fields, checks))
        steps[i] = tuple(step)
    steps = tuple(steps)
    if not (nested and len(steps) == 1 and type(steps[0]) is tuple and len(steps[0]) == 3 and steps[0][2][0] is None):
        cls._P = steps
    return steps
