"""Which event loop the agent runs on: uvloop (libuv's loop, a dependency of xrce) unless
``XRCE_AGENT_LOOP=asyncio`` asks for the standard library's.

Why uvloop: without the compiled data path every datagram of a board wakes the loop (PX4's 100 Hz
topics about 230 times a second), and the standard loop's own turn around each wake-up was a large
part of the agent's CPU (PX4 SITL: 0.75x on uvloop). With the compiled path a board's steady traffic
no longer wakes the loop: the TurtleBot3 load costs the same on both loops, the PX4 replay 0.93
against 1.27 % of a core, and uvloop 2.2 MB more resident memory (docs/PERFORMANCE.md, "A
robot's load (TurtleBot3)").
The agent uses only what both loops provide, and the tests run the same scenarios on both
(tests/agent/test_event_loop.py), so the standard loop stays a working choice where uvloop cannot be
installed or memory counts more than CPU.
"""

from __future__ import annotations

import os
import sys
import types

from xrce.agent.cli.arguments import CliError

LOOP_ENV = "XRCE_AGENT_LOOP"


class _NoTls(types.ModuleType):
    """What uvloop's loop module reads from ``ssl`` at import, for TLS transports the agent never
    opens: a class for each name, an int for each constant. The real ``ssl`` costs the agent
    1.2 MB resident beside rclpy (xrce/agent/launcher.py keeps it out of asyncio for the same
    reason); uvloop's TLS is unusable in this process, and nothing else is touched."""

    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        value = -1 if name.isupper() else type(name, (Exception,), {"__module__": "xrce-no-tls"})
        setattr(self, name, value)
        return value


def _import_uvloop():
    """uvloop, imported with the stand-in above as ``ssl`` unless something imported the real one
    already; raises ImportError when uvloop cannot be imported either way."""
    import asyncio  # noqa: F401  (before the stand-in: whether asyncio has TLS is launcher.py's)

    if "ssl" in sys.modules:
        import uvloop
        return uvloop
    sys.modules["ssl"] = _NoTls("ssl")
    try:
        import uvloop
        return uvloop
    except Exception:  # a uvloop that needs more of ssl than names at import: the real one
        for name in [n for n in sys.modules if n == "uvloop" or n.startswith("uvloop.")]:
            del sys.modules[name]
    finally:
        if isinstance(sys.modules.get("ssl"), _NoTls):
            del sys.modules["ssl"]
    import uvloop
    return uvloop


def event_loop(environ=None):
    """``(description, loop_factory)`` for ``asyncio.Runner``; the factory is None for the
    standard loop. Raises CliError for a value other than uvloop or asyncio, or for uvloop asked
    for by name and not installed."""
    wanted = (os.environ if environ is None else environ).get(LOOP_ENV, "").strip()
    if wanted not in ("", "uvloop", "asyncio"):
        raise CliError("%s must be uvloop or asyncio, not %r" % (LOOP_ENV, wanted))
    if wanted != "asyncio":
        try:
            uvloop = _import_uvloop()
        except ImportError:
            if wanted:
                raise CliError("%s=uvloop but uvloop is not installed (pip install uvloop)"
                               % LOOP_ENV) from None
        else:
            return "uvloop %s" % uvloop.__version__, uvloop.new_event_loop
    return "asyncio", None
