"""The simulated TurtleBot3 end to end: firmware (CPython thread or MicroPython) ↔ xrce-agent -m dds ↔
rclpy, over UDP and over the agent's pseudoterminal at 115200 baud; and the ``xrce-agent demo``.

Every test leases its own ROS domain with localhost-only discovery and stops what it starts.

Why the stamp check is sound: the robot stamps with ``Session.epoch_ns()``, the agent's clock after
``sync_time``; the agent runs on this machine, so its clock *is* the test's ``time.time_ns()``. The
receive time in the rclpy callback minus the stamp is then the transport delay plus the sync error
(half a loopback round trip at most); both are well under a millisecond on loopback, so a stamp
more than 5 ms away from the receive time means the stamp is wrong (not synced, or taken at the
wrong moment), not that the link is slow.
"""

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from geometry_msgs.msg import Twist as RosTwist
from nav_msgs.msg import Odometry as RosOdometry
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu as RosImu

from agent_process import AgentProcess, child_pids, restore_default_signals
from mp_harness import run_micropython
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from xrce.examples.turtlebot3 import ENCODER_TICKS_PER_REV, TurtleBot3
from xrce.transports.serial import SerialTransport
from xrce.transports.udp import UdpTransport

REPO = Path(__file__).resolve().parents[2]
MP_SCRIPT = Path(__file__).resolve().parents[1] / "micropython" / "turtlebot3_main.py"
RELIABLE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
BEST_EFFORT = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT)
STAMP_SANITY_NS = 200_000_000  # a stamp from another clock would be seconds off
# The sync error is half a loopback round trip; a stamp later than the receive time by more than
# this would mean the robot's clock runs ahead of the agent's.
SYNC_ERROR_NS = 1_000_000
FAILSAFE_SANITY_S = 2.0


def _sync_bound(rtt_ns, clock_step_ns=1000):
    # With one clock on both ends the true offset is 0, and a sync is only sure of it to within
    # half the round trip of the exchange it kept (the asymmetry of a stalled leg on a loaded
    # machine can take all of it: a fixed 1-2 ms bound failed there), plus the client clock's
    # step, by which its two readings can each be off. The round trip itself must stay that of a
    # local exchange.
    assert -clock_step_ns <= rtt_ns < 20 * SYNC_ERROR_NS, rtt_ns  # a step can make it negative
    return max(rtt_ns, 0) // 2 + clock_step_ns


def turtlebot3_msgs_types():
    """(SensorState, TFMessage) rclpy classes, building them first when the build tool exists;
    None when they cannot be had on this machine yet."""
    try:
        from xrce.agent import interfaces
    except ImportError:
        interfaces = None
    if interfaces is not None:
        interfaces.build(names=["tf2_msgs", "turtlebot3_msgs"])  # a cache hit after the first time
    try:
        from tf2_msgs.msg import TFMessage
        from turtlebot3_msgs.msg import SensorState
    except ImportError:
        return None
    return SensorState, TFMessage


class Stamped:
    """Collects (receive wall-clock ns, message) from an rclpy subscription callback."""

    def __init__(self):
        self.samples = []

    def __call__(self, msg):
        self.samples.append((time.time_ns(), msg))

    def between(self, start_ns, end_ns):
        return [(t, m) for t, m in self.samples if start_ns <= t < end_ns]


