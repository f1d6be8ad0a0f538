"""The ``xrce-agent`` process entry point (console script and ``python -m xrce.agent``).

It shapes what the agent process imports before anything else runs (resident memory measured
on the project's machine), and changes nothing for a program that imports ``xrce.agent.cli``:

- asyncio is imported with ``ssl`` hidden for the length of that import: asyncio imports ``ssl``
  only to offer TLS transports, which the agent never opens, and ``ssl`` with its OpenSSL library
  costs 4.3 MB (``import asyncio`` +9.4 MB with it, +5.0 MB without). Other code may still
  ``import ssl`` afterwards; only this process's asyncio has no TLS.
- ``yaml`` is deferred (``xrce.agent.middleware.ros.deferred``): rclpy imports it at start-up for parameter
  files, which the agent's nodes never read; it runs, whole, on first use (1.4 MB with its C
  extension and libyaml otherwise).
- glibc's malloc gets at most ``MALLOC_ARENAS`` arenas (``mallopt(M_ARENA_MAX)``, before any thread
  starts): by default each new thread gets an arena of its own, up to 8 per core, and the agent
  has ~15 (Fast DDS's receive, event and flow-controller threads, rclpy's executor, the loop);
  each arena keeps its freed pages resident. Under the TurtleBot3 load 49.5 -> 48.8 MB
  (bench/agent_cost.py; a malloc_trim afterwards frees nothing more, where without the limit it
  frees 0.5 MB). Set here, not through ``MALLOC_ARENA_MAX`` in the user's environment.
"""

import sys

# Threads past the first two arenas take turns on them. One arena measured the same memory, but
# would put the loop's every allocation behind the lock of every Fast DDS thread's.
MALLOC_ARENAS = 2


def _limit_malloc_arenas():
    try:
        from xrce.agent.engine._fastpath import limit_malloc_arenas
    except ImportError:  # not built (the agent runs without it): glibc's default arenas
        return
    limit_malloc_arenas(MALLOC_ARENAS)


def _import_asyncio_without_tls():
    if "asyncio" in sys.modules or "ssl" in sys.modules:
        return
    sys.modules["ssl"] = None  # "import ssl" raises ImportError, which asyncio expects
    try:
        import asyncio  # noqa: F401
    finally:
        if sys.modules.get("ssl", 0) is None:
            del sys.modules["ssl"]


def main(argv=None):
    _limit_malloc_arenas()
    _import_asyncio_without_tls()
    from xrce.agent.middleware.ros import deferred
    deferred.defer("yaml")
    from xrce.agent.cli import main as agent_main
    return agent_main(argv)
