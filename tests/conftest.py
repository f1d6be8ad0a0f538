"""Fixtures shared by several test modules, defined here once: pytest builds a session-scoped one
once per run (an import into two modules would make two), and a test module gets the engine
fixture without importing it. The run leaves nothing in ~/.ros or /dev/shm (tests/helpers/hygiene.py)."""

import os
import shutil
import tempfile
import termios
import tty

import pytest

from engine_peer import ced_agent, eprosima_ced_agent  # noqa: F401
from hygiene import PrivateRosLogDir, remove_dead_fastdds_segments_after_exit, shm_names
from install_env import sourced_ros, wheel_venv, xrce_wheels  # noqa: F401

_run = {}


@pytest.hookimpl(tryfirst=True)
def pytest_configure(config):
    # Before any test imports rclpy and starts a context: rcl reads ROS_LOG_DIR at its first init.
    _run["ros_log"] = PrivateRosLogDir()
    if not config.option.basetemp:
        # tmp_path under a base of this run's own, removed at its end. Not pytest's numbered
        # /tmp/pytest-of-USER/pytest-N: its "remove when done" (retention "none") takes no lock, so
        # any other pytest run ending meanwhile on the machine deleted this run's tmp_path trees.
        config.option.basetemp = _run["basetemp"] = tempfile.mkdtemp(prefix="xrce-tests-")
    # Every agent a test starts keeps its state store (issue 51) under this run's base, not in
    # the user's ~/.local/state: nothing of one run's sessions is restored into another's agent.
    os.environ["XDG_STATE_HOME"] = os.path.join(str(config.option.basetemp), "xdg-state")
    # One clean-up of /dev/shm per run, the controller's once its workers are gone: a worker's at
    # its own end would probe the lock files of the other worker's live participants (hygiene.py
    # takes a lock to see whether anyone holds it), and a Fast DDS process opening one right then
    # fails its open_and_lock_file.
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        _run["shm_before"] = shm_names()


def pytest_unconfigure(config):
    ros_log = _run.pop("ros_log", None)
    if ros_log is not None:
        ros_log.close()
    if "shm_before" in _run:
        remove_dead_fastdds_segments_after_exit(_run.pop("shm_before"))
    basetemp = _run.pop("basetemp", None)
    if basetemp is not None and not os.environ.get("XRCE_KEEP_TMP"):
        shutil.rmtree(basetemp, ignore_errors=True)


# The longest single tests (20-60 s each, `--durations` of a serial run, docs/PERFORMANCE.md "CI
# time"): on xdist workers they start first, so that none of them is the last test of a worker while
# the other worker has finished. A test missing from here only runs in its usual place.
LONG_TESTS_FIRST = (
    "tests/board/test_turtlebot3_heap.py::test_turtlebot3_runs_a_minute_in_a_capped_heap",
    "tests/microros/test_microros_graph.py::test_graph_capture_replayed_gets_micro_ros_agents_graph",
    "tests/microros/test_microros_replay.py::test_rclc_actions_and_parameters_replayed_into_ros",
    "tests/hostile/test_hostile_network.py::test_memory_budget_holds_under_a_mixed_flood",
    "tests/repo/test_readme_example.py::test_every_readme_shell_line_runs_as_written",
)


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the groups into the tests' ids
def pytest_collection_modifyitems(config, items):
    """README's command runs the suite on pytest-xdist workers (``-n 2 --dist loadgroup``). Tests
    that share an expensive fixture of this tree go to one worker, so that it is built once: those
    of a module-scoped fixture (an agent and its ROS graph, an mpy build), and those of the session
    fixtures of tests/helpers/install_env.py, which also keeps two ~250 MB installs of ROS wheels from
    running at once. Other tests are spread one by one, the longest first."""
    for item in items:
        groups = set()
        fixture_info = getattr(item, "_fixtureinfo", None)
        for definitions in (fixture_info.name2fixturedefs.values() if fixture_info else ()):
            definition = definitions[-1]  # the one this test gets
            if not definition.baseid:  # pytest's and plugins' own (tmp_path_factory, event loops)
                continue
            if definition.scope == "session":
                groups.add("session-fixtures")
            elif definition.scope in ("package", "module", "class"):
                groups.add(definition.baseid)
        if groups:
            item.add_marker(pytest.mark.xdist_group("+".join(sorted(groups))))
    if getattr(config.option, "loadgroup", False):  # set on xdist's workers, which all sort alike
        def rank(item):
            return next((i for i, prefix in enumerate(LONG_TESTS_FIRST) if item.nodeid.startswith(prefix)),
                        len(LONG_TESTS_FIRST))
        items.sort(key=rank)


@pytest.fixture
def pty_pair():
    """Opens raw pseudo-terminal pairs on demand: ``make()`` -> (master fd, slave path)."""
    opened = []

    def make():
        master, slave = os.openpty()
        tty.setraw(master, termios.TCSANOW)
        opened.extend((master, slave))
        return master, os.ttyname(slave)

    yield make
    for fd in opened:
        os.close(fd)
