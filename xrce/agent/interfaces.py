"""Build ROS 2 interface packages (``.msg``/``.srv``) against the ROS 2 xrce runs on: the PyPI
wheels in this interpreter's prefix, or a sourced ROS 2 (its AMENT_PREFIX_PATH, see rosenv.py).

``xrce-agent build-interfaces [DIR ...]`` and the agent's lazy path (``ensure_package``) run plain
cmake (no colcon) on every interface package found under the given directories, in dependency
order, each into its own install prefix ``<cache>/<hash>/`` where the hash covers the package's
files, its in-tree dependencies' hashes, the rosidl versions and the Python version. A prefix that
exists and is complete is reused (a cache hit costs one hash of a few small files).

Where the types are found at run time: a ``.pth`` file in the interpreter's site-packages
(``xrce_interfaces.pth``) installs a ``sys.meta_path`` finder fed by ``xrce_interfaces.json`` next
to it (package -> prefix, dependencies). On the first import of a registered package the finder
loads that prefix's libraries with ``RTLD_GLOBAL`` (dependencies first) — rosidl's C typesupport
looks its implementations up among loaded libraries and rclpy cannot import the type otherwise —
and imports the package from the prefix's site-packages. No environment variable is needed, in the
agent or in any other rclpy program of the same venv. Chosen over installing into the venv prefix
itself because a cache of hashed prefixes never overwrites files a running process has mapped,
rebuilding a changed package is an atomic switch of one registry entry, and removing the registry
files undoes everything. Registering is idempotent (same entry, same file contents).

Where the project's own packages come from: ``xrce/ros_interfaces/``, package data of xrce, so a
checkout, ``pip install -e`` and a wheel install all find them.

Only the standard library is imported at module level: the ``.pth`` hook imports this module in
every interpreter start of the venv.
"""

from __future__ import annotations

import json
import os
import sys
import threading

REGISTRY_NAME = "xrce_interfaces.json"
PTH_NAME = "xrce_interfaces.pth"
# The typesupport libraries in the order they depend on each other.
_LIBRARY_ORDER = ("rosidl_generator_c", "rosidl_typesupport_fastrtps_c",
                  "rosidl_typesupport_introspection_c", "rosidl_typesupport_c",
                  "rosidl_generator_py")
# ROS packages whose versions change the generated code (read from their package.xml wherever the
# ROS in use installed them: the wheels' prefix or a sourced ROS).
_ROSIDL_PACKAGES = ("rosidl_cmake", "rosidl_default_generators", "rosidl_generator_py", "rclpy",
                    "std_msgs")
_PROJECT_INTERFACES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                   "ros_interfaces")
_COMPLETE_MARKER = ".xrce-complete"
_CMAKE_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "interfaces_cmake")
_PROJECT_INCLUDE = os.path.join(_CMAKE_DIR, "project_include.cmake")


class InterfaceBuildError(Exception):
    """A package could not be configured, built or found."""


# ----------------------------------------------------------------------------- run time (site hook)

class _RegisteredInterfaceFinder:
    """Imports registered interface packages from their cache prefixes (see module docstring)."""

    def __init__(self):
        self.entries = {}  # package -> {"prefix": str, "depends": [package, ...]}
        self._loaded = set()

    def update(self, entries):
        self.entries.update(entries)

    def _preload(self, package, seen):
        if package in self._loaded or package in seen or package not in self.entries:
            return
        seen.add(package)
        entry = self.entries[package]
        for dependency in entry.get("depends", ()):
            self._preload(dependency, seen)
        import ctypes

        libdir = os.path.join(entry["prefix"], "lib")
        for kind in _LIBRARY_ORDER:
            path = os.path.join(libdir, "lib%s__%s.so" % (package, kind))
            if os.path.exists(path):
                ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
        self._loaded.add(package)

    def find_spec(self, fullname, path=None, target=None):
        if "." in fullname:
            return None
        entry = self.entries.get(fullname)
        if entry is None or not os.path.exists(os.path.join(entry["prefix"], _COMPLETE_MARKER)):
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
# An uninstalled xrce must not break the interpreter, hence the ImportError guard.
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


# ----------------------------------------------------------------------------- discovery

class InterfacePackage:
    __slots__ = ("name", "path", "depends")

    def __init__(self, name, path, depends):
        self.name = name
        self.path = path
        self.depends = depends  # every declared dependency, in-tree or not

    def __repr__(self):
        return "InterfacePackage(%r, %r)" % (self.name, self.path)


def project_interface_dirs():
    """The interface packages shipped with xrce (``xrce/ros_interfaces``: turtlebot3_msgs, ...)."""
    return [_PROJECT_INTERFACES] if os.path.isdir(_PROJECT_INTERFACES) else []


