"""``--version`` on both commands, as an installed user runs them (the venv's console scripts):
xrce's version, and for the agent the ROS 2 distribution, RMW and DDS it would join, found
without importing rclpy. And how xrce picks which distribution's PyPI wheels to depend on
(``XRCE_ROS_DISTRO``, xrce/agent/interfaces/ros_install.py)."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import xrce
from agent_process import AgentProcess
from ros_helpers import ros_domain  # noqa: F401
from xrce.agent.interfaces import ros_install as rosenv

BIN = Path(sys.executable).parent
TIMEOUT = 60


def _run(command, *args, **extra_env):
    env = {k: v for k, v in os.environ.items() if k != "RMW_IMPLEMENTATION"}
    env.update(extra_env)
    return subprocess.run([str(BIN / command), *args], env=env, capture_output=True, text=True,
                          timeout=TIMEOUT)


def test_client_version_is_one_line():
    done = _run("xrce-client", "--version")
    assert done.returncode == 0 and done.stderr == "", done
    assert done.stdout.splitlines() == ["xrce-client %s (DDS-XRCE 1.0, Python %d.%d.%d)"
                                        % ((xrce.__version__,) + tuple(sys.version_info[:3]))]


def test_agent_version_names_the_ros_it_would_join():
    pytest.importorskip("rclpy")
    done = _run("xrce-agent", "--version")
    assert done.returncode == 0 and done.stderr == "", done
    lines = done.stdout.splitlines()
    assert lines[0].startswith("xrce-agent %s (DDS-XRCE 1.0" % xrce.__version__), lines
    # The same distribution and Fast DDS the agent then names in its first log line.
    line, _ = rosenv.describe()
    distro = line.split()[2]
    assert lines[1].startswith("ROS 2 %s (" % distro), (lines, line)
    fastdds = rosenv.installed_fastdds()
    assert lines[1].endswith("RMW rmw_fastrtps_cpp (Fast DDS %s)" % fastdds[1]), lines
    assert "RMW rmw_fastrtps_cpp (Fast DDS %s)" % fastdds[1] in line, line

    other = _run("xrce-agent", "--version", RMW_IMPLEMENTATION="rmw_nonexistent_cpp")
    assert other.returncode == 0
    assert other.stdout.splitlines()[1].endswith(
        "RMW rmw_nonexistent_cpp (not installed: this ROS 2 has %s)" % ", ".join(rosenv.installed_rmws()))


def test_the_agent_first_line_names_the_distribution_and_the_dds_it_loaded(ros_domain):  # noqa: F811
    pytest.importorskip("rclpy")
    version = _run("xrce-agent", "--version").stdout.splitlines()[1]
    distro = version.split()[2]
    fastdds = rosenv.installed_fastdds()[1]
    with AgentProcess("udp4") as agent:
        pass
    log = "".join(agent.output)
    line = re.search(r"INFO +xrce\.agent\.rosenv: (ROS 2 .*)", log)
    assert line, log
    # e.g. "ROS 2 kilted from PyPI wheels (...): rclpy 9.1.2 at ..., RMW rmw_fastrtps_cpp (Fast DDS 3.2.2)"
    assert line.group(1).startswith("ROS 2 %s from " % distro), line.group(1)
    assert line.group(1).endswith("RMW rmw_fastrtps_cpp (Fast DDS %s)" % fastdds), line.group(1)
    assert "XMLPARSER" not in log and "deprecated" not in log, log


@pytest.mark.parametrize("command", ["xrce-agent", "xrce-client"])
def test_a_bad_version_argument_is_one_line_and_exit_2(command):
    done = _run(command, "--version=3")
    assert done.returncode == 2 and done.stdout == "", done
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("%s: error: " % command), lines


def test_the_distribution_of_the_wheels_is_chosen_at_install():
    for distro in rosenv.PYPI_DISTROS:
        install, extras = rosenv.install_requirements({rosenv.DISTRO_VARIABLE: distro})
        ros = [r for r in install + extras["test"] if r.startswith("ros-")]
        assert "ros-%s-rclpy[fastrtps]; %s" % (distro, rosenv.PYPI_ROS_MARKER) in ros
        assert all(r.startswith("ros-%s-" % distro) for r in ros), ros
        assert "ros-%s-test-msgs; %s" % (distro, rosenv.PYPI_ROS_MARKER) in extras["test"]
    # Jazzy stays the default; PyPI has no python-cmake-module for Kilted (nor does it need one),
    # and Kilted's typesupport generators need ament_cmake_ros_core to build interface packages.
    assert "ros-kilted-ament-cmake-ros-core; " + rosenv.PYPI_ROS_MARKER in \
        rosenv.install_requirements({"XRCE_ROS_DISTRO": "kilted"})[0]
    assert rosenv.install_requirements({})[0] == rosenv.install_requirements({"XRCE_ROS_DISTRO": "jazzy"})[0]
    assert not [r for r in rosenv.install_requirements({"XRCE_ROS_DISTRO": "Kilted"})[0]
                if "python-cmake-module" in r]
    # A sourced ROS decides alone: the variable picks no wheels then.
    install, _ = rosenv.install_requirements({"XRCE_ROS_DISTRO": "kilted", "ROS_DISTRO": "kilted"})
    assert not [r for r in install if r.startswith("ros-")]
    with pytest.raises(ValueError, match="XRCE_ROS_DISTRO=humble: PyPI has ROS 2 wheels of jazzy and "
                                         "kilted only"):
        rosenv.install_requirements({"XRCE_ROS_DISTRO": "humble"})
