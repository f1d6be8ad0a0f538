"""The ways xrce gets its rclpy, each installed as a user would (see tests/helpers/install_env.py):

- no ROS on the machine: the PyPI ROS 2 wheels come with xrce; a non-editable wheel install runs
  ``xrce-agent demo`` (its interface packages and cmake include ship in the wheel);
- a sourced ROS 2: installing xrce pulls no ROS wheel, the agent runs on that ROS's rclpy and RMW,
  bridges a client's topic into it and builds a missing message package against it;
- a Raspberry Pi (aarch64, CPython 3.12): the install resolves from binary wheels;
- no rclpy anywhere: ``-m dds`` stops in one line, ``-m ced`` runs.
"""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time

import pytest

from install_env import (
    REPO, _pip_output, clean_env, distributions_in, restore_default_signals, run, start_installed_agent,
    stop_listener_client_and_agent, venv_site,
)
from ros_helpers import ros_domain  # noqa: F401
from xrce.wire import constants as C
from xrce.agent.interfaces import ros_install as rosenv
from xrce.client.session import Session
from xrce.msgs.std_msgs import Header, String
from xrce.msgs.turtlebot3_msgs import SensorState
from xrce.transports.udp import UdpTransport

# The tags pip on a Raspberry Pi 4/5 with Ubuntu 24.04 (glibc 2.39) accepts, oldest first.
PI_PLATFORMS = ("manylinux2014_aarch64", "manylinux_2_17_aarch64", "manylinux_2_28_aarch64",
                "manylinux_2_39_aarch64", "linux_aarch64")
# pip evaluates environment markers on the machine it runs on, whatever --platform and
# --python-version say; this runs pip as a Pi's CPython 3.12 would see its markers.
PIP_AS_ON_A_PI = r"""
import platform, runpy, sys
platform.machine = lambda: "aarch64"
platform.python_version = lambda: "3.12.3"
platform.python_version_tuple = lambda: ("3", "12", "3")
sys.argv = ["pip"] + sys.argv[1:]
runpy.run_module("pip", run_name="__main__", alter_sys=True)
"""


def wheel_requirements(wheel):
    import zipfile

    with zipfile.ZipFile(wheel) as archive:
        (name,) = [n for n in archive.namelist() if n.endswith(".dist-info/METADATA")]
        lines = archive.read(name).decode().splitlines()
    return [line.split(":", 1)[1].strip() for line in lines if line.startswith("Requires-Dist:")]


def test_wheel_dependencies_follow_the_ros_in_use(xrce_wheels, tmp_path):
    pypi = [r for r in wheel_requirements(xrce_wheels["pypi"]) if "extra ==" not in r]
    ros = [r for r in pypi if r.startswith("ros-")]
    assert "ros-jazzy-rclpy[fastrtps]; " + rosenv.PYPI_ROS_MARKER in ros, pypi
    assert all(r.endswith("; " + rosenv.PYPI_ROS_MARKER) for r in ros), ros
    test_msgs = [r for r in wheel_requirements(xrce_wheels["pypi"]) if r.startswith("ros-jazzy-test-msgs;")]
    assert len(test_msgs) == 1 and 'platform_machine == "x86_64"' in test_msgs[0] \
        and 'extra == "test"' in test_msgs[0], test_msgs

    system = wheel_requirements(xrce_wheels["system"])
    assert not [r for r in system if r.startswith("ros-")], system
    assert {"pyserial", "crcmod-plus", "pyyaml", "uvloop"} <= set(system)

    bad = run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", tmp_path, REPO],
              env=clean_env(XRCE_ROS="ros1"))
    assert bad.returncode != 0
    assert "xrce: XRCE_ROS=ros1: use pypi (ROS 2 wheels from PyPI) or system (the sourced ROS 2)" \
        in bad.stdout, _pip_output(bad)


def dry_run_on_a_pi(wheel, tmp_path, as_on_a_pi):
    prefix = [sys.executable, "-c", PIP_AS_ON_A_PI] if as_on_a_pi else [sys.executable, "-m", "pip"]
    platforms = [a for p in PI_PLATFORMS for a in ("--platform", p)]
    result = run(prefix + ["install", "-q", "--dry-run", "--ignore-installed", "--target", tmp_path / "t",
                           *platforms, "--python-version", "3.12", "--only-binary", ":all:",
                           "--report", tmp_path / "report.json", wheel], env=clean_env(), timeout=300)
    assert result.returncode == 0, _pip_output(result)[-3000:]
    report = json.loads((tmp_path / "report.json").read_text())
    return report, {item["metadata"]["name"].lower(): item["download_info"]["url"].rsplit("/", 1)[-1]
                    for item in report["install"]}


