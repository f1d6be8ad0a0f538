"""``xrce-agent demo [--serial]``: agent + simulated TurtleBot3 + a ROS 2 node, in one command.

The agent (``-m dds``) and the robot (``python -m xrce.examples.turtlebot3``, over UDP or, with
``--serial``, over the agent's pseudoterminal at 115200 baud) run as child processes in their own
process group, so a terminal Ctrl-C reaches only the demo, which then stops the robot first (it
deletes its session) and the agent second. This process is the ROS side: it prints what arrives on
``/sensor_state`` and ``/odom`` once a second and drives a square on ``/cmd_vel``. It uses the
user's ROS_DOMAIN_ID (default 0), so ``ros2 topic echo /odom`` works alongside. Its options
(``--serial``, ``--duration``) are declared in ``xrce.agent.cli``, which imports this module only
when the demo runs.
"""

from __future__ import annotations

import math
import os
import re
import selectors
import signal
import subprocess
import sys
import threading
import time

PROG = "xrce-agent demo"
SIDE_M = 0.5
LINEAR_SPEED = 0.15
ANGULAR_SPEED = 0.6
COMMAND_PERIOD_S = 0.1  # 10 Hz: well inside the robot's 0.5 s fail-safe
PRINT_PERIOD_S = 1.0
START_TIMEOUT_S = 60.0


def _say(text):
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def _wait_banner(proc, timeout_s):
    """The agent's banner line (port or pseudoterminal path), or None if it ended first."""
    selector = selectors.DefaultSelector()
    selector.register(proc.stdout, selectors.EVENT_READ)
    deadline = time.monotonic() + timeout_s
    try:
        while time.monotonic() < deadline:
            if not selector.select(timeout=0.5):
                if proc.poll() is not None:
                    return None
                continue
            line = proc.stdout.readline()
            if not line:
                return None
            if line.startswith("xrce-agent:") and ("on port" in line or "pseudoterminal at" in line):
                return line.strip()
    finally:
        selector.close()
    return None


def _forward_output(proc, prefix):
    """Relay a child's output lines to ours (a thread per child: the pipes must never fill)."""
    def pump():
        for line in proc.stdout:
            _say(prefix + line.rstrip("\n"))
    thread = threading.Thread(target=pump, daemon=True)
    thread.start()
    return thread


def stop_child(proc, timeout_s=10.0):
    """SIGINT ``proc`` as Ctrl-C would (an agent then destroys its ROS entities), wait, and kill it
    if it hangs. The benches stop their child processes with it too."""
    if proc is None or proc.poll() is not None:
        return
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def _ensure_interfaces():
    """Build turtlebot3_msgs and tf2_msgs (a cache hit after the first run) unless the ROS in use
    has them already (apt's ros-jazzy-tf2-msgs, ...); False if not possible."""
    import importlib.machinery

    try:
        from xrce.agent import interfaces
        missing = [name for name in ("tf2_msgs", "turtlebot3_msgs")
                   if importlib.machinery.PathFinder.find_spec(name) is None]
        if missing:
            interfaces.build(names=missing)
        from turtlebot3_msgs.msg import SensorState  # noqa: F401
        return True
    except Exception as exc:  # the demo still shows /odom without them
        _say("%s: turtlebot3_msgs unavailable (%s); /sensor_state will not be shown" % (PROG, exc))
        return False


def _yaw(q):
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


class _Square:
    """Forward SIDE_M, turn 90°, four times, again and again: open-loop timing on /cmd_vel."""

    def __init__(self):
        self.legs = ((LINEAR_SPEED, 0.0, SIDE_M / LINEAR_SPEED),
                     (0.0, ANGULAR_SPEED, (math.pi / 2) / ANGULAR_SPEED))
        self.index = 0
        self.leg_started = time.monotonic()

    def command(self, now):
        linear, angular, seconds = self.legs[self.index % 2]
        if now - self.leg_started >= seconds:
            self.index += 1
            self.leg_started = now
            linear, angular, _ = self.legs[self.index % 2]
        return linear, angular


