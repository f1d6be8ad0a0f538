"""A plain rclpy process driven by one-line commands on stdin, for bench/run.py.

It is the "ROS side" of every ROS benchmark, in its own process (its own GIL), on the domain given
by ROS_DOMAIN_ID. Replies are one line each on stdout. Commands:

    sub TOPIC be|rel [TYPE]  raw subscription counting arrivals (EventsExecutor); TYPE as
                             pkg/msg/Name, default geometry_msgs/msg/Twist
    lat TOPIC be|rel         Twist subscription recording now - linear.x (CLOCK_MONOTONIC seconds)
    count TOPIC              -> "N FIRST LAST": arrivals so far and first/last arrival times
    latency TOPIC            -> JSON list of the latencies recorded, in seconds
    publishers TOPIC         -> how many publishers this peer sees on TOPIC
    subscribers TOPIC        -> how many subscribers this peer sees on TOPIC
    flood TOPIC be|rel SECONDS   publish pre-serialized Twists flat out -> "N ELAPSED CPU"
                             (CPU: this process's user+system seconds during the flood)
    stamped TOPIC be|rel COUNT HZ  publish COUNT Twists with linear.x = send time -> "N"
    quit
"""

import importlib
import json
import os
import struct
import sys
import threading
import time

import rclpy
from geometry_msgs.msg import Twist
from rclpy.context import Context
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rclpy.signals import SignalHandlerOptions

_MONOTONIC = time.monotonic


def process_cpu_seconds():
    times = os.times()
    return times.user + times.system


def message_class(type_name):
    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module("%s.%s" % (package, kind)), name)


def qos(kind):
    reliability = ReliabilityPolicy.RELIABLE if kind == "rel" else ReliabilityPolicy.BEST_EFFORT
    return QoSProfile(depth=1000, reliability=reliability)


class Peer:
    def __init__(self):
        self.context = Context()
        rclpy.init(args=[], context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node("xrce_bench_peer", context=self.context, start_parameter_services=False,
                         enable_rosout=False, use_global_arguments=False)
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.jobs = []
        self.lock = threading.Lock()
        self.arrivals = {}  # topic -> [count, first, last]
        self.latencies = {}
        self.publishers = {}
        self.running = True
        self.thread = threading.Thread(target=self.spin, daemon=True)
        self.thread.start()

    def spin(self):
        never = rclpy.task.Future()
        while self.running:
            with self.lock:
                jobs, self.jobs = self.jobs, []
            for job, done in jobs:
                try:
                    done.append(job())
                except Exception as exc:  # reported to the caller
                    done.append(exc)
            self.executor.spin_until_future_complete(never, timeout_sec=0.002)

    def on_executor(self, job):
        """Entity changes on the spinning thread (EventsExecutor is not safe across threads)."""
        done = []
        with self.lock:
            self.jobs.append((job, done))
        while not done:
            time.sleep(0.001)
        if isinstance(done[0], Exception):
            raise done[0]
        return done[0]

    def subscribe(self, topic, kind, type_name=None):
        msg_class = Twist if type_name is None else message_class(type_name)
        record = self.arrivals[topic] = [0, 0.0, 0.0]

        def arrived(_raw):
            now = _MONOTONIC()
            if not record[0]:
                record[1] = now
            record[0] += 1
            record[2] = now

        self.on_executor(lambda: self.node.create_subscription(msg_class, topic, arrived,
                                                               qos(kind), raw=True))

    def measure_latency(self, topic, kind):
        samples = self.latencies[topic] = []
        unpack = struct.Struct("<d").unpack_from

        def arrived(raw):
            samples.append(_MONOTONIC() - unpack(raw, 4)[0])  # linear.x right after the header

        self.on_executor(lambda: self.node.create_subscription(Twist, topic, arrived, qos(kind),
                                                               raw=True))

    def flood(self, topic, kind, seconds):
        publisher = self.publisher(topic, kind)
        body = serialize_message(Twist())
        publish = publisher.publish
        sent = 0
        cpu_before = process_cpu_seconds()
        start = time.monotonic()
        end = start + seconds
        while True:
            for _ in range(100):
                publish(body)
            sent += 100
            if time.monotonic() >= end:
                break
        return sent, time.monotonic() - start, process_cpu_seconds() - cpu_before

    def publisher(self, topic, kind):
        publisher = self.publishers.get(topic)
        if publisher is None:
            publisher = self.publishers[topic] = self.on_executor(
                lambda: self.node.create_publisher(Twist, topic, qos(kind)))
            deadline = time.monotonic() + 10
            while self.node.count_subscribers(topic) == 0 and time.monotonic() < deadline:
                time.sleep(0.01)
            time.sleep(0.5)  # let discovery settle on both sides
        return publisher

    def stamped(self, topic, kind, count, hz):
        publisher = self.publisher(topic, kind)
        message = Twist()
        period = 1.0 / hz
        start = time.monotonic()
        for index in range(count):
            due = start + index * period
            now = time.monotonic()
            if due > now:
                time.sleep(due - now)
            message.linear.x = _MONOTONIC()
            publisher.publish(message)
        return count

    def close(self):
        self.running = False
        self.thread.join(5)
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


def main():
    peer = Peer()
    print("ready", flush=True)
    try:
        for line in sys.stdin:
            words = line.split()
            if not words:
                continue
            command, args = words[0], words[1:]
            if command == "quit":
                break
            if command == "sub":
                peer.subscribe(args[0], args[1], args[2] if len(args) > 2 else None)
                reply = "ok"
            elif command == "lat":
                peer.measure_latency(args[0], args[1])
                reply = "ok"
            elif command == "count":
                count, first, last = peer.arrivals.get(args[0], (0, 0.0, 0.0))
                reply = "%d %.6f %.6f" % (count, first, last)
            elif command == "latency":
                reply = json.dumps(peer.latencies.get(args[0], []))
            elif command == "publishers":
                reply = str(peer.node.count_publishers(args[0]))
            elif command == "subscribers":
                reply = str(peer.node.count_subscribers(args[0]))
            elif command == "stamped":
                reply = str(peer.stamped(args[0], args[1], int(args[2]), float(args[3])))
            elif command == "flood":
                sent, elapsed, cpu = peer.flood(args[0], args[1], float(args[2]))
                reply = "%d %.6f %.6f" % (sent, elapsed, cpu)
            else:
                reply = "error unknown command %r" % command
            print(reply, flush=True)
    finally:
        peer.close()


if __name__ == "__main__":
    main()
