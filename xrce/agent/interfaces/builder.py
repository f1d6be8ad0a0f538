"""Building ROS 2 interface packages (``.msg``/``.srv``/``.action``) with plain cmake (no colcon)
against the ROS 2 xrce runs on (see xrce.agent.interfaces for the whole).

Every interface package found under the given directories is built in dependency order, each into
its own install prefix ``<cache>/<hash>/`` where the hash covers the package's files, its in-tree
dependencies' hashes, the rosidl versions and the Python version. A prefix that exists and is
complete is reused (a cache hit costs one hash of a few small files).

Where the project's own packages come from: ``xrce/ros_interfaces/``, package data of xrce, so a
checkout, ``pip install -e`` and a wheel install all find them.

Only the standard library is imported at module level: xrce.agent.interfaces, which the ``.pth``
hook imports in every interpreter start of the venv, imports this module.
"""

from __future__ import annotations

import os
import sys

import xrce
from xrce.agent.interfaces.registry import COMPLETE_MARKER, register

# ROS packages whose versions change the generated code (read from their package.xml wherever the
# ROS in use installed them: the wheels' prefix or a sourced ROS).
_ROSIDL_PACKAGES = ("rosidl_cmake", "rosidl_default_generators", "rosidl_generator_py", "rclpy",
                    "std_msgs")
# Found from the xrce package, not from this file, which has moved before (issue 24).
_PROJECT_INTERFACES = os.path.join(os.path.dirname(os.path.abspath(xrce.__file__)), "ros_interfaces")
_CMAKE_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "cmake")  # this package's
_PROJECT_INCLUDE = os.path.join(_CMAKE_DIR, "project_include.cmake")


class InterfaceBuildError(Exception):
    """A package could not be configured, built or found."""


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
    from xrce.agent.interfaces import ros_install as rosenv

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
    from xrce.agent.interfaces import ros_install as rosenv

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


def build_one(package, cache_root, package_hash, dependency_prefixes, jobs=None, on_start=None):
    """Build ``package`` into ``<cache_root>/<package_hash>`` unless a complete build is there;
    ``on_start(name)`` is called when a real build begins (not for a cached one)."""
    import fcntl
    import shutil
    import time

    started = time.monotonic()
    prefix = os.path.join(cache_root, package_hash)
    marker = os.path.join(prefix, COMPLETE_MARKER)
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
        if on_start is not None:
            on_start(package.name)
        try:
            _build_into(package, prefix, dependency_prefixes, jobs or os.cpu_count() or 1)
        except BaseException:
            shutil.rmtree(prefix, ignore_errors=True)
            raise
        with open(marker, "w") as f:
            f.write("%s\n" % package.name)
    return prefix, False, time.monotonic() - started


def build(dirs=None, cache_root=None, names=None, site_dir=None, register_results=True,
          report=None, on_start=None):
    """Build the interface packages under ``dirs`` (default ``search_dirs()``) — all of them, or
    ``names`` and their in-tree dependencies — in dependency order; list of BuildResult.
    ``on_start(name)`` when a package's real build begins, ``report(result)`` when it is done."""
    dirs = list(dirs) if dirs else search_dirs()
    if not dirs:
        raise InterfaceBuildError("no interface directories: pass one (this xrce ships no "
                                  "xrce/ros_interfaces)")
    from xrce.agent.interfaces import ros_install as rosenv

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
                                            [prefixes[d] for d in in_tree], on_start=on_start)
        hashes[package.name], prefixes[package.name] = package_hash, prefix
        result = BuildResult(package.name, prefix, cached, seconds, in_tree)
        results.append(result)
        if report is not None:
            report(result)
    if register_results:
        register(results, site_dir)
    return results


# ----------------------------------------------------------------------------- the agent's child

NOT_IN_SEARCH_PATH = 3  # exit code of main(): no interface package of that name in the directories


def main(argv=None):
    """``python -m xrce.agent.interfaces.builder PACKAGE DIR...``: build and register PACKAGE (with its
    in-tree dependencies) from DIRs; ``--list DIR...``: print the names of the packages there.
    The agent's lazy build runs this in a child interpreter (xrce.agent.interfaces), so that
    nothing a build or the search imports stays in the agent's memory."""
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--list"]:  # the names of the packages in DIRs, one a line
        try:
            found = find_packages([d for d in argv[1:] if os.path.isdir(d)])
        except InterfaceBuildError as exc:
            sys.stderr.write("%s\n" % exc)
            return 1
        sys.stdout.write("".join("%s\n" % name for name in sorted(found)))
        return 0
    package, dirs = argv[0], [d for d in argv[1:] if os.path.isdir(d)]
    try:
        if not dirs or package not in find_packages(dirs):
            return NOT_IN_SEARCH_PATH
        build(dirs, names=[package])
    except InterfaceBuildError as exc:
        sys.stderr.write("%s\n" % exc)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