_extra_dirs = []


def add_search_dirs(dirs):
    """Directories the agent's lazy build looks in, besides ``project_interface_dirs()``."""
    for directory in dirs:
        directory = os.path.abspath(directory)
        if directory not in _extra_dirs:
            _extra_dirs.append(directory)


def search_dirs():
    return list(_extra_dirs) + project_interface_dirs()


def _read_package_xml(path):
    import xml.etree.ElementTree as ElementTree

    try:
        root = ElementTree.parse(path).getroot()
    except (OSError, ElementTree.ParseError) as exc:
        raise InterfaceBuildError("cannot read %s: %s" % (path, exc)) from None
    name = (root.findtext("name") or "").strip()
    if not name:
        raise InterfaceBuildError("%s names no package" % path)
    depends = []
    for tag in ("depend", "build_depend", "buildtool_depend"):
        for element in root.findall(tag):
            text = (element.text or "").strip()
            if text and text not in depends:
                depends.append(text)
    return name, depends


def find_packages(dirs):
    """``{name: InterfacePackage}`` for every directory under ``dirs`` holding a package.xml and a
    CMakeLists.txt (an ament_cmake interface package). The first directory naming a package wins."""
    found = {}
    for top in dirs:
        if not os.path.isdir(top):
            raise InterfaceBuildError("no such directory: %s" % top)
        for root, subdirs, files in os.walk(top):
            subdirs[:] = sorted(d for d in subdirs if not d.startswith("."))
            if "package.xml" in files and "CMakeLists.txt" in files:
                name, depends = _read_package_xml(os.path.join(root, "package.xml"))
                found.setdefault(name, InterfacePackage(name, root, depends))
                subdirs[:] = []  # a package does not contain packages
    return found


def dependency_order(packages, wanted=None):
    """Packages (all, or ``wanted`` and their in-tree dependencies) with dependencies first."""
    order, state = [], {}

    def visit(name, chain):
        if state.get(name) == "done":
            return
        if state.get(name) == "visiting":
            raise InterfaceBuildError("dependency cycle: %s" % " -> ".join(chain + [name]))
        state[name] = "visiting"
        for dependency in packages[name].depends:
            if dependency in packages:
                visit(dependency, chain + [name])
        state[name] = "done"
        order.append(packages[name])

    for name in sorted(wanted if wanted is not None else packages):
        if name not in packages:
            raise InterfaceBuildError("no interface package %s" % name)
        visit(name, [])
    return order


# ----------------------------------------------------------------------------- hashing and cache

def default_cache_root():
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "xrce", "interfaces")


def _toolchain_fingerprint():
    from xrce.agent import rosenv

    parts = ["python=%d.%d" % sys.version_info[:2], "machine=%s" % os.uname().machine]
    for package in _ROSIDL_PACKAGES:
        version, prefix = rosenv.package_version(package)
        # Every venv with the same wheels shares builds; a sourced ROS is told apart by its prefix.
        where = "venv" if prefix == sys.prefix else prefix or "-"
        parts.append("%s=%s@%s" % (package, version or "none", where))
    with open(_PROJECT_INCLUDE, "rb") as f:
        parts.append("include=%s" % f.read().hex())
    return "\n".join(parts)


def content_hash(package, dependency_hashes, fingerprint):
    """Hash of everything that determines the build output of ``package``."""
    import hashlib

    digest = hashlib.sha256()
    digest.update(fingerprint.encode())
    for name in sorted(dependency_hashes):
        digest.update(("\0dep %s %s" % (name, dependency_hashes[name])).encode())
    for root, subdirs, files in os.walk(package.path):
        subdirs[:] = sorted(d for d in subdirs if not d.startswith("."))
        for filename in sorted(files):
            if filename in ("package.xml", "CMakeLists.txt") or \
                    filename.endswith((".msg", ".srv", ".action", ".idl")):
                path = os.path.join(root, filename)
                digest.update(("\0file %s\0" % os.path.relpath(path, package.path)).encode())
                with open(path, "rb") as f:
                    digest.update(f.read())
    return digest.hexdigest()[:20]


class BuildResult:
    __slots__ = ("name", "prefix", "cached", "seconds", "depends")

    def __init__(self, name, prefix, cached, seconds, depends):
        self.name = name
        self.prefix = prefix
        self.cached = cached
        self.seconds = seconds
        self.depends = depends

    def __repr__(self):
        return "BuildResult(%r, %r, cached=%r, %.2fs)" % (self.name, self.prefix, self.cached,
                                                          self.seconds)


