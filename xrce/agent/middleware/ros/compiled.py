"""The ROS type-support extension (``_rostypes``, built from this folder's .c and .h), or None.

What it gives the ROS middleware: raw message and service types made from a package's C
libraries without its Python code (``raw_types``), type supports for types known only by their
DDS name (``raw_types.named_message_type``), a replier's requests and replies as CDR bytes, and a
domain's DDS participant made with the GIL released (``participant``). Without it (a
platform-independent wheel, no C compiler at install) the generated Python classes serve, types
known only by name are refused, and participants are made by rclpy with the GIL held.

A build from other sources than those beside it (an editable install whose .c changed since) is
left unused, with one warning, as the engine's receive path is (``xrce.agent.c_sources``).
"""

from __future__ import annotations

import importlib
import logging
import os

log = logging.getLogger("xrce.agent.ros")  # the ROS bridge's one name (domain.log)

MODULE = "xrce.agent.middleware.ros._rostypes"

_UNSET = object()
_helper = _UNSET  # the extension once looked up; None where it cannot serve
missing = "not built"  # why there is none (``_helper`` None): "not built" or the build's staleness


def helper():
    """The extension module, or None (not built, or stale: ``missing`` says which)."""
    global _helper, missing
    if _helper is _UNSET:
        try:
            _rostypes = importlib.import_module(MODULE)
        except ImportError:
            _helper = None
            missing = "not built"
        else:
            from xrce.agent import c_sources

            stale = c_sources.stale_build(_rostypes, os.path.dirname(os.path.abspath(__file__)))
            if stale is None:
                _helper = _rostypes
            else:
                _helper = None
                missing = stale
                log.warning("compiled ROS type supports (%s) %s: `pip install -e .` rebuilds "
                            "them; left unused", MODULE, stale)
    return _helper
