# Small shims so that the shared modules run unchanged on CPython and MicroPython.

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

    def sleep_ms(ms):
        time.sleep_ms(ms)

else:
    _monotonic_ns = time.monotonic_ns
    # A period for tick arithmetic that never wraps in practice on CPython.
    _TICKS_PERIOD = 1 << 62

    def ticks_ms():
        return (_monotonic_ns() // 1000000) % _TICKS_PERIOD

    def ticks_diff(later, earlier):
        return later - earlier

    def ticks_add(ticks, delta):
        return ticks + delta

    def sleep_ms(ms):
        time.sleep(ms / 1000)


def epoch_ns():
    # Wall-clock nanoseconds since the Unix epoch (CLOCK_REALTIME, as the C client's uxr_nanos).
    try:
        return time.time_ns()
    except AttributeError:  # very old MicroPython ports
        return int(time.time() * 1000000000)


if IS_MICROPYTHON:
    ticks_us = time.ticks_us
else:

    def ticks_us():
        return (_monotonic_ns() // 1000) % _TICKS_PERIOD


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