def _cmake_environment(dependency_prefixes):
    """The build's environment: the in-tree dependencies' prefixes, then the ROS in use (a sourced
    ROS's AMENT_PREFIX_PATH and/or the wheels in this interpreter's prefix)."""
    from xrce.agent import rosenv

    env = dict(os.environ)
    prefixes = []
    for prefix in list(dependency_prefixes) + rosenv.ament_prefixes() + [sys.prefix]:
        if prefix not in prefixes:
            prefixes.append(prefix)
    env["AMENT_PREFIX_PATH"] = os.pathsep.join(prefixes)
    inherited = [p for p in env.get("CMAKE_PREFIX_PATH", "").split(os.pathsep) if p and p not in prefixes]
    env["CMAKE_PREFIX_PATH"] = os.pathsep.join(prefixes + inherited)
    env["PATH"] = os.path.join(sys.prefix, "bin") + os.pathsep + env.get("PATH", "")
    if not rosenv.sourced_prefixes():
        # The wheels need no PYTHONPATH; an unrelated one could shadow their generators.
        env.pop("PYTHONPATH", None)
    # A sourced ROS keeps PYTHONPATH: its rosidl generators and ament_package live there.
    return env


def _run(command, env, log_path):
    import subprocess

    with open(log_path, "ab") as log:
        log.write(("\n$ %s\n" % " ".join(command)).encode())
        log.flush()
        completed = subprocess.run(command, env=env, stdout=log, stderr=subprocess.STDOUT,
                                   stdin=subprocess.DEVNULL)
    if completed.returncode != 0:
        with open(log_path, "rb") as log:
            tail = log.read()[-3000:].decode(errors="replace")
        raise InterfaceBuildError("%s failed (exit %d); log %s:\n%s"
                                  % (os.path.basename(command[0]), completed.returncode, log_path, tail))


def _build_into(package, prefix, dependency_prefixes, jobs):
    import shutil
    import sysconfig
    import tempfile

    import numpy

    cmake = shutil.which("cmake")
    if cmake is None:
        raise InterfaceBuildError("cmake is not installed (apt-get install cmake)")
    generator = ["-G", "Ninja"] if shutil.which("ninja") else []
    env = _cmake_environment(dependency_prefixes)
    build_dir = tempfile.mkdtemp(prefix="xrce-build-%s-" % package.name)
    log_path = prefix + ".log"
    try:
        _run([cmake, "-S", package.path, "-B", build_dir, *generator,
              "-DCMAKE_BUILD_TYPE=Release",
              "-DCMAKE_INSTALL_PREFIX=" + prefix,
              "-DCMAKE_PREFIX_PATH=" + env["CMAKE_PREFIX_PATH"].replace(os.pathsep, ";"),
              "-DPython3_EXECUTABLE=" + sys.executable,
              "-DBUILD_TESTING=OFF",
              "-DCMAKE_PROJECT_INCLUDE=" + _PROJECT_INCLUDE,
              "-DXRCE_C_ONLY=ON",
              "-DXRCE_PYTHON_INCLUDE_DIR=" + sysconfig.get_paths()["include"],
              "-DXRCE_NUMPY_INCLUDE_DIR=" + numpy.get_include()], env, log_path)
        _run([cmake, "--build", build_dir, "--target", "install", "--parallel", str(jobs)],
             env, log_path)
    finally:
        shutil.rmtree(build_dir, ignore_errors=True)


