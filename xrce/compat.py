"""Small shims so that the shared modules run unchanged on CPython and MicroPython."""

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
    """Wall-clock nanoseconds since the Unix epoch (CLOCK_REALTIME, as the C client's uxr_nanos)."""
    try:
        return time.time_ns()
    except AttributeError:  # very old MicroPython ports
        return int(time.time() * 1000000000)
