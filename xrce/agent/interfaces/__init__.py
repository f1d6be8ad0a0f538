"""Build ROS 2 interface packages (``.msg``/``.srv``/``.action``) against the ROS 2 xrce runs on:
the PyPI wheels in this interpreter's prefix, or a sourced ROS 2 (its AMENT_PREFIX_PATH, see
xrce.agent.interfaces.ros_install).

``xrce-agent build-interfaces [DIR ...]`` and the agent's lazy path (``ensure_package``), both here,
run plain cmake on every interface package found under the given directories into a content-hash
cache (xrce.agent.interfaces.builder); a ``.pth`` hook makes the built packages importable in every
interpreter of the venv with no environment variable (xrce.agent.interfaces.registry).

Only the standard library is imported at module level: the ``.pth`` hook imports this module in
every interpreter start of the venv.
"""

from __future__ import annotations

import os
import sys
import threading

from xrce.agent.interfaces.registry import REGISTRY_NAME, default_site_dir
# Used through this module: the .pth hook calls activate_registry.
from xrce.agent.interfaces.registry import activate_registry  # noqa: F401

# The build code (xrce.agent.interfaces.builder: package search, hashing, cmake) loads when a build or
# the search path is first needed, also for callers that name it through this module (the agent's
# --interfaces DIR calls add_search_dirs): the .pth hook imports this module in every interpreter
# of the environment, and an agent whose types are built already never needs it.
_FROM_BUILD = ("InterfaceBuildError", "add_search_dirs", "build", "find_packages", "search_dirs")


def __getattr__(name):
    if name in _FROM_BUILD:
        from xrce.agent.interfaces import builder

        return getattr(builder, name)
    raise AttributeError("module %r has no attribute %r" % (__name__, name))


# ----------------------------------------------------------------------------- agent's lazy path

# A client names types; a type name must never make the agent run code it would not run anyway
# (xrce.agent.middleware.ros.types decides what may be imported). Building is for packages the interface
# directories hold: their names are listed once per agent run by a child interpreter, each such
# package gets one build attempt per run, and both children are killed past their timeout, so a
# CREATE parked on them always comes back.
_lazy_lock = threading.Lock()
_lazy_builds = {}  # package -> concurrent.futures.Future of its build (one per agent run)
_job_lock = threading.Lock()  # listings and builds run one at a time
_search_index = None  # Future of the frozenset of package names in the interface directories
LAZY_BUILD_TIMEOUT_S = 600.0
SEARCH_INDEX_TIMEOUT_S = 60.0


def _submit(function, *args):
    """The future of ``function(*args)``, run on a thread of its own that ends with it; one such
    job at a time, in no promised order (a build waits for the listing's future, not for its turn).
    Not a one-worker pool: its worker, idle after the agent's first build, would stay for the
    agent's whole life with its stack and malloc arena (1.0 MB under the TurtleBot3 load)."""
    import concurrent.futures

    future = concurrent.futures.Future()

    def run():
        with _job_lock:
            if not future.set_running_or_notify_cancel():
                return
            try:
                result = function(*args)
            except BaseException as exc:  # handed to whoever waits on the future
                future.set_exception(exc)
            else:
                future.set_result(result)

    threading.Thread(target=run, name="xrce-interfaces").start()
    return future


def search_index():
    """The future of the names of the interface packages in the search path (listed once per
    agent run, in a child interpreter: the search parses package.xml files)."""
    global _search_index
    with _lazy_lock:
        if _search_index is None:
            _search_index = _submit(_list_in_child)
        return _search_index


def _list_in_child():
    import subprocess

    from xrce.agent.interfaces.builder import search_dirs

    dirs = search_dirs()
    if not dirs:
        return frozenset()
    command = [sys.executable, "-m", "xrce.agent.interfaces.builder", "--list"] + dirs
    try:
        completed = _run_child(command, SEARCH_INDEX_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        _log().warning("listing the interface directories took over %.0f s: no package of "
                       "theirs will be built in this run", SEARCH_INDEX_TIMEOUT_S)
        return frozenset()
    if completed.returncode != 0:
        _log().warning("cannot list the interface directories: %s",
                       (completed.stderr or "exit code %d" % completed.returncode).strip())
        return frozenset()
    return frozenset(line.strip() for line in completed.stdout.splitlines() if line.strip())


def _run_child(command, timeout_s):
    """``subprocess.run`` of ``command`` in its own process group, which is killed whole (cmake,
    ninja and the compilers under it too) past ``timeout_s``: subprocess.TimeoutExpired then."""
    import signal
    import subprocess

    child = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        stdout, stderr = child.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        try:
            os.killpg(child.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        child.communicate()
        raise
    return subprocess.CompletedProcess(command, child.returncode, stdout, stderr)


def _log():
    import logging

    return logging.getLogger("xrce.agent.interfaces")


def start_package_build(package_name):
    """The future of building ``package_name`` from the interface search path: started by the
    first call of the agent run, shared by every later one (a build that failed or timed out is
    not retried before the agent restarts). Its result is True once the package is built (or was
    cached) and importable, False when the search path has no such package; it raises
    InterfaceBuildError when the build failed.

    Builds run one at a time, each on a thread that ends with it.
    """
    with _lazy_lock:
        future = _lazy_builds.get(package_name)
        if future is None:
            future = _submit(_build_in_child, package_name)
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

    from xrce.agent.interfaces.builder import NOT_IN_SEARCH_PATH, InterfaceBuildError, search_dirs

    command = [sys.executable, "-m", "xrce.agent.interfaces.builder", package_name] + search_dirs()
    try:
        completed = _run_child(command, LAZY_BUILD_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        raise InterfaceBuildError("building %s took over %.0f s (stopped)"
                                  % (package_name, LAZY_BUILD_TIMEOUT_S)) from None
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

    from xrce.agent.interfaces.builder import InterfaceBuildError

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


# A build is cmake and rosidl's generators, silent meanwhile: 18 s for tf2_msgs and 44 s for
# turtlebot3_msgs on two loaded cores. A line when one starts, then one every
# BUILD_PROGRESS_PERIOD_S until it is done.
BUILD_PROGRESS_PERIOD_S = 10.0


def run_build_command(args):
    import time

    from xrce.agent.interfaces.builder import InterfaceBuildError, build

    def say(text):
        sys.stdout.write(text + "\n")
        sys.stdout.flush()

    building = []  # the Event that ends the progress lines of the build under way

    def progress(name, started, done):
        while not done.wait(BUILD_PROGRESS_PERIOD_S):
            say("  still building %s (%.0f s)" % (name, time.monotonic() - started))

    def end_progress():
        while building:
            building.pop().set()

    def on_start(name):
        say("building %s (cmake and rosidl's generators: 15-45 s)..." % name)
        building.append(threading.Event())
        threading.Thread(target=progress, args=(name, time.monotonic(), building[-1]),
                         daemon=True).start()

    def report(result):
        end_progress()
        say("%s %s %s %.2fs" % ("cached" if result.cached else "built", result.name,
                                result.prefix, result.seconds))

    try:
        results = build(args.dirs or None, args.cache, args.packages, report=report,
                        on_start=on_start)
    except InterfaceBuildError as exc:
        sys.stderr.write("xrce-agent: error: %s\n" % exc)
        return 1
    finally:
        end_progress()
    sys.stdout.write("registered %d package(s) in %s\n" % (len(results),
                                                           os.path.join(default_site_dir(), REGISTRY_NAME)))
    return 0
