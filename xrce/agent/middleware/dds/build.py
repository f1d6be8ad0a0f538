"""The plain-DDS bridge (``_plaindds.cpp`` beside this file), compiled on first use and cached.

Why at run time and not by setup.py as the agent's C extensions are: it is C++ against Fast DDS's
headers, and pip builds xrce before it installs the ROS wheels that carry them (in a fresh venv
they are not there when setup.py runs); the C extensions need no ROS header (they look rcl up in
the loaded libraries). Built here, it is also built against exactly the Fast DDS the process
has loaded (Jazzy's wheels, a sourced ROS, a later reinstall), and a plain DDS topic costs
nothing to an agent that never sees one. The compile takes about 3 s once; the result is kept in
``$XDG_CACHE_HOME/xrce/plaindds/`` (default ``~/.cache``) under the CRC of the source, the Fast
DDS library it links and the Python ABI, and a later agent loads it in milliseconds. The
interface packages are built at run time for the same reason (``xrce.agent.interfaces``).

Refused, with one line naming what is missing: a Fast DDS other than 2.x (ROS 2 Jazzy) or 3.x
(ROS 2 Kilted), an RMW other than rmw_fastrtps_cpp (no Fast DDS loaded), no headers beside
the loaded library, no C++ compiler (``$CXX`` or ``c++``).
"""

from __future__ import annotations

import binascii
import logging
import os
import sys
import threading

from xrce.agent.middleware import MiddlewareError, TypeNotReady

log = logging.getLogger("xrce.agent.dds")

MODULE = "xrce.agent.middleware.dds._plaindds"
_HERE = os.path.dirname(os.path.abspath(__file__))
SOURCE = os.path.join(_HERE, "_plaindds.cpp")
SOURCES = (SOURCE, os.path.join(_HERE, "_plaindds_types.hpp"))  # what the build's key covers
COMPILE_TIMEOUT_S = 300
_FASTDDS_LIBRARIES = ("libfastrtps.so.", "libfastdds.so.")
# Fast DDS's major version -> (the library it is, what the bridge links): 3 renamed libfastrtps.
# The source reads either (its #if on the version the headers give).
_LINK = {"2": ("libfastrtps.so.", "-lfastrtps"), "3": ("libfastdds.so.", "-lfastdds")}

_lock = threading.Lock()
# The build's (or load's) concurrent.futures.Future, once asked for. The modules that build and
# load it are imported then: an agent without plain DDS topics never loads them.
_future = None


class BridgeUnavailable(MiddlewareError):
    """The bridge cannot be had in this process; the message says why, in one line."""


def loaded_fastdds(maps_path: str = "/proc/self/maps") -> tuple[str, str] | None:
    """``(path, version)`` of the Fast DDS library mapped into this process, or None."""
    try:
        with open(maps_path) as maps:
            paths = {line.split()[-1] for line in maps if "/" in line}
    except OSError:
        return None
    for path in sorted(paths, key=len, reverse=True):
        name = os.path.basename(path)
        for prefix in _FASTDDS_LIBRARIES:
            if name.startswith(prefix) and name[len(prefix):][:1].isdigit():
                return path, name[len(prefix):]
    return None


def cache_root() -> str:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "xrce", "plaindds")


