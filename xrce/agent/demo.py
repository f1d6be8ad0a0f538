"""``xrce-agent demo [--serial] [--domain N | --lan]``: agent + simulated TurtleBot3 + a ROS 2 node,
in one command.

The agent (``-m dds``) and the robot (``python -m xrce.examples.turtlebot3``, over UDP or, with
``--serial``, over the agent's pseudoterminal at 115200 baud) run as child processes in their own
sessions, so a terminal's Ctrl-C or hang-up reaches only the demo, which then stops the robot first
(it deletes its session) and the agent second, and exits only when both are gone (130 after Ctrl-C,
129 after SIGHUP, 143 after SIGTERM). This process is the ROS side: it prints what arrives on
``/sensor_state`` and ``/odom`` once a second and drives a closed square on ``/cmd_vel``, except
while the robot runs a ``/patrol`` goal (its action status says so): a command would pre-empt the
patrol, so the demo yields ``/cmd_vel`` to it and drives on when the goal has ended.

The demo publishes ``/cmd_vel``, which a real robot obeys: by default everything runs in a ROS
domain of its own (the first free one of ``PRIVATE_DOMAINS``, held through an abstract socket
name, so no lock file is left anywhere) with localhost-only discovery, and the banner says how to
watch it from another shell. ``--domain N`` or ``--lan`` (the user's ``ROS_DOMAIN_ID``) publish
with the usual discovery range, after a warning line. Its options are declared in
``xrce.agent.cli.subcommands``, which imports this module only when the demo runs.
"""

from __future__ import annotations

import math
import os
import re
import selectors
import signal
import socket
import subprocess
import sys
import threading
import time

from xrce.agent.middleware import MAX_DOMAIN_ID
from xrce.tools.ros_cli import ros2_command

PROG = "xrce-agent demo"
SIDE_M = 0.5
LINEAR_SPEED = 0.15  # nominal; the legs are fitted to whole command periods (_Square)
ANGULAR_SPEED = 0.6
COMMAND_PERIOD_S = 0.1  # 10 Hz: well inside the robot's 0.5 s fail-safe
PRINT_PERIOD_S = 1.0
START_TIMEOUT_S = 60.0
BUILD_PROGRESS_PERIOD_S = 5.0
PRIVATE_DOMAINS = range(150, 170)  # clear of the test suite's leases (24, 40..99)
EXIT_CODES = {signal.SIGINT: 130, signal.SIGHUP: 129, signal.SIGTERM: 143}


def _say(text):
    """A line on stdout; a terminal that went away (SIGHUP) must not stop the clean-up."""
    try:
        sys.stdout.write(text + "\n")
        sys.stdout.flush()
    except (OSError, ValueError):
        pass


class UsageError(Exception):
    """A setting the demo cannot run with: one line, exit code 2."""


def _private_domain():
    """(domain id, the socket that holds it): the first domain of PRIVATE_DOMAINS no other demo on
    this machine holds. An abstract-namespace socket name is the lock: the kernel drops it with
    the process, however it ends, and it leaves no file behind."""
    for domain in PRIVATE_DOMAINS:
        holder = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            holder.bind("\0xrce-agent-demo-domain-%d" % domain)
        except OSError:
            holder.close()
            continue
        return domain, holder
    raise UsageError("every private demo domain %d..%d is taken by another demo; pass --domain N"
                     % (PRIVATE_DOMAINS[0], PRIVATE_DOMAINS[-1]))


def _user_domain():
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return 0
    try:
        domain = int(text)
    except ValueError:
        domain = -1
    # Checked before anything starts (--domain is checked by its parser): Fast DDS ends the whole
    # process (exit 1, no exception) when this process's own node joins a domain over 232, which
    # left the demo's agent and robot running; the agent itself refuses the robot's participant.
    if not 0 <= domain <= MAX_DOMAIN_ID:
        raise UsageError("ROS_DOMAIN_ID=%s is not a domain id in 0..%d (unset it, or pass "
                         "--domain N)" % (text, MAX_DOMAIN_ID))
    return domain


def choose_network(args):
    """(domain, localhost only, holder socket or None, environment for the children)."""
    env = dict(os.environ)
    env.pop("PYTHONSTARTUP", None)
    if args.domain is None and not args.lan:
        domain, holder = _private_domain()
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        env.pop("ROS_STATIC_PEERS", None)
        env.pop("ROS_LOCALHOST_ONLY", None)  # Jazzy's deprecated switch; the range above decides
        env["ROS_DOMAIN_ID"] = str(domain)
        return domain, True, holder, env
    domain = args.domain if args.domain is not None else _user_domain()
    env["ROS_DOMAIN_ID"] = str(domain)
    return domain, False, None, env


_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def _wait_banner(proc, timeout_s, stop, seen):
    """The agent's banner line (port or pseudoterminal path), or None if it ended first or the
    demo was stopped. Every other line it printed meanwhile is kept in ``seen``."""
    selector = selectors.DefaultSelector()
    selector.register(proc.stdout, selectors.EVENT_READ)
    deadline = time.monotonic() + timeout_s
    try:
        while time.monotonic() < deadline and not stop.is_set():
            if not selector.select(timeout=0.2):
                if proc.poll() is not None:
                    return None
                continue
            line = proc.stdout.readline()
            if not line:
                return None
            if line.startswith("xrce-agent:") and ("on port" in line or "pseudoterminal at" in line):
                return line.strip()
            seen.append(_ANSI.sub("", line).strip())
    finally:
        selector.close()
    return None


