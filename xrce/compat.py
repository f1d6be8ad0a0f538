# Small shims so that the shared modules run unchanged on CPython and MicroPython.
#
# The CPython versions of the tick functions are in xrce/_cpython.py: a board loads only what it
# runs (the code of a function it never defines would still cost it heap).

import time

try:  # MicroPython: constants folded at compile time
    from micropython import const
except ImportError:  # CPython

    def const(value):
        return value


IS_MICROPYTHON = hasattr(time, "ticks_ms")

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
    try:
        return time.time_ns()
    except AttributeError:  # very old MicroPython ports
        return int(time.time() * 1000000000)


def random_client_key():
    # Four random bytes, never all zero (the agent rejects key 0).
    try:
        import os
        key = os.urandom(4)
    except (ImportError, AttributeError, NotImplementedError):
        import random
        value = random.getrandbits(32)
        key = bytes(((value >> 24) & 0xFF, (value >> 16) & 0xFF, (value >> 8) & 0xFF, value & 0xFF))
    if key == b"\x00\x00\x00\x00":
        key = b"\x00\x00\x00\x01"
    return key