def _plan():
    """What to compile with: (output path, compiler command), or raise BridgeUnavailable."""
    import importlib.machinery
    import sysconfig

    found = loaded_fastdds()
    if found is None:
        raise BridgeUnavailable("plain DDS topics need Fast DDS (the rmw_fastrtps_cpp RMW); "
                                "this process has not loaded it (RMW_IMPLEMENTATION=%s)"
                                % (os.environ.get("RMW_IMPLEMENTATION") or "the default"))
    library, version = found
    link = _LINK.get(version.split(".", 1)[0])
    if link is None or not os.path.basename(library).startswith(link[0]):
        raise BridgeUnavailable("plain DDS topics are carried on Fast DDS 2 (ROS 2 Jazzy) and 3 "
                                "(ROS 2 Kilted); this agent runs Fast DDS %s" % version)
    libdir = os.path.dirname(os.path.realpath(library))
    include = os.path.join(os.path.dirname(libdir), "include")
    if not os.path.isfile(os.path.join(include, "fastdds", "dds", "domain",
                                       "DomainParticipant.hpp")):
        raise BridgeUnavailable("plain DDS topics need Fast DDS's headers, which are not in %s "
                                "beside the loaded %s" % (include, library))
    source = b""
    for path in SOURCES:
        with open(path, "rb") as handle:
            source += handle.read()
    crc = "%08x" % binascii.crc32(source)
    key = "%08x" % binascii.crc32(("%s\0%s\0%s" % (library, version, sys.version)).encode(),
                                  binascii.crc32(source))
    suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
    output = os.path.join(cache_root(), key, "_plaindds" + suffix)
    compiler = os.environ.get("CXX") or "c++"
    command = [compiler, "-O2", "-std=c++17", "-shared", "-fPIC", "-fvisibility=hidden",
               '-DXRCE_SOURCE_CRC="%s"' % crc,
               "-I" + sysconfig.get_paths()["include"], "-I" + include, SOURCE,
               "-L" + libdir, "-Wl,-rpath," + libdir, link[1], "-lfastcdr"]
    return output, command


def _compile(output: str, command: list) -> None:
    import subprocess

    os.makedirs(os.path.dirname(output), exist_ok=True)
    partial = "%s.%d.tmp" % (output, os.getpid())
    try:
        done = subprocess.run(command + ["-o", partial], capture_output=True, text=True,
                              timeout=COMPILE_TIMEOUT_S)
    except FileNotFoundError:
        raise BridgeUnavailable("plain DDS topics need a C++ compiler to build the agent's Fast "
                                "DDS bridge once (%s not found; set CXX)" % command[0]) from None
    except subprocess.TimeoutExpired:
        raise BridgeUnavailable("building the plain DDS bridge took over %d s" % COMPILE_TIMEOUT_S)
    if done.returncode != 0:
        try:
            os.unlink(partial)
        except OSError:
            pass
        first = next((line for line in done.stderr.splitlines() if "error" in line),
                     done.stderr.strip()[:200])
        raise BridgeUnavailable("building the plain DDS bridge failed: %s" % first)
    os.replace(partial, output)  # another agent building the same finds it whole or not at all


def _load(output: str):
    import importlib.machinery
    import importlib.util

    loader = importlib.machinery.ExtensionFileLoader(MODULE, output)
    spec = importlib.util.spec_from_file_location(MODULE, output, loader=loader)
    module = importlib.util.module_from_spec(spec)
    loader.exec_module(module)
    sys.modules[MODULE] = module
    return module


def _make(output: str, command: list):
    if not os.path.isfile(output):
        log.info("building the plain DDS bridge for Fast DDS (once; cached in %s)",
                 os.path.dirname(output))
        _compile(output, command)
    try:
        return _load(output)
    except ImportError as exc:
        raise BridgeUnavailable("the plain DDS bridge %s does not load: %s" % (output, exc)) from None


def bridge():
    """The compiled bridge module. Raises TypeNotReady while it is being built (the engine parks
    the CREATE and retries it then) and BridgeUnavailable when it cannot be had in this run (not
    retried before a restart)."""
    global _future
    with _lock:
        future = _future
        if future is None:
            import concurrent.futures

            future = _future = concurrent.futures.Future()
            try:
                output, command = _plan()
            except BridgeUnavailable as exc:
                future.set_exception(exc)
            else:
                if os.path.isfile(output):  # built by an earlier run: loaded at once
                    _run(future, output, command)
                else:
                    threading.Thread(target=_run, args=(future, output, command),
                                     name="xrce-plaindds-build", daemon=True).start()
    if not future.done():
        raise TypeNotReady("the plain DDS bridge is being built", future)
    error = future.exception()
    if error is not None:
        raise BridgeUnavailable(str(error)) from None
    return future.result()


def _run(future, output: str, command: list) -> None:
    if not future.set_running_or_notify_cancel():
        return
    try:
        module = _make(output, command)
    except BaseException as exc:  # handed to every CREATE that waits for it
        future.set_exception(exc)
    else:
        future.set_result(module)