def stamp_ns(msg):
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def check_rate_and_stamps(collected, start_ns, end_ns, hz, stamp_error_ns):
    """The robot publishes at ``hz`` (counted by its own stamps: deliveries bunch up on a loaded
    machine, the robot's schedule does not) and its stamps are the agent's clock to within
    ``stamp_error_ns``, the error its time sync itself admits. How small the stamp-to-receive delay
    is, is bench/agent/sensor_state_delay.py's figure; here only a sanity bound (issue 23: a fixed -1 ms
    failed beside a CPU hog, where one sync's round trip took longer)."""
    window = collected.between(start_ns, end_ns)
    assert len(window) >= 10, len(window)
    stamps = sorted(stamp_ns(msg) for _, msg in window)
    rate = (len(stamps) - 1) / ((stamps[-1] - stamps[0]) / 1e9)
    assert abs(rate - hz) <= 0.2 * hz, (rate, len(window))
    delays = sorted(received - stamp_ns(msg) for received, msg in window)
    # delay = transport + stamp error, transport >= 0: a stamp from the future (the robot's synced
    # clock ahead of the agent's) shows as a negative delay, never beyond the sync's own error.
    assert delays[0] > -stamp_error_ns, (delays[:5], stamp_error_ns)
    assert delays[len(delays) // 2] < STAMP_SANITY_NS, delays[len(delays) // 2]
    return rate, delays


class RobotThread(threading.Thread):
    """The CPython firmware in its own thread, as it would run on its own MCU."""

    def __init__(self, transport, domain_id, cmd_vel_reliable, key=None):
        super().__init__(daemon=True, name="turtlebot3")
        # Time sync every second instead of 10 s, so the periodic path runs inside the measurement.
        self.robot = TurtleBot3(transport, domain_id=domain_id, cmd_vel_reliable=cmd_vel_reliable,
                                time_sync_period_ms=1000, key=key, log=lambda text: None)
        self.ready = threading.Event()
        self.failed = None
        self._halt = threading.Event()
        self.largest_offset_ns = 0  # the largest |time offset| the syncs kept during the run

    def run(self):
        try:
            if self.robot.connect(timeout_ms=500, attempts=20) is None or not self.robot.setup():
                self.failed = "no agent or setup failed"
                return
            self.ready.set()
            self.robot.run(should_stop=self._watch_offset_and_halt)
        except Exception as exc:  # reported by the test, which would otherwise only time out
            self.failed = repr(exc)
            raise

    def _watch_offset_and_halt(self):
        offset = abs(self.robot.session.time_offset_ns)
        if offset > self.largest_offset_ns:
            self.largest_offset_ns = offset
        return self._halt.is_set()

    def stop(self):
        self._halt.set()
        self.join(5)
        self.robot.shutdown()


def drive(publisher, twist, seconds, hz=30):
    """Publish ``twist`` at ``hz`` for ``seconds``; (number published, wall-clock ns of the last)."""
    period = 1.0 / hz
    count = 0
    next_at = time.monotonic()
    end = next_at + seconds
    while next_at < end:
        publisher.publish(twist)
        last_ns = time.time_ns()
        count += 1
        next_at += period
        pause = next_at - time.monotonic()
        if pause > 0:
            time.sleep(pause)
    return count, last_ns


def forward_twist(speed):
    twist = RosTwist()
    twist.linear.x = speed
    return twist


def wait_for_failsafe(odom, stopped_ns, timeout_s=3.0):
    """Seconds from the last command to the first /odom whose twist is zero."""
    assert wait_until(lambda: any(t > stopped_ns and m.twist.twist.linear.x == 0.0
                                  for t, m in odom.samples), timeout_s)
    first = min(t for t, m in odom.samples if t > stopped_ns and m.twist.twist.linear.x == 0.0)
    return (first - stopped_ns) / 1e9


def run_flow(agent, ros_peer, domain, transport, cmd_vel_reliable):  # noqa: F811
    types = turtlebot3_msgs_types()
    node = ros_peer.node
    imu, odom, sensor_state, tf = Stamped(), Stamped(), Stamped(), Stamped()
    node.create_subscription(RosImu, "/imu", imu, BEST_EFFORT)
    node.create_subscription(RosOdometry, "/odom", odom, RELIABLE)
    if types is not None:
        node.create_subscription(types[0], "/sensor_state", sensor_state, BEST_EFFORT)
        node.create_subscription(types[1], "/tf", tf, RELIABLE)
    cmd_vel = node.create_publisher(RosTwist, "/cmd_vel", RELIABLE if cmd_vel_reliable else BEST_EFFORT)

    robot_thread = RobotThread(transport, domain, cmd_vel_reliable)
    robot_thread.start()
    robot = robot_thread.robot
    try:
        assert robot_thread.ready.wait(30), robot_thread.failed
        assert ("sensor_state" in robot.failed_topics) == (types is None), robot.failed_topics
        # One clock: the offset is 0 to within half the round trip of the exchange the sync kept.
        assert abs(robot.session.time_offset_ns) <= _sync_bound(robot.session.time_rtt_ns)
        assert wait_until(lambda: node.count_subscribers("/cmd_vel") >= 1 and odom.samples
                          and imu.samples and (types is None or sensor_state.samples), 15)

        # 3 s of 30 Hz commands; the sensor streams are measured over the same window.
        start_ns = time.time_ns()
        sent, last_command_ns = drive(cmd_vel, forward_twist(0.1), 3.0)
        stopped_ns = time.time_ns()
        # One clock on both ends: a stamp is off by the offset the sync kept (plus a clock step).
        stamp_error_ns = robot_thread.largest_offset_ns + 1000
        check_rate_and_stamps(imu, start_ns, stopped_ns, 10, stamp_error_ns)
        if types is not None:
            check_rate_and_stamps(sensor_state, start_ns, stopped_ns, 10, stamp_error_ns)
            last = sensor_state.samples[-1][1]
            assert last.torque and 10.5 <= last.battery <= 12.4
            assert last.left_encoder == last.right_encoder > 0  # straight ahead: both wheels alike

        if cmd_vel_reliable:
            assert wait_until(lambda: robot.commands_received == sent, 15), (robot.commands_received, sent)
        else:
            assert robot.commands_received >= 0.9 * sent, (robot.commands_received, sent)
        assert robot.last_command == (0.1, 0.0)
        # 0.1 m/s for ~3 s straight ahead: odom moves along +x only.
        moving = [m for t, m in odom.between(start_ns + 500_000_000, stopped_ns)]
        assert moving and all(m.twist.twist.linear.x == 0.1 for m in moving)
        position = odom.between(0, stopped_ns)[-1][1].pose.pose.position
        assert 0.25 <= position.x <= 0.32 and abs(position.y) < 1e-9, (position.x, position.y)
        ticks = robot.left_ticks
        expected_ticks = robot.x / (2 * 3.141592653589793 * 0.033) * ENCODER_TICKS_PER_REV
        assert abs(ticks - expected_ticks) <= 1

        failsafe_s = wait_for_failsafe(odom, last_command_ns)
        # Never before its 0.5 s; the upper bound is a sanity bound (a loaded machine delays /odom).
        assert 0.5 <= failsafe_s <= FAILSAFE_SANITY_S, failsafe_s
        assert robot.failsafe_trips == 1
        assert robot.time_syncs >= 4  # at start, then every second of the run
        if types is not None:  # odom -> base_footprint follows the same pose as /odom
            _, tf_msg = tf.between(0, stopped_ns)[-1]
            (transform,) = tf_msg.transforms
            assert (transform.header.frame_id, transform.child_frame_id) == ("odom", "base_footprint")
            assert abs(transform.transform.translation.x - position.x) < 0.011  # one 10 Hz period
            assert transform.transform.rotation.w == 1.0
        return robot
    finally:
        robot_thread.stop()


@pytest.mark.timeout(60)
def test_robot_over_udp_reliable_cmd_vel(ros_peer, ros_domain):  # noqa: F811
    with AgentProcess("udp4", "-m", "dds") as agent:
        run_flow(agent, ros_peer, ros_domain, UdpTransport("127.0.0.1", agent.port), True)


@pytest.mark.timeout(60)
def test_robot_over_pty_at_115200_best_effort_cmd_vel(ros_peer, ros_domain):  # noqa: F811
    with AgentProcess("pseudoterminal", "-m", "dds") as agent:
        run_flow(agent, ros_peer, ros_domain, SerialTransport(agent.device, 115200), False)


@pytest.mark.timeout(120)
def test_robot_under_micropython_over_udp(ros_peer, ros_domain):  # noqa: F811
    types = turtlebot3_msgs_types()
    node = ros_peer.node
    imu, odom, sensor_state = Stamped(), Stamped(), Stamped()
    node.create_subscription(RosImu, "/imu", imu, BEST_EFFORT)
    node.create_subscription(RosOdometry, "/odom", odom, RELIABLE)
    if types is not None:
        node.create_subscription(types[0], "/sensor_state", sensor_state, BEST_EFFORT)
    cmd_vel = node.create_publisher(RosTwist, "/cmd_vel", RELIABLE)
    with AgentProcess("udp4", "-m", "dds") as agent:
        result = {}
        runner = threading.Thread(target=lambda: result.setdefault(
            "run", run_micropython(MP_SCRIPT, agent.port, ros_domain, 8, 1, timeout=90)), daemon=True)
        runner.start()
        assert wait_until(lambda: odom.samples and node.count_subscribers("/cmd_vel") >= 1, 60)
        start_ns = time.time_ns()
        sent, last_command_ns = drive(cmd_vel, forward_twist(0.1), 2.0)
        stopped_ns = time.time_ns()
        failsafe_s = wait_for_failsafe(odom, last_command_ns)
        runner.join(100)
    run = result["run"]
    assert run.returncode == 0, run.stdout + run.stderr
    lines = dict(line.split(" ", 1) for line in run.stdout.splitlines() if " " in line)
    assert lines["connect"] == lines["setup"] == lines["done"] == "True", run.stdout
    # The WebAssembly port's time.time_ns() moves in whole milliseconds (JavaScript's Date.now()).
    assert abs(int(lines["time_offset_ns"])) <= _sync_bound(int(lines["time_rtt_ns"]), SYNC_ERROR_NS)
    assert (lines["failed_topics"] == "-") == (types is not None), lines["failed_topics"]
    assert int(lines["commands_received"]) == sent and lines["last_command"] == "0.1,0.0"
    assert lines["failsafe_trips"] == "1" and 0.5 <= failsafe_s <= FAILSAFE_SANITY_S, failsafe_s
    # 0.1 m/s for the 2 s of commands and the 0.5 s until the fail-safe stops the wheels.
    assert 0.22 <= float(lines["x"]) <= 0.28 and float(lines["y"]) == 0.0, run.stdout
    # The one sync of the run (its period is 10 s) kept this offset; the port's clock steps 1 ms.
    stamp_error_ns = abs(int(lines["time_offset_ns"])) + SYNC_ERROR_NS
    check_rate_and_stamps(imu, start_ns, stopped_ns, 10, stamp_error_ns)
    if types is not None:
        check_rate_and_stamps(sensor_state, start_ns, stopped_ns, 10, stamp_error_ns)
        assert sensor_state.samples[-1][1].left_encoder > 0


def pid_alive(pid):
    try:
        with open("/proc/%d/stat" % pid) as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.timeout(90)
@pytest.mark.parametrize("serial", [False, True], ids=["udp", "serial"])
def test_demo_prints_robot_topics_and_exits_cleanly_on_sigint(ros_domain, serial):  # noqa: F811
    command = [sys.executable, "-m", "xrce.agent", "demo"] + (["--serial"] if serial else [])
    demo = subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=restore_default_signals)
    lines = []
    reader = threading.Thread(target=lambda: lines.extend(demo.stdout), daemon=True)
    reader.start()
    try:
        assert wait_until(lambda: any(l.startswith("odom:") and "v=0.15" in l for l in lines)
                          and any(l.startswith("sensor_state:") for l in lines), 60), "".join(lines)
        children = child_pids(demo.pid)
        assert len(children) == 2, children  # the agent and the robot
        demo.send_signal(signal.SIGINT)
        assert demo.wait(30) == 130, "".join(lines)  # as a shell reports a command Ctrl-C ended
    finally:
        if demo.poll() is None:
            demo.kill()
            demo.wait()
    reader.join(5)
    assert not [pid for pid in children if pid_alive(pid)]
    assert lines[-1].strip() == "xrce-agent demo: stopped"
    assert any("[robot] turtlebot3: at x=" in l for l in lines)  # the robot's own clean-exit line


