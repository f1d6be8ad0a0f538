"""PX4 SITL end to end through an XRCE agent, with an rclpy node doing what px4_ros_com's examples
do; prints the rows of issue #37's table for each run and a summary over the runs.

    unshare -nm sh -c 'mount -t tmpfs tmpfs /dev/shm && mount -t tmpfs tmpfs /tmp && \\
        ip link set lo up && exec .venv/bin/python bench/px4/sitl.py \\
        --px4-build $PX4W/PX4-Autopilot/build/px4_sitl_default --px4-msgs DIR [--runs 3]'

``--px4-build`` (or $PX4_BUILD) is PX4's ``build/px4_sitl_default`` (``make px4_sitl_default`` in a
PX4-Autopilot checkout of a release tag); ``--px4-msgs`` (or $PX4_MSGS) a folder holding the
``px4_msgs`` source package (github PX4/px4_msgs) of the same
PX4 release, built here for this script's node only (xrce.agent.interfaces, registered in this
process alone): the agent never sees it, and the script checks that its interpreter cannot import
it. The agent is ``python -m xrce.agent udp4 -p 8888`` of this checkout, or ``--agent-cmd CMD``
(e.g. eProsima's MicroXRCEAgent, run as ``CMD udp4 -p 8888``) for the other column. PX4 keeps lock
and socket files in /tmp per instance, hence the private /tmp above.

One run, in order: the agent; PX4 instance 0 (``PX4_SIM_MODEL=sihsim_quadx px4 -d etc`` in a fresh
folder) until its log says ``time sync converged``; the ROS graph (PX4's writers, readers and
replier as ROS publishers, subscribers and service); 10 s of best-effort subscriptions to every
``/fmu/out`` topic (Hz by wall clock, and the share of the samples PX4 wrote, from sample
timestamps on PX4's clock, as lockstep SITL on a loaded machine runs slower than real time);
offboard control (OffboardControlMode + TrajectorySetpoint at 10 Hz, DO_SET_MODE(1, 6), ARM;
armed, offboard, and the climb read from vehicle_local_position); a ``/fmu/vehicle_command`` call
(NAV_LAND); ``uxrce_dds_client status`` in PX4's shell; PX4 instance 1 (namespace px4_1) and a call
of each vehicle's service with its own target system; PX4 0 killed and started again; the agent
stopped and started again. Each recovery is timed until samples flow again and the service
answers. Agent CPU: user+system seconds over the 10 s of subscriptions, in % of one core.
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from bench.common.peer_agent import answers_ping  # noqa: E402
AGENT_PORT = 8888  # PX4's default (rcS: uxrce_dds_client start -t udp -p 8888)
DO_SET_MODE, ARM_DISARM, NAV_LAND = 176, 400, 21
ARMED, OFFBOARD = 2, 14
FAST_TOPIC_HZ = 50  # a topic streaming faster than this is one of PX4's 100 Hz ones
# PX4's log once its time sync has converged and the session is synchronized, or (1.16 only, 1.17
# logs it at debug level) once its filter has converged; after an agent restart only the first
# comes again (the filter stays converged)
SYNCED = "synchronized with time offset|time sync converged"


def log(text):
    print("[%s] %s" % (time.strftime("%H:%M:%S"), text), file=sys.stderr, flush=True)


def cpu_seconds(pid):
    with open("/proc/%d/stat" % pid) as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def wait_for(predicate, timeout_s, interval_s=0.05):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(interval_s)
    return True


# ------------------------------------------------------------------------------------ processes

class Agent:
    """The agent under test on UDP 8888: ours (SIGINT stops it) or ``--agent-cmd`` (SIGTERM)."""

    def __init__(self, command, log_path):
        self.command = command
        self.log_path = log_path
        self.proc = None

    def start(self):
        argv = (shlex.split(self.command) if self.command else
                [sys.executable, "-m", "xrce.agent"]) + ["udp4", "-p", str(AGENT_PORT)]
        self._log = open(self.log_path, "a")
        self.proc = subprocess.Popen(argv, cwd=REPO, stdout=self._log, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL)
        if not wait_for(lambda: answers_ping(AGENT_PORT) or self.proc.poll() is not None, 60):
            raise RuntimeError("the agent did not answer on port %d" % AGENT_PORT)
        if self.proc.poll() is not None:
            raise RuntimeError("the agent exited: see %s" % self.log_path)

    def stop(self):
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM if self.command else signal.SIGINT)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc is not None:
            self._log.close()
        self.proc = None


class Px4:
    """One PX4 SITL instance, headless (``-d``), in its own folder, its log kept in memory."""

    def __init__(self, build: Path, instance: int, folder: Path):
        self.build, self.instance, self.folder = build, instance, folder
        self.lines = []  # (monotonic time, line)
        self.proc = None
        self.started = None

    def start(self):
        self.folder.mkdir(parents=True, exist_ok=True)
        env = dict(os.environ, PX4_SIM_MODEL="sihsim_quadx")
        self.lines = []
        self.saved = False
        self.started = time.monotonic()
        self.proc = subprocess.Popen([str(self.build / "bin" / "px4"), "-d", "-i", str(self.instance),
                                      str(self.build / "etc")], cwd=self.folder, env=env,
                                     stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, start_new_session=True)
        threading.Thread(target=self._read, args=(self.proc,), daemon=True).start()

    def _read(self, proc):
        for raw in proc.stdout:
            self.lines.append((time.monotonic(), raw.decode(errors="replace").rstrip()))

    def said(self, pattern, since=0.0):
        """Monotonic time of the first log line matching ``pattern`` after ``since``, or None."""
        for when, line in list(self.lines):
            if when >= since and re.search(pattern, line):
                return when
        return None

    def shell(self, command, timeout_s=20):
        """A command of PX4's shell, through PX4's own client (``px4-<command> --instance N``)."""
        name, *args = command.split()
        result = subprocess.run([str(self.build / "bin" / ("px4-" + name)), "--instance",
                                 str(self.instance), *args], cwd=self.folder, capture_output=True,
                                text=True, timeout=timeout_s)
        return result.stdout + result.stderr

    def save_log(self):
        """Append what PX4 said to ``px4.log`` in its folder (each boot after the previous)."""
        if self.saved:
            return
        self.saved = True
        with open(self.folder / "px4.log", "a") as f:
            f.writelines("%.3f %s\n" % (when, line) for when, line in self.lines)

    def kill(self):
        if self.proc is not None:
            self.save_log()
        if self.proc is not None and self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()

    def stop(self):
        if self.proc is not None:
            self.save_log()
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.kill()
        # PX4's per-instance lock and shell socket files
        for path in ("/tmp/px4_lock-%d" % self.instance, "/tmp/px4-sock-%d" % self.instance):
            try:
                os.unlink(path)
            except FileNotFoundError:
                pass


# ------------------------------------------------------------------------------------- ROS side

def px4_msgs_for_this_process(source_dir, site_dir):
    """Build px4_msgs (a cache hit after the first time) and make it importable here only."""
    from xrce.agent import interfaces
    from xrce.agent.interfaces.registry import register

    results = interfaces.build([source_dir], names=["px4_msgs"], register_results=False)
    register(results, site_dir=site_dir)
    import px4_msgs.msg  # noqa: F401
    import px4_msgs.srv  # noqa: F401


def agent_can_import_px4_msgs(agent_command):
    python = sys.executable if not agent_command else None
    if python is None:
        return False  # another program: not a Python of ours
    probe = subprocess.run([python, "-c", "import px4_msgs"], cwd=REPO, capture_output=True)
    return probe.returncode == 0


class Node:
    """The rclpy node: px4_ros_com's listener, offboard example and service call."""

    def __init__(self):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        rclpy.init()
        self.rclpy = rclpy
        self.node = rclpy.create_node("px4_sitl_bench")
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.arrivals = {}  # topic -> [(monotonic, PX4 timestamp in us)]
        self.latest = {}  # topic -> latest decoded message
        self.timesync = []  # /fmu/out/timesync_status messages
        self._subscriptions = {}
        self._stop = False
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        while not self._stop:
            self.executor.spin_once(timeout_sec=0.05)

    def close(self):
        self._stop = True
        self._thread.join(5)
        self.node.destroy_node()
        self.rclpy.shutdown()

    @staticmethod
    def message_type(type_name):
        import importlib

        package, kind, name = type_name.split("/")
        return getattr(importlib.import_module("%s.%s" % (package, kind)), name)

    def topics(self, prefix):
        return {name: types[0] for name, types in self.node.get_topic_names_and_types()
                if name.startswith(prefix)}

    def subscribe_all(self, prefix):
        """Best-effort subscriptions to every topic under ``prefix`` (as the listener example)."""
        from rclpy.qos import qos_profile_sensor_data

        for topic, type_name in self.topics(prefix).items():
            if topic in self._subscriptions:
                continue
            self.arrivals[topic] = []

            def on_message(message, topic=topic):
                stamp = getattr(message, "timestamp", 0)
                self.arrivals[topic].append((time.monotonic(), stamp))
                self.latest[topic] = message
                if topic == "/fmu/out/timesync_status":
                    self.timesync.append(message)

            self._subscriptions[topic] = self.node.create_subscription(
                self.message_type(type_name), topic, on_message, qos_profile_sensor_data)

    def unsubscribe_all(self):
        """Destroy the subscriptions (the next agent's writers are then matched anew)."""
        for subscription in self._subscriptions.values():
            self.node.destroy_subscription(subscription)
        self._subscriptions.clear()

    def count(self, topic):
        return len(self.arrivals.get(topic, ()))

    def call(self, service, request, timeout_s):
        """The response of one service call, or None after ``timeout_s``."""
        import px4_msgs.srv

        client = self.node.create_client(px4_msgs.srv.VehicleCommand, service)
        try:
            if not client.wait_for_service(timeout_sec=timeout_s):
                return None
            future = client.call_async(request)
            wait_for(future.done, timeout_s)
            return future.result() if future.done() else None
        finally:
            self.node.destroy_client(client)


