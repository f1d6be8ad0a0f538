"""Run code under real MicroPython 1.27 (WebAssembly port, driven by Node) from pytest.

``run_micropython`` installs the pinned npm package on first use (``npm ci`` in tests/micropython)
and never skips: the MicroPython proof has to run in CI, so a missing Node is an error.
"""

import fcntl
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

HARNESS_DIR = Path(__file__).resolve().parents[1] / "micropython"
RUNNER = HARNESS_DIR / "run.mjs"
REPO_ROOT = HARNESS_DIR.parent.parent
DEFAULT_HEAP = 256 * 1024
MIN_NODE_MAJOR = 18
_PACKAGE_MARKER = HARNESS_DIR / "node_modules" / "@micropython" / "micropython-webassembly-pyscript" / "micropython.mjs"


class HarnessSetupError(RuntimeError):
    """Node or the MicroPython npm package is not usable on this machine."""


def node_executable():
    node = shutil.which("node")
    if node is None:
        raise HarnessSetupError(
            "node is not on PATH: the MicroPython tests need Node.js >= %d "
            "(Debian: apt-get install nodejs npm)" % MIN_NODE_MAJOR
        )
    version = subprocess.run([node, "--version"], capture_output=True, text=True, timeout=30).stdout.strip()
    major = int(version.lstrip("v").split(".")[0] or 0)
    if major < MIN_NODE_MAJOR:
        raise HarnessSetupError("node %s is too old: the MicroPython tests need >= %d" % (version, MIN_NODE_MAJOR))
    return node


def ensure_installed():
    """Install tests/micropython/node_modules from the lockfile unless it is already there."""
    if _PACKAGE_MARKER.exists():
        return
    npm = shutil.which("npm")
    if npm is None:
        raise HarnessSetupError("npm is not on PATH: cannot install the MicroPython WebAssembly package")
    # Several pytest processes may start at once; the lock keeps them from racing on node_modules.
    with open(HARNESS_DIR / ".npm-install.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if _PACKAGE_MARKER.exists():
            return
        result = subprocess.run(
            [npm, "ci", "--no-audit", "--no-fund"],
            cwd=HARNESS_DIR,
            capture_output=True,
            text=True,
            timeout=300,
        )
        if result.returncode != 0 or not _PACKAGE_MARKER.exists():
            raise HarnessSetupError("npm ci in %s failed:\n%s%s" % (HARNESS_DIR, result.stdout, result.stderr))


def run_micropython(script, *args, heap=DEFAULT_HEAP, timeout=60, mounts=(), default_mount=True, stepped=False):
    """Run ``script`` (a path, or Python source text) under MicroPython and wait for it.

    ``stepped``: the script defines a generator function ``main()`` that the harness advances one
    step at a time, collecting garbage between steps; the heap is then capped at ``heap`` for real
    (the run fails with a MemoryError when it would have to grow) and ``mpheap.live`` holds the live
    heap before each step (see tests/micropython/run.mjs).

    ``mounts`` is a sequence of ``(host_dir, micropython_dir)`` pairs copied into the MicroPython
    filesystem; by default the repo's ``xrce`` package is there as ``/lib/xrce``. Returns the
    ``subprocess.CompletedProcess`` (text stdout/stderr); ``subprocess.TimeoutExpired`` after
    ``timeout`` seconds, with the Node process killed.
    """
    node = node_executable()
    ensure_installed()
    command = [node, str(RUNNER), "--heap", str(int(heap))]
    if stepped:
        command.append("--stepped")
    for host_dir, target in mounts:
        command += ["--mount", "%s:%s" % (os.fspath(host_dir), target)]
    if not default_mount:
        command.append("--no-default-mount")
    temporary = None
    if isinstance(script, Path) or (isinstance(script, str) and "\n" not in script and script.endswith(".py")):
        script_path = os.fspath(script)
    else:
        temporary = tempfile.NamedTemporaryFile("w", suffix=".py", prefix="mp_script_", delete=False)
        with temporary:
            temporary.write(script)
        script_path = temporary.name
    try:
        return subprocess.run(
            command + [script_path] + [str(arg) for arg in args],
            capture_output=True,
            text=True,
            timeout=timeout,
            cwd=REPO_ROOT,
        )
    finally:
        if temporary is not None:
            os.unlink(temporary.name)
