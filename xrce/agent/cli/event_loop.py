"""Which event loop the agent runs on: uvloop (libuv's loop, a dependency of xrce) unless
``XRCE_AGENT_LOOP=asyncio`` asks for the standard library's.

Why uvloop: a board's traffic wakes the agent a few hundred times a second (PX4's 100 Hz topics
about 230), and at that rate the standard loop's own turn around each wake-up is a measurable part
of the agent's CPU; libuv's turn costs a fraction of it (docs/PERFORMANCE.md, "PX4 SITL"). The
agent uses only what both loops provide, and the tests run the same scenarios on both
(tests/test_event_loop.py), so the standard loop stays a working choice where uvloop cannot be
installed.
"""

from __future__ import annotations

import os

from xrce.agent.cli.arguments import CliError

LOOP_ENV = "XRCE_AGENT_LOOP"


def event_loop(environ=None):
    """``(description, loop_factory)`` for ``asyncio.Runner``; the factory is None for the
    standard loop. Raises CliError for a value other than uvloop or asyncio, or for uvloop asked
    for by name and not installed."""
    wanted = (os.environ if environ is None else environ).get(LOOP_ENV, "").strip()
    if wanted not in ("", "uvloop", "asyncio"):
        raise CliError("%s must be uvloop or asyncio, not %r" % (LOOP_ENV, wanted))
    if wanted != "asyncio":
        try:
            import uvloop
        except ImportError:
            if wanted:
                raise CliError("%s=uvloop but uvloop is not installed (pip install uvloop)"
                               % LOOP_ENV) from None
        else:
            return "uvloop %s" % uvloop.__version__, uvloop.new_event_loop
    return "asyncio", None
