"""Installs of xrce made the way users make them, for the tests of the install paths.

- ``xrce_wheels``: this checkout built twice with ``pip wheel`` — as on a machine without ROS (the
  PyPI ROS 2 wheels are dependencies) and as with a ROS 2 sourced (they are not).
- ``wheel_venv``: a fresh venv with the first wheel installed by pip, non-editable (pip fetches the
  ros-jazzy-* wheels from the package index, ~30 s).
- ``sourced_ros``: a ROS 2 install prefix laid out like /opt/ros/jazzy (``lib/``, ``share/``,
  ``lib/pythonX.Y/site-packages``; ``pip install --prefix`` of the ROS 2 wheels), the environment
  its setup.bash would export, and a venv where xrce was installed from this checkout with that
  environment — hence without any ROS wheel.

Everything that installs needs the package index: where it cannot be reached (a network namespace
of its own) these fixtures skip with that reason.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from unittest import mock

import pytest

from agent_process import AgentProcess, restore_default_signals

REPO = Path(__file__).resolve().parents[2]
PYTHON_DIR = "python%d.%d" % sys.version_info[:2]
# What the ros-wheels bootstrapper of the test's own venv put in the environment: a child using
# another ROS must not inherit it.
_OWN_ROS_VARIABLES = ("LD_LIBRARY_PATH", "_ROS_WHEELS_BOOTSTRAP_COMPLETE", "PYTHONPATH", "VIRTUAL_ENV",
                      "AMENT_PREFIX_PATH", "CMAKE_PREFIX_PATH", "ROS_DISTRO", "ROS_VERSION",
                      "ROS_PYTHON_VERSION", "XRCE_ROS", "PYTHONHOME")


def clean_env(**extra):
    """os.environ less anything naming the test's own ROS (its venv's libraries, a sourced ROS)."""
    env = {k: v for k, v in os.environ.items() if k not in _OWN_ROS_VARIABLES}
    env.update(extra)
    return env


def run(command, env=None, timeout=300, cwd=None):
    return subprocess.run([str(c) for c in command], env=env, cwd=cwd, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, timeout=timeout, preexec_fn=restore_default_signals)


def _pip_output(result):
    # The machine's pip configuration names index directories that do not exist for every
    # package; those warnings are noise in an assertion message.
    return "\n".join(l for l in result.stdout.splitlines() if "is ignored: it is neither" not in l)


_index_reachable = None


def require_package_index(tmp_dir):
    """Skip unless pip can fetch from the index the ROS 2 wheels come from (a 1 kB wheel)."""
    global _index_reachable
    if _index_reachable is None:
        probe = run([sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--retries", "0",
                     "--timeout", "10", "-d", tmp_dir, "ros-jazzy-std-msgs"], env=clean_env(), timeout=120)
        _index_reachable = probe.returncode == 0
    if not _index_reachable:
        pytest.skip("needs the package index (pip installs from it, as a user does); unreachable here")


def venv_site(venv):
    return Path(venv) / "lib" / PYTHON_DIR / "site-packages"


def distributions_in(site):
    """Names of the distributions installed in ``site`` (a site-packages directory)."""
    names = set()
    for entry in Path(site).iterdir():
        if entry.name.endswith(".dist-info"):
            names.add(entry.name[:-len(".dist-info")].rsplit("-", 1)[0].lower().replace("_", "-"))
    return names


def make_venv(path):
    subprocess.run([sys._base_executable, "-m", "venv", str(path)], check=True, timeout=120)
    return Path(path) / "bin" / "python"


def start_installed_agent(python, env, cwd, *args):
    """``xrce-agent ARGS`` of the xrce installed for ``python``, in exactly ``env``: run from ``cwd``
    (not the checkout) so that the installed xrce is the one imported."""
    agent = AgentProcess(*args, cwd=cwd)
    agent.env = env
    with mock.patch.object(sys, "executable", str(python)):
        agent.__enter__()
    return agent


def stop_listener_client_and_agent(listener, client, agent):
    """The end of a test that bridges a client through an installed agent to an rclpy listener
    process, however it ended: the listener (Ctrl-C first, as a user would), the client's session
    (deleted, so the agent logs it out), then the agent. ``listener`` and ``client`` may be None."""
    if listener is not None and listener.poll() is None:
        listener.send_signal(signal.SIGINT)
        try:
            listener.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            listener.kill()
            listener.communicate()
    if client is not None:
        client.delete(attempts=2, timeout_ms=500)
        client.close()
    agent.stop()


def source_copy(root: Path) -> Path:
    """This checkout without its build products, for pip to build from: pip builds in the source
    tree (build/, xrce.egg-info), and a test on the other xdist worker that builds this checkout
    too (README's install line) made pip's copy step fail with ENOENT in one CI run."""
    import shutil

    source = root / "src"
    shutil.copytree(REPO, source, ignore=shutil.ignore_patterns(
        ".venv*", "node_modules", "build", "dist", "*.so", ".git", "__pycache__", "*.egg-info",
        ".*cache"))
    return source


@pytest.fixture(scope="session")
def xrce_wheels(tmp_path_factory):
    """``{"pypi": wheel, "system": wheel}``: this checkout built without and with a sourced ROS."""
    root = tmp_path_factory.mktemp("wheels")
    require_package_index(root / "probe")
    wheels = {}
    source = source_copy(root)
    # XRCE_FASTPATH=0: the platform-independent wheel a release publishes for every machine (a Pi
    # included); the agent's compiled UDP path comes with a build from source (tests/fastpath/test_fastpath.py).
    for kind, extra in (("pypi", {"XRCE_FASTPATH": "0"}),
                        ("system", {"ROS_DISTRO": "jazzy", "XRCE_FASTPATH": "0"})):
        out = root / kind
        built = run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", out, source],
                    env=clean_env(**extra), timeout=300)
        assert built.returncode == 0, _pip_output(built)
        (wheels[kind],) = out.glob("xrce-*.whl")
    return wheels


@pytest.fixture(scope="session")
def wheel_venv(tmp_path_factory, xrce_wheels):
    """(python, site-packages) of a fresh venv where pip installed the xrce wheel (no ROS sourced)."""
    root = tmp_path_factory.mktemp("wheel-venv")
    started = time.monotonic()
    python = make_venv(root)
    # --no-compile: byte-compiling the ~250 MB of ROS wheels was 18 of 41 s of the install
    # (docs/PERFORMANCE.md "CI time"); Python compiles the few modules a test imports itself.
    install = run([python, "-m", "pip", "install", "-q", "--no-compile", xrce_wheels["pypi"]],
                  env=clean_env(), timeout=600)
    assert install.returncode == 0, _pip_output(install)[-3000:]
    print("fresh venv with the xrce wheel and its ROS 2 wheels: %.1f s" % (time.monotonic() - started))
    return python, venv_site(root)


class SourcedRos:
    """A ROS 2 prefix, the environment its setup.bash exports, and a venv with xrce installed there."""

    def __init__(self, prefix, venv):
        self.prefix = Path(prefix)
        self.site = self.prefix / "lib" / PYTHON_DIR / "site-packages"
        self.venv = Path(venv)
        self.python = self.venv / "bin" / "python"

    def env(self, **extra):
        # What /opt/ros/jazzy/setup.bash exports. The wheels' vendored *.libs directories stand in
        # for the system libraries (tinyxml2, spdlog, ...) that apt's ROS takes from Ubuntu.
        libraries = [str(self.prefix / "lib")] + sorted(str(p) for p in self.site.glob("*.libs"))
        return clean_env(
            ROS_DISTRO="jazzy", ROS_VERSION="2", ROS_PYTHON_VERSION="3",
            AMENT_PREFIX_PATH=str(self.prefix), CMAKE_PREFIX_PATH=str(self.prefix),
            PYTHONPATH=str(self.site), LD_LIBRARY_PATH=os.pathsep.join(libraries),
            PATH=str(self.prefix / "bin") + os.pathsep + os.environ["PATH"], **extra)


@pytest.fixture(scope="session")
def sourced_ros(tmp_path_factory):
    from xrce.agent.interfaces import ros_install as rosenv

    root = tmp_path_factory.mktemp("sourced-ros")
    require_package_index(root / "probe")
    started = time.monotonic()
    python = make_venv(root / "venv")
    prefix = root / "opt" / "ros" / "jazzy"
    # --ignore-installed: the prefix holds the whole ROS, as /opt/ros does, whatever pip runs in.
    laid_out = run([python, "-m", "pip", "install", "-q", "--no-compile", "--prefix", prefix,
                    "--ignore-installed", *rosenv.pypi_ros_requirements()], env=clean_env(), timeout=600)
    assert laid_out.returncode == 0, _pip_output(laid_out)[-3000:]
    ros = SourcedRos(prefix, root / "venv")
    install = run([python, "-m", "pip", "install", "-q", source_copy(root)], env=ros.env(),
                  timeout=300)
    assert install.returncode == 0, _pip_output(install)[-3000:]
    print("ROS 2 prefix and a venv with xrce installed beside it: %.1f s" % (time.monotonic() - started))
    return ros