def test_install_resolves_on_a_raspberry_pi_with_cpython_312(xrce_wheels, tmp_path):
    # With apt's ROS sourced on the Pi: xrce and four small binary wheels.
    _, chosen = dry_run_on_a_pi(xrce_wheels["system"], tmp_path, as_on_a_pi=False)
    assert set(chosen) == {"xrce", "pyserial", "crcmod-plus", "pyyaml", "uvloop"}, chosen
    for name, filename in chosen.items():
        assert filename.endswith("-none-any.whl") or "aarch64" in filename, (name, filename)
    assert "cp312" in chosen["pyyaml"] and "cp312" in chosen["uvloop"]

    # The wheel built without ROS (as on PyPI): on the Pi its markers leave every ROS wheel out.
    report, chosen = dry_run_on_a_pi(xrce_wheels["pypi"], tmp_path, as_on_a_pi=True)
    assert report["environment"]["platform_machine"] == "aarch64"
    assert report["environment"]["python_version"] == "3.12"
    assert set(chosen) == {"xrce", "pyserial", "crcmod-plus", "pyyaml", "uvloop"}, chosen


def test_without_any_rclpy_dds_fails_in_one_line_and_ced_runs(sourced_ros, tmp_path):
    # The sourced-ROS venv with no ROS sourced: xrce is installed, no rclpy can be had.
    env = clean_env(HOME=str(tmp_path))
    agent = sourced_ros.venv / "bin" / "xrce-agent"
    for command in ([agent, "udp4", "-p", "0"], [agent, "demo", "--duration", "1"]):
        failed = run(command, env=env, timeout=60, cwd=tmp_path)
        assert failed.returncode == 1, failed.stdout
        assert failed.stdout.count("\n") == 1, failed.stdout
        assert failed.stdout.startswith("xrce-agent") and "error: no ROS 2 to bridge to: rclpy is not " \
            "importable (No module named 'rclpy')" in failed.stdout
        assert "source /opt/ros/jazzy/setup.bash" in failed.stdout and "Traceback" not in failed.stdout

    built = run([agent, "build-interfaces"], env=env, timeout=60, cwd=tmp_path)
    assert built.returncode == 1 and built.stdout.count("\n") == 1, built.stdout
    assert built.stdout.startswith("xrce-agent: error: no ROS 2 to build against: source your ROS 2")

    # ROS sourced, but built for another Python than the agent's: the error says so.
    other = "python3.%d" % (sys.version_info[1] + 1)
    (tmp_path / "ros" / "lib" / other / "site-packages" / "rclpy").mkdir(parents=True)
    (tmp_path / "ros" / "share" / "ament_index" / "resource_index").mkdir(parents=True)
    mismatched = run([agent, "udp4", "-p", "0"], timeout=60, cwd=tmp_path,
                     env=dict(env, ROS_DISTRO="jazzy", AMENT_PREFIX_PATH=str(tmp_path / "ros")))
    assert mismatched.returncode == 1 and mismatched.stdout.count("\n") == 1, mismatched.stdout
    assert "the sourced ROS 2 jazzy (%s) has rclpy for %s, not for this python3.%d" % (
        tmp_path / "ros", other, sys.version_info[1]) in mismatched.stdout

    ced = subprocess.Popen([str(agent), "udp4", "-p", "0", "-m", "ced"], env=env, cwd=tmp_path,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                           preexec_fn=restore_default_signals)
    try:
        banner = ced.stdout.readline()
        assert re.match(r"xrce-agent: udp4 agent on port (\d+) \(middleware ced\)", banner), banner
        port = int(re.search(r"port (\d+)", banner).group(1))
        client = Session(UdpTransport("127.0.0.1", port))
        try:
            assert client.create(attempts=5, timeout_ms=1000) and client.ping(1000)
            client.delete(attempts=1, timeout_ms=500)
        finally:
            client.close()
    finally:
        ced.send_signal(signal.SIGINT)
        assert ced.wait(20) == 0


LISTENER = r"""
import sys
import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
from turtlebot3_msgs.msg import SensorState

print("rclpy", rclpy.__file__, flush=True)
rclpy.init()
node = Node("sourced_listener")
got = {}
qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
node.create_subscription(String, "/chatter", lambda m: got.setdefault("chatter", m.data), qos)
node.create_subscription(SensorState, "/sensor_state", lambda m: got.setdefault("sensor", m), qos)
print("ready", flush=True)
while len(got) < 2:
    rclpy.spin_once(node, timeout_sec=0.1)
s = got["sensor"]
print("got", got["chatter"], s.header.frame_id, s.left_encoder, round(s.battery, 2), flush=True)
node.destroy_node()
rclpy.shutdown()
"""


