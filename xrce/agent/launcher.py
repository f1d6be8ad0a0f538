"""The ``xrce-agent`` process entry point (console script and ``python -m xrce.agent``).

It imports asyncio before anything else does, with ``ssl`` hidden for the length of that import:
asyncio imports ``ssl`` only to offer TLS transports, which the agent never opens, and ``ssl``
with its OpenSSL library costs 4.3 MB of resident memory (measured: ``import asyncio`` +9.4 MB
with it, +5.0 MB without). Other code may still ``import ssl`` afterwards; only this process's
asyncio has no TLS. Importing ``xrce.agent.cli`` from a program of one's own changes nothing.
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
    from xrce.agent.cli import main as agent_main
    return agent_main(argv)