def _agent_failure(proc, seen):
    """What the agent said before it ended: its own error lines, or the last lines it printed."""
    try:
        rest, _ = proc.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        rest = ""
    lines = [l for l in seen + [_ANSI.sub("", l).strip() for l in (rest or "").splitlines()] if l]
    errors = [l for l in lines if l.startswith("xrce-agent: error:")]
    shown = errors or lines[-3:]
    return shown, proc.returncode


def _forward_output(proc, prefix):
    """Relay a child's output lines to ours (a thread per child: the pipes must never fill, even
    after our terminal went away, or the child would block in a write and never stop)."""
    def pump():
        for line in proc.stdout:
            _say(prefix + line.rstrip("\n"))
    thread = threading.Thread(target=pump, daemon=True)
    thread.start()
    return thread


def stop_child(proc, timeout_s=10.0, signum=signal.SIGINT):
    """SIGINT ``proc`` as Ctrl-C would (an agent then destroys its ROS entities), wait, and kill it
    if it hangs. The benches stop their child processes with it too."""
    if proc is None or proc.poll() is not None:
        return
    proc.send_signal(signum)
    try:
        proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def _ensure_interfaces(stop):
    """Build turtlebot3_msgs and tf2_msgs (a cache hit after the first run) unless the ROS in use
    has them already (apt's ros-jazzy-tf2-msgs, ...); False if not possible. The first build takes
    45-60 s on two cores (measured: 44-51 s idle, 62 s at a load of 7): a line says so after the
    first second (a cache hit is done by then), and another every few seconds until it is done."""
    import importlib.machinery

    missing = [name for name in ("tf2_msgs", "turtlebot3_msgs")
               if importlib.machinery.PathFinder.find_spec(name) is None]
    done = threading.Event()
    started = time.monotonic()
    if missing:
        def progress():
            if done.wait(1.0):  # a cache hit: nothing to say
                return
            _say("%s: building %s for rclpy (first run only, 45-60 s on two cores; then cached)"
                 % (PROG, " and ".join(missing)))
            while not done.wait(BUILD_PROGRESS_PERIOD_S):
                _say("%s: still building (%.0f s)..." % (PROG, time.monotonic() - started))
        threading.Thread(target=progress, daemon=True).start()
    try:
        if missing:
            from xrce.agent import interfaces

            def report(result):
                if not result.cached:
                    _say("%s: built %s in %.1f s" % (PROG, result.name, result.seconds))
            interfaces.build(names=missing, report=report)
        from turtlebot3_msgs.msg import SensorState  # noqa: F401
        return True
    except Exception as exc:  # the demo still shows /odom without them
        if stop.is_set():  # Ctrl-C reached the build's cmake too: not worth a report
            return False
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        _say("%s: turtlebot3_msgs unavailable (%s); /sensor_state will not be shown" % (PROG, reason))
        return False
    finally:
        done.set()


def _yaw(q):
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _fitted(amount, nominal_speed, period_s):
    """(speed, commands) covering ``amount`` in a whole number of command periods, so that a leg
    ends exactly on the command grid and the square closes (0.5 m at 0.15 m/s is 3.33 s: on a 0.1 s
    grid the legs ran 3.4 s, and each corner turned ~2.8 degrees too far)."""
    commands = max(1, round(amount / nominal_speed / period_s))
    return amount / (commands * period_s), commands


class _Square:
    """Forward SIDE_M, turn 90 degrees, four times, again and again: open loop on /cmd_vel, one
    command per COMMAND_PERIOD_S, each leg a whole number of commands."""

    def __init__(self, period_s=COMMAND_PERIOD_S):
        linear, forward = _fitted(SIDE_M, LINEAR_SPEED, period_s)
        angular, turn = _fitted(math.pi / 2, ANGULAR_SPEED, period_s)
        self.legs = ((linear, 0.0, forward), (0.0, angular, turn))
        self.sent = 0  # commands so far

    def next_command(self):
        """(linear m/s, angular rad/s) of the next command period."""
        forward, turn = self.legs[0][2], self.legs[1][2]
        position = self.sent % (forward + turn)
        self.sent += 1
        leg = self.legs[0] if position < forward else self.legs[1]
        return leg[0], leg[1]


