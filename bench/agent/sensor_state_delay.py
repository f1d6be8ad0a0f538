"""Stamp-to-receive delay of /sensor_state from the simulated TurtleBot3, as micro-ROS reports it.

    .venv/bin/python bench/agent/sensor_state_delay.py [--quick] [--seconds S] [--links udp,pty]

For each link (UDP; the agent's pseudoterminal at 115200 baud) it starts ``xrce-agent -m dds`` and
the robot firmware (``python -m xrce.examples.turtlebot3``) as separate processes, subscribes to
/sensor_state with rclpy here, and measures receive wall clock (in the callback) minus the header
stamp the robot took from its agent-synced clock: first idle, then while this process publishes
/cmd_vel at 30 Hz. The robot, the agent and this process share one machine clock, so the delay is
the real end-to-end latency plus the time-sync error (half a loopback round trip).

Reference: micro-ROS' published TurtleBot3 figures over WiFi (mean 16 ms, std 1.7 ms idle; 28 ms,
std 15.6 ms with /cmd_vel load) — a radio link and an MCU, so only the shape compares.
"""

import argparse
import os
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from bench.common.procs import interrupt  # noqa: E402

REFERENCE = {"idle": (16.0, 1.7), "30 Hz /cmd_vel": (28.0, 15.6)}  # micro-ROS over WiFi, ms


def ensure_interfaces():
    from xrce.agent import interfaces
    interfaces.build(names=["tf2_msgs", "turtlebot3_msgs"])


class Delays:
    def __init__(self):
        self.recording = None

    def __call__(self, msg):
        received = time.time_ns()
        if self.recording is not None:
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            self.recording.append((received - stamp) / 1e6)


def publish_cmd_vel(publisher, stop, hz=30.0):
    from geometry_msgs.msg import Twist
    twist = Twist()
    twist.linear.x = 0.1
    twist.angular.z = 0.2
    next_at = time.monotonic()
    while not stop.is_set():
        publisher.publish(twist)
        next_at += 1.0 / hz
        stop.wait(max(0.0, next_at - time.monotonic()))


def measure_link(link, seconds, peer, domain):
    from agent_process import AgentProcess
    from geometry_msgs.msg import Twist
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from ros_helpers import wait_until
    from turtlebot3_msgs.msg import SensorState

    agent_args = ("udp4", "-m", "dds", "-v", "2") if link == "udp" else ("pseudoterminal", "-m", "dds", "-v", "2")
    results = {}
    with AgentProcess(*agent_args) as agent:
        robot_link = (["udp4", "-p", str(agent.port)] if link == "udp"
                      else ["serial", "--dev", agent.device, "-b", "115200"])
        robot = subprocess.Popen([sys.executable, "-m", "xrce.examples.turtlebot3", *robot_link,
                                  "--domain", str(domain), "--connect-attempts", "30"],
                                 cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        delays = Delays()
        best_effort = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT)
        subscription = peer.node.create_subscription(SensorState, "/sensor_state", delays, best_effort)
        cmd_vel = peer.node.create_publisher(Twist, "/cmd_vel", 10)
        try:
            delays.recording = []
            if not wait_until(lambda: len(delays.recording) >= 5, 30):
                raise RuntimeError("no /sensor_state from the robot over %s" % link)
            time.sleep(0.5)
            for phase in ("idle", "30 Hz /cmd_vel"):
                stop = threading.Event()
                loader = None
                if phase != "idle":
                    loader = threading.Thread(target=publish_cmd_vel, args=(cmd_vel, stop), daemon=True)
                    loader.start()
                    time.sleep(0.5)  # the robot is moving before we measure
                delays.recording = []
                time.sleep(seconds)
                results[phase] = delays.recording
                delays.recording = None
                stop.set()
                if loader is not None:
                    loader.join(2)
        finally:
            interrupt(robot, 10)
            peer.node.destroy_subscription(subscription)
            peer.node.destroy_publisher(cmd_vel)
    return results


def describe(samples):
    if len(samples) < 2:
        return "n=%d (too few)" % len(samples)
    return "n=%4d mean %7.3f  min %7.3f  max %7.3f  std %7.3f ms" % (
        len(samples), statistics.fmean(samples), min(samples), max(samples), statistics.stdev(samples))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="3 s per phase instead of 10")
    parser.add_argument("--seconds", type=float, default=None, help="seconds per phase")
    parser.add_argument("--links", default="udp,pty", help="comma-separated: udp, pty")
    args = parser.parse_args()
    seconds = args.seconds or (3.0 if args.quick else 10.0)

    from ros_helpers import DomainLease, RosPeer

    ensure_interfaces()
    lease = DomainLease()
    os.environ["ROS_DOMAIN_ID"] = str(lease.domain_id)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    peer = RosPeer(lease.domain_id, "sensor_state_delay")
    try:
        print("/sensor_state stamp-to-receive delay, %.0f s per phase (ROS domain %d)"
              % (seconds, lease.domain_id))
        for phase, (mean, std) in REFERENCE.items():
            print("  %-9s %-16s mean %7.3f                            std %7.3f ms  (published)"
                  % ("micro-ROS", phase, mean, std))
        for link in args.links.split(","):
            results = measure_link(link.strip(), seconds, peer, lease.domain_id)
            for phase, samples in results.items():
                print("  %-9s %-16s %s" % (link if link != "pty" else "pty115200", phase, describe(samples)))
            idle, loaded = results.get("idle"), results.get("30 Hz /cmd_vel")
            if idle and loaded:
                print("  %-9s load raises the mean by %+.1f %%"
                      % ("", 100.0 * (statistics.fmean(loaded) / statistics.fmean(idle) - 1.0)))
            sys.stdout.flush()
    finally:
        peer.close()
        lease.release()


if __name__ == "__main__":
    main()
