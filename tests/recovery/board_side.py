"""The two sides of tests/recovery/programs/board_once.c, shared by the live restart test, the
recording of its traffic (record_board_restart.py) and bench/restart/board_restart.py: the C
program with its printed lines time-stamped (``Board``), and what ROS does with it (``RosSide``:
subscribes to its writers, publishes /board_cmd, calls /board_add)."""

import os
import socket
import subprocess
import threading
import time

from agent_process import restore_default_signals
from ros_helpers import wait_until

HERE = os.path.dirname(os.path.abspath(__file__))
PROGRAM = os.path.join(HERE, "programs", "board_once.c")
INTERFACES = os.path.join(os.path.dirname(HERE), "interfaces")  # example_interfaces
WAIT_S = 30.0  # generous: a loaded 2-core machine; the figures say how long it really took


class Board:
    """The C program, its lines read and time-stamped as they come."""

    def __init__(self, exe, args, pass_fds=()):
        self.lines = []
        self.proc = subprocess.Popen([str(exe), *args], stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, pass_fds=pass_fds,
                                     preexec_fn=restore_default_signals)
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self):
        for line in self.proc.stdout:
            self.lines.append((time.monotonic(), line.strip()))

    def commands(self, since=0.0):
        return [(t, int(l.split()[1])) for t, l in list(self.lines)
                if l.startswith("CMD ") and t >= since]

    def has(self, text):
        return any(l == text for _, l in list(self.lines))

    def stop(self):
        if self.proc.poll() is None:
            self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._thread.join(5)


def free_udp_port():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class RosSide:
    """What ROS does with the board: subscribes to its writers, publishes /board_cmd (reliable,
    a count, 20 Hz), calls /board_add."""

    def __init__(self, peer):
        from xrce.agent import interfaces

        interfaces.build([INTERFACES], names=["example_interfaces"])  # (cached after once)
        from example_interfaces.srv import AddTwoInts
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Int32

        self.peer = peer
        node = peer.node
        self.sensor = []  # (arrival, value)
        self.reliable = []
        node.create_subscription(Int32, "/board_sensor",
                                 lambda m: self.sensor.append((time.monotonic(), m.data)),
                                 QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
        node.create_subscription(Int32, "/board_reliable",
                                 lambda m: self.reliable.append((time.monotonic(), m.data)), 10)
        self.publisher = node.create_publisher(Int32, "/board_cmd", 10)
        self.client = node.create_client(AddTwoInts, "/board_add")
        self.AddTwoInts = AddTwoInts
        self.Int32 = Int32
        self.sent = []  # (time, value) published
        self._count = 0
        self._stop = False
        self._thread = threading.Thread(target=self._publish, daemon=True)
        self._thread.start()

    def _publish(self):
        while not self._stop:
            self._count += 1
            self.sent.append((time.monotonic(), self._count))
            self.publisher.publish(self.Int32(data=self._count))
            time.sleep(0.05)

    def call(self, a, b, timeout=WAIT_S):
        if not self.client.wait_for_service(timeout_sec=timeout):
            return None
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            future = self.client.call_async(self.AddTwoInts.Request(a=a, b=b))
            if wait_until(future.done, 3.0):
                return future.result().sum
            future.cancel()
        return None

    def stop(self):
        self._stop = True
        self._thread.join(5)


def graph_counts(peer):
    node = peer.node
    names = [n for n, _ns in peer.node_names()]
    services = [name for name, _types in node.get_service_names_and_types()]
    return {"nodes": names.count("restart_board"),
            "sensor_publishers": node.count_publishers("/board_sensor"),
            "reliable_publishers": node.count_publishers("/board_reliable"),
            "cmd_subscribers": node.count_subscribers("/board_cmd"),
            "add_services": services.count("/board_add")}