def vehicle_command(number, param1=0.0, param2=0.0, param3=0.0, target_system=1):
    import px4_msgs.msg

    return px4_msgs.msg.VehicleCommand(command=number, param1=param1, param2=param2, param3=param3,
                                       target_system=target_system, target_component=1,
                                       source_system=1, source_component=1, from_external=True)


class Offboard:
    """px4_ros_com's offboard_control: setpoints at 10 Hz, after 10 of them DO_SET_MODE + ARM."""

    def __init__(self, node):
        import px4_msgs.msg

        self.msg = px4_msgs.msg
        self.node = node.node
        self.mode = self.node.create_publisher(self.msg.OffboardControlMode,
                                               "/fmu/in/offboard_control_mode", 10)
        self.setpoint = self.node.create_publisher(self.msg.TrajectorySetpoint,
                                                   "/fmu/in/trajectory_setpoint", 10)
        self.command = self.node.create_publisher(self.msg.VehicleCommand,
                                                  "/fmu/in/vehicle_command", 10)
        self.armed_at = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        count = 0
        while not self._stop.wait(0.1):
            stamp = int(self.node.get_clock().now().nanoseconds / 1000)
            self.mode.publish(self.msg.OffboardControlMode(timestamp=stamp, position=True))
            self.setpoint.publish(self.msg.TrajectorySetpoint(
                timestamp=stamp, position=[0.0, 0.0, -5.0], yaw=-3.14))
            count += 1
            if count == 10:
                self.command.publish(vehicle_command(DO_SET_MODE, 1.0, 6.0))
                self.command.publish(vehicle_command(ARM_DISARM, 1.0))
                self.armed_at = time.monotonic()

    def stop(self):
        self._stop.set()
        self._thread.join(2)


