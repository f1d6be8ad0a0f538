"""Build ROS 2 interface packages (``.msg``/``.srv``) against the ROS 2 xrce runs on: the PyPI
wheels in this interpreter's prefix, or a sourced ROS 2 (its AMENT_PREFIX_PATH, see rosenv.py).

``xrce-agent build-interfaces [DIR ...]`` and the agent's lazy path (``ensure_package``), both here,
run plain cmake on every interface package found under the given directories into a content-hash
cache (xrce.agent.interface_build); a ``.pth`` hook makes the built packages importable in every
interpreter of the venv with no environment variable (xrce.agent.interface_registry).

Only the standard library is imported at module level: the ``.pth`` hook imports this module in
every interpreter start of the venv.
"""

from __future__ import annotations

import os
import sys
import threading

from xrce.agent.interface_registry import REGISTRY_NAME, default_site_dir
# Used through this module: the .pth hook calls activate_registry.
from xrce.agent.interface_registry import activate_registry  # noqa: F401

# The build code (xrce.agent.interface_build: package search, hashing, cmake) loads when a build or
# the search path is first needed, also for callers that name it through this module (the agent's
# --interfaces DIR calls add_search_dirs): the .pth hook imports this module in every interpreter
# of the environment, and an agent whose types are built already never needs it.
_FROM_BUILD = ("InterfaceBuildError", "add_search_dirs", "build", "find_packages", "search_dirs")


def __getattr__(name):
    if name in _FROM_BUILD:
        from xrce.agent import interface_build

        return getattr(interface_build, name)
    raise AttributeError("module %r has no attribute %r" % (__name__, name))


# ----------------------------------------------------------------------------- agent's lazy path

_lazy_lock = threading.Lock()
_lazy_builds = {}  # package -> concurrent.futures.Future of its build
_lazy_executor = None
LAZY_BUILD_TIMEOUT_S = 600.0


def start_package_build(package_name):
    """The future of building ``package_name`` from the interface search path, started now if no
    build of it is under way or done. Its result is True once the package is built (or was cached)
    and importable, False when the search path has no such package; it raises InterfaceBuildError
    when the build failed (and the next call starts a new one).

    Builds run one at a time on a worker thread; concurrent requests for one package share a build.
    """
    global _lazy_executor
    import concurrent.futures

    with _lazy_lock:
        future = _lazy_builds.get(package_name)
        if future is None or (future.done() and future.exception() is not None):
            if _lazy_executor is None:
                _lazy_executor = concurrent.futures.ThreadPoolExecutor(
                    max_workers=1, thread_name_prefix="xrce-interfaces")
            future = _lazy_executor.submit(_build_in_child, package_name)
            _lazy_builds[package_name] = future
    return future


def _build_in_child(package_name):
    """Look ``package_name`` up in the search path, build and register it in a child interpreter,
    then import from the registry the child wrote. Why a child: the search parses package.xml files
    and the build imports numpy (for its include directory) and hashlib, which would stay in the
    agent for the rest of its life (measured: RSS 50 -> 67 MB for an agent that built
    turtlebot3_msgs on its first run)."""
    import importlib
    import subprocess

    from xrce.agent.interface_build import NOT_IN_SEARCH_PATH, InterfaceBuildError, search_dirs

    command = [sys.executable, "-m", "xrce.agent.interface_build", package_name] + search_dirs()
    completed = subprocess.run(command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    if completed.returncode == NOT_IN_SEARCH_PATH:
        return False
    if completed.returncode != 0:
        lines = (completed.stderr or completed.stdout).strip().splitlines()
        raise InterfaceBuildError(lines[-1] if lines else "exit code %d" % completed.returncode)
    activate_registry(os.path.join(default_site_dir(), REGISTRY_NAME))
    importlib.invalidate_caches()
    return True


def ensure_package(package_name, timeout_s=None):
    """Build ``package_name`` from the interface search path if it is there and wait for it; True
    when built (or cached) and registered, False when no such package is in the search path."""
    import concurrent.futures

    from xrce.agent.interface_build import InterfaceBuildError

    timeout_s = timeout_s if timeout_s is not None else LAZY_BUILD_TIMEOUT_S
    try:
        return start_package_build(package_name).result(timeout=timeout_s)
    except concurrent.futures.TimeoutError:
        raise InterfaceBuildError("building %s takes longer than %.0f s"
                                  % (package_name, timeout_s)) from None


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
    from xrce.agent.interface_build import InterfaceBuildError, build

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