def run(args):
    from xrce.agent.interfaces import ros_install as rosenv

    try:
        domain, localhost_only, holder, env = choose_network(args)
    except UsageError as exc:
        sys.stderr.write("%s: error: %s\n" % (PROG, exc))
        return 2
    try:
        line, warning = rosenv.describe()
    except rosenv.RosUnavailable as exc:
        sys.stderr.write("%s: error: %s\n" % (PROG, exc))
        return 1
    _say("%s: %s" % (PROG, line))
    if warning:
        _say("%s: warning: %s" % (PROG, warning))
    if not localhost_only:
        _say("%s: warning: publishing /cmd_vel in ROS domain %d to the whole network: a robot "
             "in that domain will move (leave out --domain/--lan to stay on this machine)"
             % (PROG, domain))
    # This process's own node joins the same domain with the same discovery range.
    os.environ.update({k: v for k, v in env.items() if k.startswith("ROS_")})
    for name in ("ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY"):
        if name not in env:
            os.environ.pop(name, None)
    stop = threading.Event()
    stopped_by = []

    def on_signal(signum, frame):
        stopped_by.append(signum)
        stop.set()
    previous = {s: signal.signal(s, on_signal) for s in EXIT_CODES}
    agent = robot = None
    try:
        have_sensor_state = _ensure_interfaces(stop)
        if stop.is_set():
            return EXIT_CODES[stopped_by[0]]
        link = ["pseudoterminal"] if args.serial else ["udp4", "-p", "0"]
        agent = subprocess.Popen([sys.executable, "-m", "xrce.agent", *link, "-m", "dds", "-v", "3"],
                                 stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                 start_new_session=True, env=env)
        seen = []
        banner = _wait_banner(agent, START_TIMEOUT_S, stop, seen)
        if stop.is_set():
            return EXIT_CODES[stopped_by[0]]
        if banner is None:
            stop_child(agent)
            shown, code = _agent_failure(agent, seen)
            _say("%s: the agent did not start (exit %s)%s" % (PROG, code, ":" if shown else ""))
            for text in shown:
                _say("[agent] " + text)
            return 1
        _say(banner)
        _forward_output(agent, "[agent] ")
        if args.serial:
            device = re.search(r"pseudoterminal at (\S+)", banner).group(1)
            robot_link = ["serial", "--dev", device, "-b", "115200"]
        else:
            robot_link = ["udp4", "--agent", "127.0.0.1", "-p", re.search(r"on port (\d+)", banner).group(1)]
        robot = subprocess.Popen([sys.executable, "-m", "xrce.examples.turtlebot3", *robot_link,
                                  "--domain", str(domain), "--ros-extras"],
                                 stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                 start_new_session=True, env=env)
        _forward_output(robot, "[robot] ")
        # ros2 where a ROS install put it on PATH, else this venv's xrce-ros (ros2cli has no
        # PyPI wheels: after the README's install there is no ros2 to type).
        ros2 = ros2_command()
        if localhost_only:
            _say("%s: watch it from another shell on this machine: ROS_DOMAIN_ID=%d "
                 "ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST %s topic echo /odom"
                 % (PROG, domain, ros2))
        else:
            _say("%s: watch it from another shell: ROS_DOMAIN_ID=%d %s topic echo /odom"
                 % (PROG, domain, ros2))
        _ros_side(domain, have_sensor_state, stop, args.duration)
        return EXIT_CODES[stopped_by[0]] if stopped_by else 0
    finally:
        # SIGTERM for the robot: one still starting (importing, before its handler is set) ends
        # quietly by default, where SIGINT would print a KeyboardInterrupt traceback; one that
        # runs logs out after its current step, as on Ctrl-C.
        stop_child(robot, signum=signal.SIGTERM)
        stop_child(agent)
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        if holder is not None:
            holder.close()
        _say("%s: stopped" % PROG)


def _ros_side(domain, have_sensor_state, stop, duration_s):
    import rclpy
    from action_msgs.msg import GoalStatus, GoalStatusArray
    from geometry_msgs.msg import Twist
    from nav_msgs.msg import Odometry
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_action_status_default
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
    # The patrol's goals as every action client sees them: the latest status array (transient
    # local, so a goal already running when the demo starts is seen too).
    running = {GoalStatus.STATUS_ACCEPTED, GoalStatus.STATUS_EXECUTING, GoalStatus.STATUS_CANCELING}
    patrol = {"running": False}

    def on_patrol_status(msg):
        now_running = any(status.status in running for status in msg.status_list)
        if now_running != patrol["running"]:
            patrol["running"] = now_running
            _say("%s: %s" % (PROG, "a /patrol goal is running: /cmd_vel yields to it until it ends"
                             if now_running else "the /patrol goal ended: driving the square again"))

    node.create_subscription(GoalStatusArray, "/patrol/_action/status", on_patrol_status,
                             qos_profile_action_status_default)
    square = _Square()
    started = time.monotonic()
    next_command = next_print = started
    _say("%s: ROS domain %d; driving a %.1f m square on /cmd_vel (Ctrl-C to stop)" % (PROG, domain, SIDE_M))
    try:
        while not stop.is_set():
            now = time.monotonic()
            if duration_s and now - started >= duration_s:
                break
            if now >= next_command and square.sent == 0 and not cmd_vel.get_subscription_count():
                next_command += COMMAND_PERIOD_S  # the robot would miss the first leg's start
            elif now >= next_command and patrol["running"]:
                next_command += COMMAND_PERIOD_S  # a command would abort the patrol
            elif now >= next_command:
                next_command += COMMAND_PERIOD_S
                twist = Twist()
                twist.linear.x, twist.angular.z = square.next_command()
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
