# What only CPython runs, kept out of the modules a board loads (the code of a function a board
# never calls would still cost it heap): MicroPython's tick functions (xrce/__init__.py imports
# them on CPython), the message classes' _FIELDS table and what xrce.msgs._define adds on CPython.

import sys
import time

# Milliseconds and microseconds of the monotonic clock, with a period for tick arithmetic that
# never wraps in practice.
_monotonic_ns = time.monotonic_ns
_TICKS_PERIOD = 1 << 62


def ticks_ms():
    return (_monotonic_ns() // 1000000) % _TICKS_PERIOD


def ticks_us():
    return (_monotonic_ns() // 1000) % _TICKS_PERIOD


def ticks_diff(later, earlier):
    return later - earlier


def ticks_add(ticks, delta):
    return ticks + delta


def sleep_ms(ms):
    time.sleep(ms / 1000)


class FieldTable:
    # Class._FIELDS of a message class, ((name, kind, nested class or None), ...) with kind 0 value,
    # 1 message, 2 list of messages, 3 bytes (octet arrays), as CPython tools (xrce/client/cli.py)
    # read it; worked out by xrce/msgs/_dict.py on first use.
    def __get__(self, obj, cls):
        from xrce.msgs._dict import _shape

        return _shape(cls)


_FIELD_TABLE = FieldTable()


def message_class(name, base, namespace, constants):
    """The class xrce.msgs._define makes on CPython: what a board's has, plus the defining module, as
    a class statement would set it (pickle needs it), the type's constants as class attributes, and
    ``_FIELDS``, which CPython tools (xrce/client/cli.py) read, on the shared base class."""
    base._FIELDS = _FIELD_TABLE
    namespace["__module__"] = sys._getframe(2).f_globals["__name__"]
    cls = type(name, (base,), namespace)
    if constants:
        from xrce.msgs.constants import load_constants

        load_constants(cls)
    return cls
