"""How long ROS goes dark when the agent crashes, or the board resets, and comes back.

    .venv/bin/python bench/restart/restart_gap.py [--runs 5] [--downtime 1.0]

What a user does (issue 12): an rclpy subscriber on ``/chatter`` stays up the whole time;
``xrce-client pub udp4 ... --rate 20`` publishes; ``xrce-agent udp4 -p PORT -m dds`` is killed with
SIGKILL and started again ``--downtime`` seconds later. The figure is the longest gap between two
samples in the subscriber. Beside it, measured in the same run, is the cold start: the agent
launched with the subscriber already waiting and the publisher started as soon as the agent prints
its banner, time from launch to the first sample. Then a board reset: the publisher is killed and
started again at once with the same client key while the agent stays up.

Each run also collects the agent's recovery timeline line (``xrce.agent.engine.timeline``) so the phases of
the median run can be read next to the figures. ``bench/run.py --only restart`` calls ``measure``.

``--board-once [its options]``: instead, a board that never re-creates its session (eProsima's
client, tests/recovery/programs/board_once.c) across a SIGINT and a SIGKILL restart of the agent,
over UDP and serial: bench/restart/board_restart.py, whose docstring says what it measures.
"""

import os
import random
import re
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from bench.common.procs import interrupt  # noqa: E402

PYTHON = sys.executable
TOPIC = "/chatter"
RATE_HZ = 20.0
KEY = "B0A7C0DE"


def subscriber_main():
    """Child: a plain rclpy best-effort subscriber printing each arrival's CLOCK_MONOTONIC time."""
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data
    from std_msgs.msg import String

    rclpy.init(args=[])
    node = Node("restart_gap_listener", start_parameter_services=False, enable_rosout=False)
    out = sys.stdout
    node.create_subscription(String, TOPIC, lambda _m: out.write("%.6f\n" % time.monotonic())
                             or out.flush(), qos_profile_sensor_data)
    out.write("ready\n")
    out.flush()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass


class Arrivals:
    """The subscriber process and the arrival times it reports."""

    def __init__(self, env):
        self.proc = subprocess.Popen([PYTHON, __file__, "--subscriber"], cwd=REPO, env=env,
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        self.times = []
        self.ready = threading.Event()
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()
        if not self.ready.wait(60):
            self.close()
            raise RuntimeError("the rclpy subscriber did not start")

    def _read(self):
        for line in self.proc.stdout:
            if line.startswith("ready"):
                self.ready.set()
            else:
                try:
                    self.times.append(float(line))
                except ValueError:
                    pass

    def count(self):
        return len(self.times)

    def wait_count(self, count, timeout_s):
        deadline = time.monotonic() + timeout_s
        while len(self.times) < count:
            if time.monotonic() > deadline:
                return False
            time.sleep(0.01)
        return True

    def first_after(self, moment):
        return next((t for t in list(self.times) if t >= moment), None)

    def longest_gap(self, since):
        """Longest interval between consecutive arrivals, from the last arrival before ``since``."""
        times = list(self.times)
        start = max((i for i, t in enumerate(times) if t < since), default=0)
        gaps = [b - a for a, b in zip(times[start:], times[start + 1:])]
        return max(gaps) if gaps else None

    def close(self):
        interrupt(self.proc, 10)


class Agent:
    """``xrce-agent udp4 -p PORT -m dds`` with its log collected (stdout and stderr)."""

    def __init__(self, port, env, verbosity="4"):
        self.launched = time.monotonic()
        self.proc = subprocess.Popen([PYTHON, "-m", "xrce.agent", "udp4", "-p", str(port), "-m",
                                      "dds", "-v", verbosity], cwd=REPO, env=env,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.lines = []
        self.banner = threading.Event()
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self):
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))
            if "agent on port" in line:
                self.banner.set()

    def timelines(self):
        return [line for line in self.lines if "recovery timeline" in line]

    def kill(self):
        self.proc.kill()
        self.proc.wait()

    def stop(self):
        interrupt(self.proc, 20)
        self.thread.join(5)