# ------------------------------------------------------------------------------------- one run

def samples_flow(node, topic, within_s):
    """Whether new samples of ``topic`` arrive within ``within_s``."""
    before = node.count(topic)
    return wait_for(lambda: node.count(topic) >= before + 10, within_s)


def one_run(args, workdir: Path, node: Node, agent: Agent) -> dict:
    rows = {}
    px4 = [Px4(args.px4_build, i, workdir / ("px4_%d" % i)) for i in (0, 1)]
    try:
        agent.start()
        px4[0].start()
        synced = wait_for(lambda: px4[0].said(SYNCED), 90)
        rows["time sync converged"] = ("yes after %.1f s" % (px4[0].said(SYNCED) - px4[0].started)
                                       if synced else "NO within 90 s")
        # PX4's entities, as ROS sees them
        graph = lambda: (  # noqa: E731
            sum(1 for t in node.topics("/fmu/out/") if node.node.count_publishers(t)),
            sum(1 for t in node.topics("/fmu/in/") if node.node.count_subscribers(t)),
            node.node.count_services("/fmu/vehicle_command"))
        wait_for(lambda: graph()[2] >= 1 and graph()[0] >= 20, 60, 0.5)
        time.sleep(2)  # the rest of the graph
        writers, readers, repliers = graph()
        creation_errors = [line for _, line in px4[0].lines if "create entities failed" in line
                           or "init failed" in line]
        rows["PX4 connects"] = "%d writers, %d readers, %d replier%s" % (
            writers, readers, repliers, "; PX4: %s" % creation_errors[0] if creation_errors else "")

        # 10 s of every /fmu/out topic
        node.subscribe_all("/fmu/out/")
        time.sleep(2)  # matched
        start_counts = {t: node.count(t) for t in node.arrivals}
        start_timesync = len(node.timesync)
        cpu0, t0 = cpu_seconds(agent.proc.pid), time.monotonic()
        time.sleep(10)
        cpu1, t1 = cpu_seconds(agent.proc.pid), time.monotonic()
        rates, shares = {}, {}
        for topic, arrivals in node.arrivals.items():
            window = arrivals[start_counts[topic]:]
            rates[topic] = len(window) / (t1 - t0)
            stamps = [stamp for _, stamp in window if stamp]
            if rates[topic] > FAST_TOPIC_HZ and len(stamps) > 2:
                # samples PX4 wrote over that span at its rate, by its own clock
                span_us = stamps[-1] - stamps[0]
                shares[topic] = (len(stamps) - 1) / (span_us / 1e6 * 100.0) if span_us else 0.0
        own = [t for t in rates if t.startswith("/fmu/out/")]
        fast = sorted(t for t in own if rates[t] > FAST_TOPIC_HZ)
        rows["/fmu/out topics"] = "%d subscribed, %d with samples in 10 s" % (
            len(own), sum(1 for t in own if rates[t]))
        rows["100 Hz topics in ROS"] = (
            "%d topics %.1f-%.1f Hz, median %.1f Hz (%.0f-%.0f %% of 100 Hz on PX4's clock)" % (
                len(fast), min(rates[t] for t in fast), max(rates[t] for t in fast),
                statistics.median(rates[t] for t in fast), 100 * min(shares[t] for t in fast),
                100 * max(shares[t] for t in fast)) if fast else "none")
        rtts = [m.round_trip_time / 1000 for m in node.timesync[start_timesync:]
                if m.source_protocol == 2]  # DDS
        rows["TIMESTAMP round trip (PX4's timesync_status, on its 4 ms lockstep clock)"] = (
            "p50 %.2f ms, max %.2f ms over %d" % (statistics.median(rtts), max(rtts), len(rtts))
            if rtts else "no samples")
        rows["agent CPU"] = "%.1f %% of a core" % (100 * (cpu1 - cpu0) / (t1 - t0))

        # offboard: arm, offboard, climb
        # PX4 1.16 and later add the message's version to a topic name from version 1 on
        status_topic, position_topic = (next((t for t in node.arrivals if re.match(
            r"/fmu/out/%s(_v\d+)?$" % name, t)), None) for name in ("vehicle_status",
                                                                    "vehicle_local_position"))
        offboard = Offboard(node)
        try:
            def state():
                status = node.latest.get(status_topic)
                return (status.arming_state, status.nav_state) if status is not None else None

            armed = wait_for(lambda: state() == (ARMED, OFFBOARD), 20)
            position = lambda: node.latest.get(position_topic)  # noqa: E731
            climbed = wait_for(lambda: position() is not None and position().z < -2.0, 25)
            z = position().z if position() is not None else float("nan")
            rows["offboard: arm, offboard, climb"] = "%s, z = %.2f m" % (
                "climbed" if armed and climbed else "FAILED (state %r)" % (state(),), z)
        finally:
            offboard.stop()

        response = node.call("/fmu/vehicle_command",
                             _request(vehicle_command(NAV_LAND, target_system=1)), 15)
        rows["/fmu/vehicle_command (LAND)"] = (
            "answered: command %d result %d" % (response.reply.command, response.reply.result)
            if response is not None else "NOT answered")

        # PX4 resets its time sync on a "time jump" (its lockstep clock against the agent's
        # UTC, after the load of the climb): wait for it to converge again
        asked = time.monotonic()
        status = ""
        while time.monotonic() < asked + 30 and "timesync converged: true" not in status:
            status = px4[0].shell("uxrce_dds_client status")
            time.sleep(0.5)
        warnings = {what: sum(1 for _, line in px4[0].lines if what in line)
                    for what in ("time jump detected", "RTT too high", "no longer converged")}
        rows["uxrce_dds_client status"] = "%s, timesync converged: %s%s; PX4 log: %s" % (
            "connected" if "Running, connected" in status else "NOT connected",
            "true" if "timesync converged: true" in status else "false",
            " (after %.1f s)" % (time.monotonic() - asked) if time.monotonic() - asked > 1 else "",
            ", ".join("%d x %s" % (n, what) for what, n in warnings.items()))

        # a second vehicle
        px4[1].start()
        wait_for(lambda: px4[1].said(SYNCED), 90)
        wait_for(lambda: node.node.count_services("/px4_1/fmu/vehicle_command") >= 1 and
                 node.topics("/px4_1/fmu/out/sensor_combined"), 60)
        node.subscribe_all("/px4_1/fmu/out/")
        answers = []
        for target, service in ((1, "/fmu/vehicle_command"), (2, "/px4_1/fmu/vehicle_command")):
            reply = node.call(service, _request(vehicle_command(DO_SET_MODE, 1.0, 4.0, 3.0,
                                                                target_system=target)), 15)
            answers.append("%s %s (%d server%s)" % (
                service, "result %d" % reply.reply.result if reply else "NOT answered",
                node.node.count_services(service), "" if node.node.count_services(service) == 1
                else "s"))
        others = sorted(name for name, _ in node.node.get_service_names_and_types()
                        if "vehicle_command" in name and name not in
                        ("/fmu/vehicle_command", "/px4_1/fmu/vehicle_command"))
        rows["two vehicles"] = "; ".join(answers) + ("; also %s" % others if others else "")

        # PX4 restart (killed: nothing sent)
        px4[0].kill()
        time.sleep(1)
        restarted = time.monotonic()
        px4[0].start()
        back = samples_flow(node, "/fmu/out/sensor_combined", 90)
        flowing_after = time.monotonic() - restarted
        served = node.call("/fmu/vehicle_command", _request(vehicle_command(
            DO_SET_MODE, 1.0, 4.0, 3.0, target_system=1)), 30)
        synced = px4[0].said(SYNCED, restarted)
        rows["PX4 restart"] = ("samples again after %.1f s (time synced after %s), "
                               "service %s" % (flowing_after, "%.1f s" % (synced - restarted)
                                               if synced else "NEVER",
                                               "answered" if served else "NOT answered")
                               if back else "NO samples in 90 s")

        # agent restart
        agent.stop()
        time.sleep(1)
        restarted = time.monotonic()
        agent.start()
        back = [samples_flow(node, topic, 120) for topic in
                ("/fmu/out/sensor_combined", "/px4_1/fmu/out/sensor_combined")]
        flowing_after = time.monotonic() - restarted
        served = [node.call(service, _request(vehicle_command(DO_SET_MODE, 1.0, 4.0, 3.0,
                                                              target_system=target)), 30)
                  for target, service in ((1, "/fmu/vehicle_command"),
                                          (2, "/px4_1/fmu/vehicle_command"))]
        synced = [instance.said(SYNCED, restarted) for instance in px4]
        rows["agent restart"] = ("both vehicles' samples again after %.1f s (time synced after %s), "
                                 "services %s" % (
                                     flowing_after, " and ".join("%.1f s" % (t - restarted) if t
                                                                 else "NEVER" for t in synced),
                                     "answered" if all(served) else "NOT all answered")
            if all(back) else "samples back: %r" % back)
    finally:
        for instance in px4:
            instance.stop()
        agent.stop()
    return rows


