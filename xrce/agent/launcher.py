"""The ``xrce-agent`` process entry point (console script and ``python -m xrce.agent``).

It shapes what the agent process imports before anything else runs (resident memory measured
on the project's machine), and changes nothing for a program that imports ``xrce.agent.cli``:

- asyncio is imported with ``ssl`` hidden for the length of that import: asyncio imports ``ssl``
  only to offer TLS transports, which the agent never opens, and ``ssl`` with its OpenSSL library
  costs 4.3 MB (``import asyncio`` +9.4 MB with it, +5.0 MB without). Other code may still
  ``import ssl`` afterwards; only this process's asyncio has no TLS. uvloop, the agent's loop, is
  kept from ``ssl`` too (xrce/agent/cli/event_loop.py).
- ``yaml`` is deferred (``xrce.agent.middleware.ros.deferred``): rclpy imports it at start-up for parameter
  files, which the agent's nodes never read; it runs, whole, on first use (1.4 MB with its C
  extension and libyaml otherwise).
"""

import sys


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
    _import_asyncio_without_tls()
    from xrce.agent.middleware.ros import deferred
    deferred.defer("yaml")
    from xrce.agent.cli import main as agent_main
    return agent_main(argv)
