"""Where built interface packages are found at run time (see xrce.agent.interfaces for the whole).

A ``.pth`` file in the interpreter's site-packages (``xrce_interfaces.pth``) installs a
``sys.meta_path`` finder fed by ``xrce_interfaces.json`` next to it (package -> prefix,
dependencies). On the first import of a registered package the finder loads that prefix's
libraries with ``RTLD_GLOBAL`` (dependencies first) — rosidl's C typesupport looks its
implementations up among loaded libraries and rclpy cannot import the type otherwise — and imports
the package from the prefix's site-packages. No environment variable is needed, in the agent or in
any other rclpy program of the same venv. Chosen over installing into the venv prefix itself
because a cache of hashed prefixes never overwrites files a running process has mapped, rebuilding
a changed package is an atomic switch of one registry entry, and removing the registry files undoes
everything. Registering is idempotent (same entry, same file contents).

Only the standard library is imported at module level: the ``.pth`` hook imports this module
(through xrce.agent.interfaces) in every interpreter start of the venv.
"""

from __future__ import annotations

import json
import os
import sys

REGISTRY_NAME = "xrce_interfaces.json"
PTH_NAME = "xrce_interfaces.pth"
# The typesupport libraries in the order they depend on each other.
_LIBRARY_ORDER = ("rosidl_generator_c", "rosidl_typesupport_fastrtps_c",
                  "rosidl_typesupport_introspection_c", "rosidl_typesupport_c",
                  "rosidl_generator_py")
# Written last into a build's prefix (xrce.agent.interfaces.builder): a prefix without it is a build
# that died half way, which the finder does not import from.
COMPLETE_MARKER = ".xrce-complete"


def _load_global(path: str) -> None:
    """dlopen ``path`` with RTLD_GLOBAL. Through ctypes' C core, the dlopen that ``ctypes.CDLL``
    calls on POSIX: the ctypes package itself, once imported, stays in the process (0.57 MB of
    classes) for these few calls."""
    try:
        from _ctypes import dlopen
    except ImportError:  # not POSIX
        import ctypes
        ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
    else:
        dlopen(path, os.RTLD_GLOBAL | os.RTLD_NOW)


class _RegisteredInterfaceFinder:
    """Imports registered interface packages from their cache prefixes (see module docstring)."""

    def __init__(self):
        self.entries = {}  # package -> {"prefix": str, "depends": [package, ...]}
        self._loaded = set()

    def update(self, entries):
        self.entries.update(entries)

    def _preload(self, package, seen, kinds=_LIBRARY_ORDER):
        if package in self._loaded or package in seen or package not in self.entries:
            return
        seen.add(package)
        entry = self.entries[package]
        for dependency in entry.get("depends", ()):
            self._preload(dependency, seen, kinds)
        libdir = os.path.join(entry["prefix"], "lib")
        for kind in kinds:
            path = os.path.join(libdir, "lib%s__%s.so" % (package, kind))
            if os.path.exists(path):
                _load_global(path)
        if kinds is _LIBRARY_ORDER:
            self._loaded.add(package)

    def find_spec(self, fullname, path=None, target=None):
        if "." in fullname:
            return None
        entry = self.entries.get(fullname)
        if entry is None or not os.path.exists(os.path.join(entry["prefix"], COMPLETE_MARKER)):
            return None
        import importlib.machinery

        spec = importlib.machinery.PathFinder.find_spec(fullname, [site_packages_of(entry["prefix"])])
        if spec is not None:
            self._preload(fullname, set())
        return spec

    def invalidate_caches(self):
        pass


_FINDER = None


def _finder():
    global _FINDER
    if _FINDER is None:
        _FINDER = _RegisteredInterfaceFinder()
        # Last: an interface package installed the ordinary way (a wheel) wins over a cached build.
        sys.meta_path.append(_FINDER)
    return _FINDER


def is_registered(package):
    """True if ``package`` has a complete build registered (in this process's finder)."""
    entry = _FINDER.entries.get(package) if _FINDER is not None else None
    return entry is not None and os.path.exists(os.path.join(entry["prefix"], COMPLETE_MARKER))


def c_typesupport_library(package):
    """For a registered package, the path of its ``lib<package>__rosidl_typesupport_c.so``, its
    and its registered dependencies' C libraries loaded as an import would load them, but not
    their rosidl_generator_py ones (Python conversions; the agent's raw message types need none,
    xrce.agent.middleware.ros.types); None for a package not registered."""
    if not is_registered(package):
        return None
    _FINDER._preload(package, set(), _LIBRARY_ORDER[:-1])
    return os.path.join(_FINDER.entries[package]["prefix"], "lib",
                        "lib%s__rosidl_typesupport_c.so" % package)


def activate_registry(registry_path):
    """Called from the ``.pth`` hook: make every package in ``registry_path`` importable."""
    try:
        with open(registry_path) as f:
            entries = json.load(f)
    except (OSError, ValueError):
        return
    if isinstance(entries, dict):
        _finder().update(entries)


def site_packages_of(prefix):
    """Where ament_cmake_python put the package's Python code: ``lib/pythonX.Y/site-packages``
    (a venv's interpreter, as the wheels and /opt/ros use) or Debian's ``local/.../dist-packages``
    (the system interpreter outside a venv)."""
    version = "python%d.%d" % sys.version_info[:2]
    candidates = (os.path.join(prefix, "lib", version, "site-packages"),
                  os.path.join(prefix, "local", "lib", version, "dist-packages"),
                  os.path.join(prefix, "lib", version, "dist-packages"))
    for candidate in candidates:
        if os.path.isdir(candidate):
            return candidate
    return candidates[0]


# ----------------------------------------------------------------------------- registration

def default_site_dir():
    import sysconfig

    return sysconfig.get_paths()["purelib"]


# One line that site.py executes at every interpreter start (it runs lines beginning with "import").
# An uninstalled xrce must not break the interpreter, hence the ImportError guard. It names
# xrce.agent.interfaces, not this module: .pth files written by earlier versions name it too.
_PTH_CODE = ("try:\n import xrce.agent.interfaces as m\n"
             "except ImportError:\n m = None\n"
             "if m is not None:\n m.activate_registry(%r)\n")


def _pth_line(registry_path):
    return "import sys; exec(%r)\n" % (_PTH_CODE % registry_path)


def register(results, site_dir=None):
    """Record built packages in ``site_dir`` (default: this interpreter's site-packages) and make
    them importable in this process too. Idempotent."""
    site_dir = site_dir or default_site_dir()
    registry_path = os.path.join(site_dir, REGISTRY_NAME)
    import fcntl

    with open(os.path.join(site_dir, ".xrce_interfaces.lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            with open(registry_path) as f:
                entries = json.load(f)
        except (OSError, ValueError):
            entries = {}
        for result in results:
            entries[result.name] = {"prefix": result.prefix, "depends": list(result.depends)}
        _write_if_changed(registry_path, json.dumps(entries, indent=1, sort_keys=True) + "\n")
        _write_if_changed(os.path.join(site_dir, PTH_NAME), _pth_line(registry_path))
    _finder().update({r.name: {"prefix": r.prefix, "depends": list(r.depends)} for r in results})
    import importlib

    importlib.invalidate_caches()


def _write_if_changed(path, text):
    try:
        with open(path) as f:
            if f.read() == text:
                return
    except OSError:
        pass
    temporary = "%s.%d.tmp" % (path, os.getpid())
    with open(temporary, "w") as f:
        f.write(text)
    os.replace(temporary, path)