def run(args):
    from xrce.agent import rosenv

    try:
        line, warning = rosenv.describe()
    except rosenv.RosUnavailable as exc:
        sys.stderr.write("%s: error: %s\n" % (PROG, exc))
        return 1
    _say("%s: %s" % (PROG, line))
    if warning:
        _say("%s: warning: %s" % (PROG, warning))
    stop = threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    have_sensor_state = _ensure_interfaces()
    domain = int(os.environ.get("ROS_DOMAIN_ID", "0") or 0)
    agent = robot = None
    try:
        link = ["pseudoterminal"] if args.serial else ["udp4", "-p", "0"]
        agent = subprocess.Popen([sys.executable, "-m", "xrce.agent", *link, "-m", "dds", "-v", "3"],
                                 stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                 start_new_session=True)
        banner = _wait_banner(agent, START_TIMEOUT_S)
        if banner is None or stop.is_set():
            _say("%s: the agent did not start" % PROG)
            return 0 if stop.is_set() else 1
        _say(banner)
        _forward_output(agent, "[agent] ")
        if args.serial:
            device = re.search(r"pseudoterminal at (\S+)", banner).group(1)
            robot_link = ["serial", "--dev", device, "-b", "115200"]
        else:
            robot_link = ["udp4", "--agent", "127.0.0.1", "-p", re.search(r"on port (\d+)", banner).group(1)]
        robot = subprocess.Popen([sys.executable, "-m", "xrce.examples.turtlebot3", *robot_link,
                                  "--domain", str(domain)],
                                 stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                 start_new_session=True)
        _forward_output(robot, "[robot] ")
        _ros_side(domain, have_sensor_state, stop, args.duration)
        return 0
    finally:
        stop_child(robot)
        stop_child(agent)
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        _say("%s: stopped" % PROG)


def _ros_side(domain, have_sensor_state, stop, duration_s):
    import rclpy
    from geometry_msgs.msg import Twist
    from nav_msgs.msg import Odometry
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rclpy.signals import SignalHandlerOptions

    context = Context()
    rclpy.init(args=[], context=context, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
    node = Node("turtlebot3_demo", context=context, start_parameter_services=False)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    latest = {}
    counts = {"sensor_state": 0, "odom": 0}

    def keep(topic):
        def callback(msg):
            latest[topic] = (time.time_ns(), msg)
            counts[topic] += 1
        return callback

    node.create_subscription(Odometry, "/odom", keep("odom"), QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    if have_sensor_state:
        from turtlebot3_msgs.msg import SensorState
        node.create_subscription(SensorState, "/sensor_state", keep("sensor_state"),
                                 QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
    cmd_vel = node.create_publisher(Twist, "/cmd_vel", 10)
    square = _Square()
    started = time.monotonic()
    next_command = next_print = started
    _say("%s: ROS domain %d; driving a %.1f m square on /cmd_vel (Ctrl-C to stop)" % (PROG, domain, SIDE_M))
    try:
        while not stop.is_set():
            now = time.monotonic()
            if duration_s and now - started >= duration_s:
                break
            if now >= next_command:
                next_command += COMMAND_PERIOD_S
                twist = Twist()
                twist.linear.x, twist.angular.z = square.command(now)
                cmd_vel.publish(twist)
            if now >= next_print:
                next_print += PRINT_PERIOD_S
                _print_status(latest, counts)
            executor.spin_once(timeout_sec=max(0.0, min(next_command, next_print) - time.monotonic()))
    finally:
        executor.remove_node(node)
        node.destroy_node()
        executor.shutdown()
        context.try_shutdown()


def _print_status(latest, counts):
    if "sensor_state" in latest:
        received, msg = latest["sensor_state"]
        age_ms = (received - (msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)) / 1e6
        _say("sensor_state: #%d encoders L=%d R=%d battery=%.2f V torque=%s (stamp→receive %.2f ms)"
             % (counts["sensor_state"], msg.left_encoder, msg.right_encoder, msg.battery,
                "on" if msg.torque else "off", age_ms))
    if "odom" in latest:
        _, msg = latest["odom"]
        pose, twist = msg.pose.pose, msg.twist.twist
        _say("odom: #%d x=%+.3f m y=%+.3f m yaw=%+6.1f° v=%.2f m/s w=%+.2f rad/s"
             % (counts["odom"], pose.position.x, pose.position.y, math.degrees(_yaw(pose.orientation)),
                twist.linear.x, twist.angular.z))
    if not latest:
        _say("waiting for the robot...")
