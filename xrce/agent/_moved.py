"""The agent's module names from before its subpackages (issue 24), importable for one more release.

``xrce.agent.session`` is now ``xrce.agent.engine.session``, ``xrce.agent.ros`` is
``xrce.agent.middleware.ros.entities`` and so on (``MOVED``). Importing an old name gives the
module under its new name, the very same object, with one ``DeprecationWarning`` that names the
new one. ``xrce.agent.engine`` is the one old name that is a package now: the names its module
had (``Agent``, the quota defaults the CLI shows) are still read from it, with the same warning
(``OLD_ENGINE_NAMES``, through ``xrce.agent.engine.__getattr__``).

One alias table and one finder instead of a shim file per old module, so that the folders show
the new layout alone. ``xrce.agent`` installs the finder when it is imported; it is consulted
only for names no real module has. Removed with the next release, with its lines in
``xrce/agent/__init__.py`` and ``xrce/agent/engine/__init__.py``.
"""

import importlib
import importlib.util
import sys
import warnings

_OLD_TO_NEW = {
    "engine": None,  # a package now: see OLD_ENGINE_NAMES
    "session": "engine.session", "registry": "engine.objects", "datapath": "engine.datapath",
    "liveliness": "engine.liveliness", "timeline": "engine.timeline",
    "admission": "engine.admission", "reuse": "engine.reuse", "xmlrep": "engine.xmlrep",
    "fastpath": "engine.fastpath", "_fastpath": "engine._fastpath",
    "udp_links": "links.udp", "tcp_links": "links.tcp", "serial_links": "links.serial",
    "ced": "middleware.ced",
    "ros": "middleware.ros.entities", "ros_creation": "middleware.ros.creation",
    "ros_domain": "middleware.ros.domain", "ros_services": "middleware.ros.services",
    "rclpy_services": "middleware.ros.rclpy_services", "rosenv": "middleware.ros.env",
    "rostypes": "middleware.ros.types", "fastdds_profile": "middleware.ros.fastdds_profile",
    "deferred": "middleware.ros.deferred",
    "interface_build": "interfaces.builder", "interface_registry": "interfaces.registry",
    "observability": "observe.observability", "diagnostics": "observe.diagnostics",
    "capture": "observe.capture", "stats_view": "observe.stats_view",
}
MOVED = {"xrce.agent." + old: "xrce.agent." + new for old, new in _OLD_TO_NEW.items() if new}

ENGINE_MODULE = "xrce.agent.engine.dispatch"
# What ``from xrce.agent.engine import ...`` found in the old module: its own names and those it
# re-exported from session (the quota defaults).
OLD_ENGINE_NAMES = frozenset((
    "Agent", "MAX_PARKED_MESSAGES", "TRACE", "AgentStats", "ClientProxy", "Link", "SessionTable",
    "CLIENT_DEAD_TIME", "CLIENT_EXPIRE_TIME", "MAX_CLIENT_BYTES", "MAX_CLIENTS",
    "MAX_OBJECTS_PER_CLIENT", "MAX_OUTPUT_QUEUE_BYTES", "MAX_REASSEMBLY", "MAX_TOTAL_BYTES",
    "STREAM_WINDOW", "_return_free_heap",
))


def _warn(old, new):
    # stacklevel 3: past this function and its caller (the loader or __getattr__); the frames of
    # the import machinery in between are skipped by warnings itself, so the warning names the
    # line that imported the old name.
    warnings.warn("%s is now %s; the old name goes with the next release" % (old, new),
                  DeprecationWarning, stacklevel=3)


class _OldNames:
    """Finds an old module name and loads it as the module's new name (a meta path finder and
    loader; not derived from importlib.abc, which loads importlib.resources, tempfile and shutil
    into every agent)."""

    def find_spec(self, fullname, path=None, target=None):
        new = MOVED.get(fullname)
        if new is None or importlib.util.find_spec(new) is None:  # e.g. _fastpath not built
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec):
        return None  # a placeholder: exec_module puts the real module in its place

    def exec_module(self, module):
        old = module.__spec__.name
        new = MOVED[old]
        _warn(old, new)
        # The import system returns what sys.modules holds under the old name once this returns.
        sys.modules[old] = importlib.import_module(new)


def engine_attribute(name):
    """``xrce.agent.engine.<name>`` for a name of the old engine module (``__getattr__``)."""
    if name not in OLD_ENGINE_NAMES:
        raise AttributeError("module 'xrce.agent.engine' has no attribute %r" % name)
    value = getattr(importlib.import_module(ENGINE_MODULE), name)
    _warn("xrce.agent.engine.%s" % name, "%s.%s" % (ENGINE_MODULE, name))
    setattr(sys.modules["xrce.agent.engine"], name, value)  # found there from now on: warned once
    return value


def install():
    if not any(isinstance(finder, _OldNames) for finder in sys.meta_path):
        sys.meta_path.append(_OldNames())  # last: every real module is found before an old name