def build_one(package, cache_root, package_hash, dependency_prefixes, jobs=None):
    """Build ``package`` into ``<cache_root>/<package_hash>`` unless a complete build is there."""
    import fcntl
    import shutil
    import time

    started = time.monotonic()
    prefix = os.path.join(cache_root, package_hash)
    marker = os.path.join(prefix, _COMPLETE_MARKER)
    if os.path.exists(marker):
        return prefix, True, time.monotonic() - started
    os.makedirs(cache_root, exist_ok=True)
    # Another process (a second agent, a parallel CLI run) may be building the same hash.
    with open(prefix + ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if os.path.exists(marker):
            return prefix, True, time.monotonic() - started
        shutil.rmtree(prefix, ignore_errors=True)  # a build that died half way
        try:
            os.unlink(prefix + ".log")
        except FileNotFoundError:
            pass
        try:
            _build_into(package, prefix, dependency_prefixes, jobs or os.cpu_count() or 1)
        except BaseException:
            shutil.rmtree(prefix, ignore_errors=True)
            raise
        with open(marker, "w") as f:
            f.write("%s\n" % package.name)
    return prefix, False, time.monotonic() - started


def build(dirs=None, cache_root=None, names=None, site_dir=None, register_results=True,
          report=None):
    """Build the interface packages under ``dirs`` (default ``search_dirs()``) — all of them, or
    ``names`` and their in-tree dependencies — in dependency order; list of BuildResult."""
    dirs = list(dirs) if dirs else search_dirs()
    if not dirs:
        raise InterfaceBuildError("no interface directories: pass one (this xrce ships no "
                                  "xrce/ros_interfaces)")
    from xrce.agent import rosenv

    if not rosenv.ament_prefixes():
        raise InterfaceBuildError("no ROS 2 to build against: source your ROS 2 first (source "
                                  "/opt/ros/jazzy/setup.bash), or install xrce on Linux x86_64 "
                                  "with CPython 3.11 or 3.12 to get ROS 2 from PyPI")
    cache_root = os.path.abspath(cache_root or default_cache_root())
    packages = find_packages(dirs)
    fingerprint = _toolchain_fingerprint()
    hashes, prefixes, results = {}, {}, []
    for package in dependency_order(packages, names):
        in_tree = [d for d in package.depends if d in packages]
        package_hash = content_hash(package, {d: hashes[d] for d in in_tree}, fingerprint)
        prefix, cached, seconds = build_one(package, cache_root, package_hash,
                                            [prefixes[d] for d in in_tree])
        hashes[package.name], prefixes[package.name] = package_hash, prefix
        result = BuildResult(package.name, prefix, cached, seconds, in_tree)
        results.append(result)
        if report is not None:
            report(result)
    if register_results:
        register(results, site_dir)
    return results


# ----------------------------------------------------------------------------- agent's lazy path

_lazy_lock = threading.Lock()
_lazy_builds = {}  # package -> concurrent.futures.Future of its build
_lazy_executor = None
LAZY_BUILD_TIMEOUT_S = 600.0


def find_in_search_path(package_name):
    dirs = [d for d in search_dirs() if os.path.isdir(d)]
    return find_packages(dirs).get(package_name) if dirs else None


def start_package_build(package_name):
    """The future of building ``package_name`` from the interface search path (started now if no
    build is under way or the last one failed), or None when the search path has no such package.

    Builds run one at a time on a worker thread; concurrent requests for one package share a build.
    """
    global _lazy_executor
    import concurrent.futures

    with _lazy_lock:
        future = _lazy_builds.get(package_name)
        if future is None or (future.done() and future.exception() is not None):
            if find_in_search_path(package_name) is None:
                return None
            if _lazy_executor is None:
                _lazy_executor = concurrent.futures.ThreadPoolExecutor(
                    max_workers=1, thread_name_prefix="xrce-interfaces")
            future = _lazy_executor.submit(build, None, None, [package_name])
            _lazy_builds[package_name] = future
    return future


def ensure_package(package_name, timeout_s=None):
    """Build ``package_name`` from the interface search path if it is there and wait for it; True
    when built (or cached) and registered, False when no such package is in the search path."""
    import concurrent.futures

    future = start_package_build(package_name)
    if future is None:
        return False
    try:
        future.result(timeout=timeout_s if timeout_s is not None else LAZY_BUILD_TIMEOUT_S)
    except concurrent.futures.TimeoutError:
        raise InterfaceBuildError("building %s takes longer than %.0f s" % (
            package_name, timeout_s if timeout_s is not None else LAZY_BUILD_TIMEOUT_S)) from None
    return True


# ----------------------------------------------------------------------------- command line

def add_build_options(parser):
    parser.add_argument("dirs", nargs="*", metavar="DIR",
                        help="directories searched for interface packages (default: the "
                             "packages shipped with xrce: turtlebot3_msgs, tf2_msgs)")
    parser.add_argument("--cache", metavar="DIR",
                        help="where built packages go (default $XDG_CACHE_HOME/xrce/interfaces "
                             "or ~/.cache/xrce/interfaces)")
    parser.add_argument("--package", action="append", metavar="NAME", dest="packages",
                        help="build only this package (and its in-tree dependencies); repeatable")


def run_build_command(args):
    def report(result):
        sys.stdout.write("%s %s %s %.2fs\n" % ("cached" if result.cached else "built",
                                               result.name, result.prefix, result.seconds))
        sys.stdout.flush()

    try:
        results = build(args.dirs or None, args.cache, args.packages, report=report)
    except InterfaceBuildError as exc:
        sys.stderr.write("xrce-agent: error: %s\n" % exc)
        return 1
    sys.stdout.write("registered %d package(s) in %s\n" % (len(results),
                                                           os.path.join(default_site_dir(), REGISTRY_NAME)))
    return 0