def publisher(port, env):
    return subprocess.Popen([PYTHON, "-m", "xrce.client", "pub", "udp4", "-p", str(port),
                             "--topic", TOPIC, "--type", "std_msgs/msg/String",
                             "--data", "hello", "--rate", str(RATE_HZ), "--count", "0",
                             "--key", KEY, "--domain", env.get("ROS_DOMAIN_ID", "0")],
                            cwd=REPO, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def free_udp_port():
    import socket
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# Fast DDS participants announce themselves every 3 s. A restarted agent whose participant misses
# the subscriber's one-time reply (bench/restart/dds_rediscovery.py) waits for the next of these, so the gap
# depends on where in that 3 s period the crash falls. A fixed time between the cold start and the
# kill would put every crash at the same phase (it made every such run exactly the worst case); a
# crash comes at any moment, so the kill falls at a random phase of one whole period.
ANNOUNCEMENT_PERIOD_S = 3.0


def one_run(arrivals, env, downtime, settle_s=2.0, timeout_s=30.0):
    """Cold start, agent SIGKILL + restart, board reset; returns seconds for each and timelines."""
    port = free_udp_port()
    result = {"cold": None, "agent_gap": None, "reset_gap": None, "timelines": []}
    agent = Agent(port, env)
    client = None
    try:
        if not agent.banner.wait(60):
            raise RuntimeError("agent did not start: %s" % "\n".join(agent.lines))
        client = publisher(port, env)
        first = arrivals.first_after(agent.launched)
        deadline = time.monotonic() + timeout_s
        while first is None and time.monotonic() < deadline:
            time.sleep(0.01)
            first = arrivals.first_after(agent.launched)
        if first is None:
            raise RuntimeError("no sample reached ROS after a cold start")
        result["cold"] = first - agent.launched
        time.sleep(settle_s + random.uniform(0.0, ANNOUNCEMENT_PERIOD_S))

        killed = time.monotonic()
        agent.kill()  # a crash: no DELETE, no goodbye
        time.sleep(downtime)
        agent = Agent(port, env)
        before = arrivals.count()
        if not arrivals.wait_count(before + int(settle_s * RATE_HZ), timeout_s):
            raise RuntimeError("data did not come back after the agent restart")
        result["agent_gap"] = arrivals.longest_gap(killed)

        reset = time.monotonic()
        client.kill()  # the board resets: its session is abandoned, not deleted
        client.wait()
        client = publisher(port, env)  # and boots again with the same key
        before = arrivals.count()
        if not arrivals.wait_count(before + int(settle_s * RATE_HZ), timeout_s):
            raise RuntimeError("data did not come back after the board reset")
        result["reset_gap"] = arrivals.longest_gap(reset)
    finally:
        interrupt(client)
        agent.stop()
    result["timelines"] = agent.timelines()
    return result


def measure(env, runs=5, downtime=1.0, log=print):
    """``runs`` rounds; returns {"cold": [...], "agent_gap": [...], "reset_gap": [...], ...}."""
    arrivals = Arrivals(env)
    figures = {"cold": [], "agent_gap": [], "reset_gap": [], "timelines": []}
    try:
        for index in range(runs):
            result = one_run(arrivals, env, downtime)
            for name in ("cold", "agent_gap", "reset_gap"):
                figures[name].append(result[name])
            figures["timelines"].append(result["timelines"])
            log("run %d: cold start %.2f s, agent restart gap %.2f s, board reset gap %.2f s"
                % (index + 1, result["cold"], result["agent_gap"], result["reset_gap"]))
            for line in result["timelines"]:
                log("    " + re.sub(r"^.*?(recovery timeline)", r"\1", line))
    finally:
        arrivals.close()
    return figures


def summary(values):
    return statistics.median(values), max(values)


def report(record, env, runs=5, downtime=1.0):
    """For bench/run.py: ``record(name, value, unit, baseline, baseline_name, target, note)``."""
    figures = measure(env, runs, downtime, log=lambda line: print(line, flush=True))
    cold = statistics.median(figures["cold"])
    for name, target in (("agent_gap", "<= 2.5 median, <= 3.5 max"), ("reset_gap", "")):
        median, worst = summary(figures[name])
        label = ("agent SIGKILL + restart %.0f s later: longest gap" % downtime if name == "agent_gap"
                 else "board reset (same key): longest gap")
        values = ", ".join("%.2f" % v for v in figures[name])
        record(label + " (median of %d)" % runs, median, "s", cold,
               "cold start to first sample (median)", target, "runs: %s" % values)
        record(label + " (max of %d)" % runs, worst, "s", max(figures["cold"]),
               "cold start to first sample (max)", target)


def main(argv=None):
    import argparse

    from ros_helpers import DomainLease

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--downtime", type=float, default=1.0, help="seconds the agent stays dead")
    args = parser.parse_args(argv)
    lease = DomainLease()
    env = dict(os.environ, ROS_DOMAIN_ID=str(lease.domain_id),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    try:
        figures = measure(env, args.runs, args.downtime)
    finally:
        lease.release()
    for name, label in (("cold", "cold start to first sample"),
                        ("agent_gap", "longest gap, agent SIGKILL + restart %.1f s later" % args.downtime),
                        ("reset_gap", "longest gap, board reset (same key)")):
        median, worst = summary(figures[name])
        print("%-52s median %.2f s  max %.2f s  (%s)" % (label, median, worst,
                                                        ", ".join("%.2f" % v for v in figures[name])))
    return 0


if __name__ == "__main__":
    if sys.argv[1:2] == ["--subscriber"]:
        subscriber_main()
    elif sys.argv[1:2] == ["--board-once"]:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        import board_restart
        sys.exit(board_restart.main(sys.argv[2:]))
    else:
        sys.exit(main())
