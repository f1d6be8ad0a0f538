# xrce: a Python implementation of the DDS-XRCE wire protocol as spoken by eProsima Micro XRCE-DDS.
#
# The tree is the architecture: xrce.wire is the codec the client (which must run on MicroPython)
# and the agent (CPython/asyncio) share, doing no I/O and raising only ``DecodeError`` on bad bytes;
# xrce.client and xrce.transports are the board's client and its links, xrce.msgs the ROS message
# classes, xrce.agent the agent and xrce.tools what only a build machine runs; xrce.command_line is
# what the command lines of all three share (tests/repo/test_import_graph.py keeps those layers apart).
#
# Modules that run on boards explain themselves in comments, not docstrings: MicroPython keeps what
# it compiles from a docstring on the heap (5.3 KB on the String + Twist client from .py, measured
# with bench/micropython/client_footprint.py).
#
# The package itself holds the project's error types and the shims that let every module run
# unchanged on CPython and MicroPython (wire, client, transports and msgs import them from here):
# every import loads this package anyway, and on a board each module of its own costs its object,
# dictionary and names (two modules: ~0.5 KB).

import time

__version__ = "0.1.0"


class XrceError(Exception):
    # Base class of every error raised by this package.
    pass


try:
    class _ValueErrorBase(XrceError, ValueError):
        pass
except TypeError:
    # MicroPython cannot combine two built-in exception layouts; there the errors are XrceErrors only.
    _ValueErrorBase = XrceError


class DecodeError(_ValueErrorBase):
    # Bytes that cannot be decoded: truncated, out of range or inconsistent.
    #
    # Every decoder in the wire core raises only this for hostile input, so a caller can drop and count
    # a bad datagram with a single ``except DecodeError``.
    pass


class EncodeError(_ValueErrorBase):
    # A value that cannot be put on the wire (out of range, too long, wrong type).
    pass


try:  # MicroPython: constants folded at compile time
    from micropython import const
except ImportError:  # CPython

    def const(value):
        return value


IS_MICROPYTHON = hasattr(time, "ticks_ms")

# The CPython versions of the tick functions are in xrce/_cpython.py: a board loads only what it
# runs (the code of a function it never defines would still cost it heap).
if IS_MICROPYTHON:
    ticks_ms = time.ticks_ms
    ticks_diff = time.ticks_diff
    ticks_add = time.ticks_add
    ticks_us = time.ticks_us
    sleep_ms = time.sleep_ms
else:
    from xrce._cpython import sleep_ms, ticks_add, ticks_diff, ticks_ms, ticks_us  # noqa: F401


def epoch_ns():
    # Wall-clock nanoseconds since the Unix epoch (CLOCK_REALTIME, as the C client's uxr_nanos).
    # A board with no wall clock (no time.time: bare-metal ports without a real-time clock) gets its
    # monotonic clock instead, as the C client's uxr_nanos on an RTOS counts from boot; a session's
    # epoch_ns() is the agent's clock once sync_time() has answered, with or without one.
    try:
        return time.time_ns()
    except AttributeError:
        pass
    try:
        return int(time.time() * 1000000000)
    except AttributeError:
        from xrce.client.on_demand import board_ns

        return board_ns()
