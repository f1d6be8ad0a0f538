"""eProsima's Micro XRCE-DDS Client (the C library micro-ROS firmware links) in test programs of the suite's own.

The library is not part of the repository and CI has neither it nor a network to get it:
``XRCE_EPROSIMA_CLIENT`` names an install prefix of Micro XRCE-DDS Client 2.4.3 and Micro-CDR 2.0.1
(headers under ``include/``, ``libmicroxrcedds_client.a`` and ``libmicrocdr.a`` under ``lib/``, UDP, TCP
and serial profiles). Where it is set and a C compiler is present, tests build the programs in
``tests/eprosima/programs/`` with it and drive the real agent; where not, those tests are skipped
with a reason that says so in capitals (``require_library``), and the run's summary lists them
(tests/conftest.py). They never pass without having run: what CI checks instead is the same traffic
recorded between eProsima's client and eProsima's agent, replayed against ours (tests/golden/eprosima/).

``build(source, out_dir)`` compiles one program (one .c file, plus ``common.h`` beside it) and returns
the executable's path; a build of the same source and flags is reused within a run.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
from pathlib import Path

ENV = "XRCE_EPROSIMA_CLIENT"
PROGRAMS = Path(__file__).resolve().parents[1] / "eprosima" / "programs"
LOUD_PREFIX = "EPROSIMA CLIENT TESTS NOT RUN"


def prefix():
    """The install prefix named by XRCE_EPROSIMA_CLIENT when it holds the library, else None."""
    value = os.environ.get(ENV)
    if not value:
        return None
    path = Path(value)
    if not (path / "lib" / "libmicroxrcedds_client.a").is_file():
        return None
    return path


def compiler():
    return shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc")


def missing_reason():
    """Why the live tests cannot run here, or None when they can."""
    if prefix() is None:
        value = os.environ.get(ENV)
        where = ("%s=%s holds no lib/libmicroxrcedds_client.a" % (ENV, value) if value
                 else "%s is not set" % ENV)
        return "%s: %s (eProsima's C client library is not in the repository)" % (LOUD_PREFIX, where)
    if compiler() is None:
        return "%s: no C compiler (cc/gcc) on PATH" % LOUD_PREFIX
    return None


def require_library():
    """Skip the calling test, loudly, where the library or a compiler is missing."""
    import pytest

    reason = missing_reason()
    if reason:
        pytest.skip(reason)
    return prefix()


def build(source, out_dir, defines=None):
    """Compile ``source`` (a path, or a file name under tests/eprosima/programs/) against the library.

    ``defines``: {NAME: value} passed as -DNAME=value. Returns the executable's path in ``out_dir``.
    """
    lib = prefix()
    if lib is None or compiler() is None:
        raise RuntimeError(missing_reason())
    source = Path(source)
    if not source.is_absolute() and not source.exists():
        source = PROGRAMS / source
    flags = ["-D%s=%s" % (name, value) for name, value in sorted((defines or {}).items())]
    digest = hashlib.sha256(source.read_bytes() + "\0".join(flags).encode())
    common = source.parent / "common.h"
    if common.exists():
        digest.update(common.read_bytes())
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    exe = out_dir / ("%s-%s" % (source.stem, digest.hexdigest()[:12]))
    if exe.exists():
        return exe
    command = [compiler(), "-O1", "-g", "-Wall", "-I%s" % (lib / "include"), "-I%s" % source.parent,
               *flags, str(source), str(lib / "lib" / "libmicroxrcedds_client.a"),
               str(lib / "lib" / "libmicrocdr.a"), "-o", str(exe)]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError("building %s failed:\n%s\n%s" % (source.name, " ".join(command), result.stderr))
    return exe