def _request(command):
    import px4_msgs.srv

    return px4_msgs.srv.VehicleCommand.Request(request=command)


def add_px4_arguments(parser) -> None:
    """--px4-build and --px4-msgs (also bench/px4/sitl_cpu.py's)."""
    parser.add_argument("--px4-build", type=Path, default=os.environ.get("PX4_BUILD"),
                        help="PX4's build/px4_sitl_default (default $PX4_BUILD)")
    parser.add_argument("--px4-msgs", default=os.environ.get("PX4_MSGS"),
                        help="folder holding the px4_msgs package of that release (default $PX4_MSGS)")


def check_px4_arguments(parser, args) -> None:
    if not args.px4_build or not (args.px4_build / "bin" / "px4").exists():
        parser.error("--px4-build: no bin/px4 in %s" % args.px4_build)
    if not args.px4_msgs or not os.path.isdir(args.px4_msgs):
        parser.error("--px4-msgs: no folder %s" % args.px4_msgs)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_px4_arguments(parser)
    parser.add_argument("--agent-cmd", default=None,
                        help="another agent's command line (run as CMD udp4 -p 8888)")
    parser.add_argument("--runs", type=int, default=1)
    parser.add_argument("--logs", type=Path, default=None,
                        help="copy each run's agent and PX4 logs into this folder")
    args = parser.parse_args(argv)
    check_px4_arguments(parser, args)

    workdir = Path(tempfile.mkdtemp(prefix="px4-sitl-bench-"))
    try:
        # Before the node's package is registered in this process: what the agent's interpreter sees.
        agent_sees = agent_can_import_px4_msgs(args.agent_cmd)
        px4_msgs_for_this_process(args.px4_msgs, str(workdir))
        node = Node()
        results = []
        try:
            for run in range(args.runs):
                log("run %d/%d" % (run + 1, args.runs))
                agent = Agent(args.agent_cmd, workdir / ("agent_%d.log" % run))
                rows = one_run(args, workdir / ("run_%d" % run), node, agent)
                if args.logs:
                    kept = args.logs / ("run_%d" % (run + 1))
                    kept.mkdir(parents=True, exist_ok=True)
                    shutil.copy(agent.log_path, kept / "agent.log")
                    for instance in (0, 1):
                        px4_log = workdir / ("run_%d" % run) / ("px4_%d" % instance) / "px4.log"
                        if px4_log.exists():
                            shutil.copy(px4_log, kept / ("px4_%d.log" % instance))
                rows["px4_msgs on the agent's side"] = "yes" if agent_sees else "no"
                results.append(rows)
                print("\n## run %d: %s, agent %s" % (run + 1, args.px4_build,
                                                    args.agent_cmd or "xrce-agent"))
                for what, value in rows.items():
                    print("| %s | %s |" % (what, value))
                sys.stdout.flush()
        finally:
            node.close()
        if len(results) > 1:
            print("\n## over %d runs" % len(results))
            for what in results[0]:
                numbers = []
                for rows in results:
                    found = (re.search(r"median (\d+\.\d+)", rows.get(what, "")) or
                             re.search(r"(\d+\.\d+) (?:Hz|%|ms)", rows.get(what, "")))
                    if found:
                        numbers.append(float(found.group(1)))
                median = " (median %.1f)" % statistics.median(numbers) if numbers else ""
                print("| %s | %s%s |" % (what, " / ".join(rows.get(what, "-") for rows in results),
                                          median))
    finally:
        if os.environ.get("PX4_BENCH_KEEP"):
            print("kept %s" % workdir)
        else:
            shutil.rmtree(workdir, ignore_errors=True)


if __name__ == "__main__":
    main()