@pytest.mark.timeout(60)
def test_robot_pings_until_an_agent_appears_then_runs():
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    logged = []
    robot = TurtleBot3(UdpTransport("127.0.0.1", port), log=logged.append)
    outcome = {}
    connecting = threading.Thread(target=lambda: outcome.setdefault("rtt", robot.connect(timeout_ms=200)),
                                  daemon=True)
    connecting.start()
    try:
        time.sleep(1.5)
        assert connecting.is_alive() and logged  # still pinging, and saying so
        with AgentProcess("udp4", "-m", "ced", "-p", str(port)):
            connecting.join(10)
            assert outcome.get("rtt") is not None
            assert robot.setup() and robot.failed_topics == []  # ced: every type is accepted
            robot.run(duration_ms=1000)
            assert 9 <= robot.published["sensor_state"] <= 11  # 10 Hz over the 1 s run
            robot.shutdown()
    finally:
        robot.transport.close()


def _robot_process(port):
    return subprocess.Popen([sys.executable, "-m", "xrce.examples.turtlebot3", "udp4", "-p", str(port)],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=restore_default_signals)


@pytest.mark.timeout(120)
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
@pytest.mark.parametrize("with_agent", [False, True], ids=["waiting", "running"])
def test_robot_command_line_ends_on_sigterm_and_sigint(signum, with_agent):
    # Issue 32: SIGTERM was ignored while the robot still pinged for an agent (connect() forever).
    # The real command line in a real process, the signal sent once it says where it is.
    import socket
    from contextlib import ExitStack

    from procs import read_until

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with ExitStack() as stack:
        if with_agent:
            port = stack.enter_context(AgentProcess("udp4", "-m", "ced")).port
        robot = _robot_process(port)
        try:
            marker = "turtlebot3: running" if with_agent else "waiting for the agent"
            line, output = read_until(robot, lambda text: marker in text, 60)
            assert line is not None, output
            robot.send_signal(signum)
            rest, _ = robot.communicate(timeout=20)
        finally:
            if robot.poll() is None:
                robot.kill()
                robot.communicate()
        assert robot.returncode == 0, output + rest
        assert "turtlebot3: at x=" in rest  # the clean exit's last status line


def test_largest_sample_constant_is_the_largest_sample():
    # LARGEST_SAMPLE sizes the session's buffers before the messages exist (issue 32): it must be
    # what the largest of them serializes to, or /odom would grow a buffer in the loop.
    from xrce.examples.turtlebot3 import LARGEST_SAMPLE

    transport = UdpTransport("127.0.0.1", 9)
    try:
        robot = TurtleBot3(transport)
        samples = (robot._sensor_state, robot._imu, robot._battery, robot._odom, robot._tf)
        assert max(len(sample.to_bytes()) for sample in samples) == LARGEST_SAMPLE
        reliable = robot.session._outputs[robot.session.reliable]
        assert len(reliable.big) >= 4 + 8 + LARGEST_SAMPLE  # header, subheader and ids, the sample
    finally:
        transport.close()
