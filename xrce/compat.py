# The CPython/MicroPython shims, defined in the package itself (xrce/__init__.py) so that a board
# loads no module for them; this name stays for code that imports them from here.

from xrce import (  # noqa: F401
    IS_MICROPYTHON, const, epoch_ns, random_client_key, sleep_ms, ticks_add, ticks_diff, ticks_ms, ticks_us,
)
