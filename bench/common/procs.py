"""Stopping the bench's child processes the way a user would: Ctrl-C first, kill only if it hangs.

The demo (``xrce-agent demo``) stops its agent and robot the same way; one function serves both.
"""

import os

from xrce.agent.demo import stop_child as interrupt  # noqa: F401  (the benches import it from here)


def read_until(process, found, timeout):
    """Read ``process``'s stdout pipe until a whole line satisfies ``found``, the process ends or
    ``timeout`` seconds pass: (that line or None, everything read as text).

    Reads the pipe's file descriptor with os.read. The text wrapper's readline after select()
    loses lines on a loaded machine: when two lines are in the pipe at once (a log line and the
    banner), readline buffers both and returns the first, select() then sees an empty pipe, and
    the banner waits in the wrapper's buffer until the timeout. Nothing is left in that buffer,
    so ``communicate()`` afterwards still gets the rest of the output."""
    import selectors
    import time

    fd = process.stdout.fileno()
    received = b""
    deadline = time.monotonic() + timeout
    with selectors.DefaultSelector() as selector:
        selector.register(fd, selectors.EVENT_READ)
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            if not selector.select(min(remaining, 0.5)):
                if process.poll() is not None:
                    break
                continue
            chunk = os.read(fd, 65536)
            if not chunk:
                break
            received += chunk
            text = received.decode(errors="replace")
            for line in text.splitlines(keepends=True):
                if line.endswith("\n") and found(line):
                    return line, text
    return None, received.decode(errors="replace")
