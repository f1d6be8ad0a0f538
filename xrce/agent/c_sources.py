"""Whether a compiled extension of the agent is built from the C sources beside it.

The agent has three optional extensions, each built by setup.py from every .c and .h of one folder:
the engine's receive path (``xrce/agent/engine/compiled/`` -> ``xrce.agent.engine.compiled._fastpath``),
the ROS type supports (``xrce/agent/middleware/ros/`` -> ``xrce.agent.middleware.ros._rostypes``)
and malloc_trim (``xrce/agent/`` -> ``xrce.agent._heap``, which nothing checks: one function that
cannot go stale).
setup.py bakes the CRC-32 of the folder's sources into each (its ``SOURCE_CRC``), computed by
``source_crc`` here (it loads this file by path: the package is not importable while pip builds
it). An editable install keeps the .so it built while the .c changes under it: a module whose CRC
is not its folder's is stale, and the agent leaves it unused rather than run the old rules.

Only the standard library here, and no hashlib: it would load OpenSSL into every agent.
"""

import binascii
import os


def source_names(folder):
    """The C sources of ``folder`` that make its extension: every .c and .h, sorted by name."""
    return sorted(name for name in os.listdir(folder) if name.endswith((".c", ".h")))


def source_crc(folder):
    """CRC-32 of ``folder``'s C sources, read in ``source_names`` order, as 8 hex digits."""
    crc = 0
    for name in source_names(folder):
        with open(os.path.join(folder, name), "rb") as handle:
            crc = binascii.crc32(handle.read(), crc)
    return "%08x" % crc


def stale_build(module, folder):
    """Why ``module`` (an extension built from ``folder``) is not what the sources there build,
    or None. An install without the .c files beside the module has nothing to compare: None (a
    wheel carries them, and the CRC they were built with)."""
    try:
        if not any(name.endswith(".c") for name in source_names(folder)):
            return None
        crc = source_crc(folder)
    except OSError:
        return None
    built = getattr(module, "SOURCE_CRC", "unknown")
    if built != crc:
        return "built from other C sources (CRC %s, the files' is %s)" % (built, crc)
    return None