@pytest.mark.timeout(400)
def test_sourced_ros_agent_bridges_into_that_ros_and_builds_types_against_it(
        sourced_ros, ros_domain, tmp_path):  # noqa: F811
    installed = distributions_in(venv_site(sourced_ros.venv))
    assert "xrce" in installed and not [d for d in installed if d.startswith("ros-")], installed

    env = sourced_ros.env(ROS_DOMAIN_ID=str(ros_domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                          XDG_CACHE_HOME=str(tmp_path / "cache"), HOME=str(tmp_path))
    # Exactly the sourced environment, nothing of the test's own venv.
    agent = start_installed_agent(sourced_ros.python, env, tmp_path, "udp4", "-m", "dds")
    listener = client = None
    try:
        log = "".join(agent.output)
        line = re.search(r"INFO +xrce\.agent\.rosenv: (ROS 2 .*)", log)
        assert line, log
        assert line.group(1).startswith("ROS 2 jazzy from the sourced ROS at %s: rclpy " % sourced_ros.prefix)
        assert "at %s, RMW rmw_fastrtps_cpp" % (sourced_ros.site / "rclpy") in line.group(1)
        assert "two ROS installs" not in log, log

        client = Session(UdpTransport("127.0.0.1", agent.port), history=8)
        assert client.create(attempts=5, timeout_ms=1000)
        node = client.create_participant(domain_id=ros_domain, name="pi_board")
        chatter = client.create_writer(node, "/chatter", String, reliable=True)
        # Not in the sourced ROS: the agent builds turtlebot3_msgs against it on first use.
        sensor = client.create_writer(node, "/sensor_state", SensorState, reliable=True)
        started = time.monotonic()
        assert client.run_until_all_status(120000), client.last_statuses
        assert set(client.last_statuses.values()) == {C.STATUS_OK}
        print("lazy build against the sourced ROS: %.1f s" % (time.monotonic() - started))

        listener = subprocess.Popen([str(sourced_ros.python), "-c", LISTENER], env=env, cwd=tmp_path,
                                    stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                    preexec_fn=restore_default_signals)
        first = listener.stdout.readline()
        assert first.startswith("rclpy %s" % (sourced_ros.site / "rclpy")), \
            first + listener.communicate(timeout=10)[0]
        ready = listener.stdout.readline()
        assert ready.strip() == "ready", ready + listener.communicate(timeout=10)[0]
        sample = SensorState(header=Header(frame_id="base"), left_encoder=42, battery=12.25)
        deadline = time.monotonic() + 20
        while listener.poll() is None and time.monotonic() < deadline:
            client.write(chatter, String(data="from the board"))
            client.write(sensor, sample)
            client.run_until_timeout(100)
        output, _ = listener.communicate(timeout=10)
        assert "got from the board base 42 12.25" in output, output
    finally:
        stop_listener_client_and_agent(listener, client, agent)
    log = "".join(agent.output)
    assert "building interface package turtlebot3_msgs" in log, log
    built = list((tmp_path / "cache" / "xrce" / "interfaces").glob("*/.xrce-complete"))
    assert len(built) == 1, built

    # An RMW this ROS lacks: one line naming the ones it has (rcl itself would just exit 102).
    other_rmw = run([sourced_ros.venv / "bin" / "xrce-agent", "udp4", "-p", "0"], timeout=60, cwd=tmp_path,
                    env=dict(env, RMW_IMPLEMENTATION="rmw_cyclonedds_cpp"))
    assert other_rmw.returncode == 1 and other_rmw.stdout.count("\n") == 1, other_rmw.stdout
    assert other_rmw.stdout == ("xrce-agent: error: RMW_IMPLEMENTATION=rmw_cyclonedds_cpp is not installed "
                                "in this ROS 2 (%s has rmw_fastrtps_cpp)\n" % sourced_ros.prefix)


@pytest.mark.timeout(300)
def test_wheel_install_runs_the_demo(wheel_venv, ros_domain, tmp_path):  # noqa: F811
    python, site = wheel_venv
    installed = distributions_in(site)
    assert {"xrce", "ros-jazzy-rclpy"} <= installed
    assert not (site / "__editable__.xrce-0.1.0.pth").exists()
    assert (site / "xrce" / "ros_interfaces" / "turtlebot3_msgs" / "package.xml").exists()
    # Run from an empty directory: nothing of this checkout is importable there.
    demo = run([python.parent / "xrce-agent", "demo", "--duration", "10"], cwd=tmp_path, timeout=240,
               env=clean_env(ROS_DOMAIN_ID=str(ros_domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST"))
    lines = demo.stdout.splitlines()
    assert demo.returncode == 0, demo.stdout
    assert lines[0].startswith("xrce-agent demo: ROS 2 jazzy from PyPI wheels (%s)" % python.parent.parent)
    assert "at %s, RMW rmw_fastrtps_cpp" % (site / "rclpy") in lines[0]
    assert any(l.startswith("sensor_state: #") for l in lines), demo.stdout
    assert any(l.startswith("odom: #") for l in lines), demo.stdout
    assert lines[-1] == "xrce-agent demo: stopped"
