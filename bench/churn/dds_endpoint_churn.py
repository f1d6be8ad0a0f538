"""What creating and destroying ROS endpoints costs in memory below the agent: rclpy, rmw_fastrtps
and Fast DDS alone, no xrce code on the way (issue 39, the RSS slope of bench/churn/churn.py).

    unshare -nm sh -c 'mount -t tmpfs tmpfs /dev/shm && ip link set lo up && \
        exec .venv/bin/python bench/churn/dds_endpoint_churn.py'

(a private loopback and /dev/shm: the discovering peer is killed, and Fast DDS leaves its
shared-memory files behind)

A board life in bench/churn/churn.py makes, on the agent's ROS side, a node with two publishers and one
subscription and destroys them again a dead time later. This does the same in one process, in a
private ROS domain, 1,000 times after 200 to warm up, with the agent's own node class
(``AgentNode``), and reads glibc's bytes in use (mallinfo2) and the resident set before and after:

- ``nodes``: a node per life, as the agent makes one per board participant;
- ``endpoints``: the three endpoints on one node that stays;
- ``matched``: the same, each matched by an endpoint of that node (a ROS node subscribed to the
  board's topics and publishing its commands): Fast DDS 2.14 keeps its matched status for every
  endpoint that ever matched (EDP's reader_status_/writer_status_ maps, never erased);

each once alone in its domain and once with another process's participant (a plain rclpy node)
discovering it, as the ROS nodes beside a robot's agent always do. Printed: bytes per life.
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout, for xrce

DOMAIN_ID = 91
WARM_UP = 200

PEER = """
import sys, time, rclpy
from rclpy.executors import SingleThreadedExecutor
rclpy.init(domain_id=int(sys.argv[1]))
node = rclpy.create_node("discovering_peer")
executor = SingleThreadedExecutor()
executor.add_node(node)
print("ready", flush=True)
while True:
    executor.spin_once(timeout_sec=0.1)
"""


class _MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in (
        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks",
        "fordblks", "keepcost")]


def _malloc_in_use() -> int:
    mallinfo2 = ctypes.CDLL(None).mallinfo2
    mallinfo2.restype = _MallInfo2
    return mallinfo2().uordblks


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def measure(mode: str, lives: int) -> tuple:
    """(bytes in use per life, RSS before, RSS after) of ``lives`` lives in this process."""
    import rclpy
    from geometry_msgs.msg import Twist
    from nav_msgs.msg import Odometry
    from rclpy.context import Context

    from xrce.agent.middleware.ros.agent_node import AgentNode
    from xrce.agent.middleware.ros.domain import NO_TYPE_DESCRIPTION

    context = Context()
    rclpy.init(args=[], context=context, domain_id=DOMAIN_ID)

    def make_node(name):
        return AgentNode(name, context=context, start_parameter_services=False,
                         enable_rosout=False, parameter_overrides=[NO_TYPE_DESCRIPTION])

    staying = make_node("staying_node")
    counterparts = []  # held until the node goes: what each life's endpoints match
    if mode == "matched":
        counterparts = [staying.create_subscription(Odometry, "/odom", lambda _m: None, 10),
                        staying.create_subscription(Odometry, "/imu", lambda _m: None, 10),
                        staying.create_publisher(Twist, "/cmd_vel", 10)]

    def life():
        node = make_node("churn_board") if mode == "nodes" else staying
        made = [node.create_publisher(Odometry, "/odom", 10),
                node.create_publisher(Odometry, "/imu", 10),
                node.create_subscription(Twist, "/cmd_vel", lambda _m: None, 10)]
        node.destroy_publisher(made[0])
        node.destroy_publisher(made[1])
        node.destroy_subscription(made[2])
        if node is not staying:
            node.destroy_node()

    try:
        for _ in range(WARM_UP):
            life()
        gc.collect()
        before, rss_before = _malloc_in_use(), _rss_mb()
        for _ in range(lives):
            life()
        gc.collect()
        return (_malloc_in_use() - before) / lives, rss_before, _rss_mb()
    finally:
        staying.destroy_node()
        rclpy.shutdown(context=context)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--lives", type=int, default=1000)
    parser.add_argument("--mode", choices=("nodes", "endpoints", "matched"), default=None,
                        help="one case in this process (the script runs each in a process of its own)")
    parser.add_argument("--peer", action="store_true", help="with a discovering participant")
    args = parser.parse_args(argv)
    if args.lives < 1:
        parser.error("--lives must be positive")
    if args.mode:
        peer = None
        if args.peer:
            peer = subprocess.Popen([sys.executable, "-c", PEER, str(DOMAIN_ID)],
                                    stdout=subprocess.PIPE, text=True)
            peer.stdout.readline()
            time.sleep(2)  # discovered
        try:
            per_life, rss_before, rss_after = measure(args.mode, args.lives)
        finally:
            if peer is not None:
                peer.kill()
                peer.wait()
        print("%-9s %-22s %7.0f B in use per life, RSS %.1f -> %.1f MB over %d lives" % (
            args.mode, "with a discovering peer" if args.peer else "alone in its domain",
            per_life, rss_before, rss_after, args.lives), flush=True)
        return 0
    for mode in ("nodes", "endpoints", "matched"):
        for peer in (False, True):
            subprocess.run([sys.executable, __file__, "--mode", mode, "--lives", str(args.lives)]
                           + (["--peer"] if peer else []), check=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
