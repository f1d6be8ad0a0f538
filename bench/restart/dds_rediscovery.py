"""How long a restarted ROS participant takes to find one that stayed up, without any agent.

    unshare -n sh -c 'ip link set lo up && .venv/bin/python bench/restart/dds_rediscovery.py [--runs 8]'
        [--new-profile XML] [--old-profile XML]

Issue 12 asks for an agent-restart gap of at most 3.5 s; bench/restart/restart_gap.py shows that about half
of the restarts lose up to 3 s after the agent is already serving its client. This script removes
the agent from the picture: a plain rclpy subscriber stays up, a plain rclpy publisher (defaults,
best-effort) is killed with SIGKILL and started again 1 s later, and each run reports the time from
the publisher's first ``publish()`` to the first sample the subscriber gets.

When the process may open a packet socket (root inside its own network namespace, as above), it
also records the RTPS discovery traffic on ``lo`` and tells, for each run, how the restarted
participant came to know the subscriber's participant:

- ``reply``: from the subscriber's answer to its first announcement (a few ms);
- ``periodic``: the subscriber's answer is on the wire right after the first announcement, but the
  restarted participant never acts on it (no heartbeat, no ACKNACK towards the subscriber); it
  starts talking to the subscriber only after the subscriber's next periodic announcement, which
  Fast DDS sends every 3 s by default. The delay is that announcement's phase: 0-3 s.

What we read from this (Fast DDS 2.14 in the Jazzy wheels): the participant sends its first
announcement before its receive paths are attached (``RTPSParticipantImpl::enable`` enables the
builtin protocols, then registers the receivers), so an answer fast enough to arrive in between
is dropped, and the subscriber never answers again because it already knows the participant.
Initial announcements only add later copies (which the subscriber ignores), and with
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST rmw_fastrtps replaces the profile's transports with its
own (shared memory + UDPv4 to 32 local ports). What does move the first announcement is a
participant-level ``throughputController`` in the restarted participant's profile: Fast DDS 2.14
then creates the builtin writers asynchronous, so the announcement leaves from the sender thread
after the receivers are attached (bytesPerPeriod 0: the unlimited asynchronous controller, no
periodic wake-up; a limited one with a 1 ms period cost the idle agent 2 % of a core, and with
one of a 1 s period bench/restart/discovery.py's order (a) saw its first sample only after 2.5-2.7 s in
2 of 25 trials, 0 of 50 with the unlimited one). xrce-agent's profile
(xrce/agent/middleware/ros/fastdds_profile.xml) does this; ``--new-profile`` gives the restarted publisher a
profiles file, ``--old-profile`` the subscriber that stays up. Eight restarts each (issue 22, in
a network namespace of its own): defaults 5 of 8 waited for the periodic announcement (first
sample after 0.1-3.0 s); the restarted publisher with the agent's profile 0 of 8 (0.00-0.06 s:
the agent restarted next to running ROS nodes); the subscriber with the agent's profile 3 of 8
still lost the answer, but its periodic announcement comes every 0.5 s (first sample within
0.80 s: a ROS node started next to a running agent).
The first announcement itself takes a while: under LOCALHOST, rmw_fastrtps gives the UDP
transport 32 initial peer ports (``maxInitialPeersRange``) and the participant sends to them one
after another, 0.4-3 ms in all here, and a subscriber with a low participant id answers its copy
well within that (the script prints both per run; capture times are read by a Python thread, so
they are approximate and cannot show exactly when the receivers were attached). SUBNET
(multicast) announcements are shorter and still lost the answer in 3 of 10 restarts here. Tried
in the restarted process, timings only, 10-12 restarts each: a throw-away participant on an
unused domain first (code paged in) and SCHED_BATCH during creation (the new Fast DDS threads do
not preempt the creating one) brought the slow restarts from 4-5 of 10 to 2-3 of 10 at best, so
neither is used.
The race is lost far more often when the CPUs are busy at that moment: when this script parsed
each captured packet as it came (Python, next to the two ROS processes) all 8 runs waited; with
no capture about half did. The capture now only stores frames and parses them between runs.
"""

import os
import random
import signal
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

PYTHON = sys.executable
TOPIC = "/rediscovery"
SPDP_WRITER = 0x000100C2
SUBMESSAGE_DATA, SUBMESSAGE_HEARTBEAT, SUBMESSAGE_ACKNACK = 0x15, 0x07, 0x06


def subscriber_main():
    """Child: plain rclpy subscriber with defaults, one line per arrival (CLOCK_MONOTONIC)."""
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data
    from std_msgs.msg import String

    rclpy.init(args=[])
    node = Node("rediscovery_listener")
    out = sys.stdout
    node.create_subscription(String, TOPIC, lambda _m: out.write("%.6f\n" % time.monotonic())
                             or out.flush(), qos_profile_sensor_data)
    out.write("ready\n")
    out.flush()
    rclpy.spin(node)


def publisher_main():
    """Child: plain rclpy publisher at 20 Hz; prints the time of its first publish()."""
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data
    from std_msgs.msg import String

    rclpy.init(args=[])
    node = Node("rediscovery_talker")
    publisher = node.create_publisher(String, TOPIC, qos_profile_sensor_data)
    message = String(data="hello")
    print("%.6f" % time.monotonic(), flush=True)
    while True:
        publisher.publish(message)
        time.sleep(0.05)


class RtpsCapture:
    """RTPS datagrams seen on lo: (time, source GUID prefix, UDP destination port, submessages)."""

    def __init__(self):
        self.frames = []  # parsed only when asked: parsing as they come delays the ROS processes
        self.sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(0x0003))
        self.sock.bind(("lo", 0))
        threading.Thread(target=self._run, daemon=True).start()

    def _run(self):
        while True:
            frame, address = self.sock.recvfrom(65535)
            if address[2] != socket.PACKET_OUTGOING:  # each loopback datagram shows up twice
                self.frames.append((time.monotonic(), frame))

    def packets(self):
        parsed = ((stamp, parse_rtps(frame[14:])) for stamp, frame in list(self.frames))
        return [(stamp,) + packet for stamp, packet in parsed if packet]


def parse_rtps(ip):
    """(source prefix, destination port, [(submessage id, writer entity id)]) or None."""
    if len(ip) < 20 or ip[9] != 17:
        return None
    header = (ip[0] & 15) * 4
    port = struct.unpack(">H", ip[header + 2:header + 4])[0]
    rtps = ip[header + 8:]
    if rtps[:4] != b"RTPS":
        return None
    submessages = []
    offset = 20
    while offset + 4 <= len(rtps):
        kind, flags = rtps[offset], rtps[offset + 1]
        length = struct.unpack("<H" if flags & 1 else ">H", rtps[offset + 2:offset + 4])[0]
        body = rtps[offset + 4:offset + 4 + length] if length else rtps[offset + 4:]
        is_data = kind == SUBMESSAGE_DATA and len(body) >= 12
        writer = struct.unpack(">I", body[8:12])[0] if is_data else 0
        submessages.append((kind, writer))
        if not length:
            break
        offset += 4 + length
    return rtps[8:20], port, submessages


def classify(packets, subscriber, launched):
    """How the participant started at ``launched`` learned of ``subscriber`` (see the docstring)."""
    def spdp(packet):
        return any(kind == SUBMESSAGE_DATA and writer == SPDP_WRITER for kind, writer in packet[3])

    mine = [p for p in packets if p[0] >= launched and p[1] != subscriber and spdp(p)]
    if not mine:
        return "no announcement seen"
    prefix, first = mine[0][1], mine[0][0]
    talks = [p for p in packets if p[1] == prefix and any(
        kind in (SUBMESSAGE_HEARTBEAT, SUBMESSAGE_ACKNACK) for kind, _w in p[3])]
    if not talks:
        return "never talked to the subscriber"
    known = talks[0][0]
    answered = any(p[1] == subscriber and spdp(p) and first <= p[0] <= first + 0.05
                   for p in packets)
    # The first announcement goes to every initial peer port in turn; an answer that comes back
    # before that burst (and the receiver registration after it) is over is the one dropped.
    burst = [p[0] for p in mine if p[0] - first < 0.05]
    answers = [p[0] for p in packets if p[1] == subscriber and spdp(p) and first <= p[0] <= first + 0.05]
    timing = "; first announcement to %d ports over %.2f ms, answer at %s" % (
        len(burst), (burst[-1] - first) * 1e3,
        "+%.2f ms" % ((answers[0] - first) * 1e3) if answers else "-")
    if known - first < 0.05:
        return "reply (+%.2f s)" % (known - first) + timing
    after_periodic = any(p[1] == subscriber and spdp(p) and known - 0.05 <= p[0] <= known
                         for p in packets)
    return "%s +%.2f s (the subscriber's answer to the first announcement: %s)" % (
        "periodic" if after_periodic else "late, not after a periodic announcement",
        known - first, "sent, not acted on" if answered else "not seen") + timing


def measure(env, runs=8, downtime=1.0, log=print, with_capture=True, old_profile=None,
            new_profile=None):
    """``old_profile`` / ``new_profile``: a Fast DDS profiles file for the subscriber that stays
    up / the publisher that restarts (None: Fast DDS's and rmw_fastrtps's defaults)."""
    old_env, new_env = (dict(env, FASTRTPS_DEFAULT_PROFILES_FILE=profile) if profile else env
                        for profile in (old_profile, new_profile))
    try:
        capture = RtpsCapture() if with_capture else None
    except (PermissionError, OSError) as error:
        capture = None
        log("no packet capture (%s): timings only" % error)
    subscriber = subprocess.Popen([PYTHON, __file__, "--subscriber"], env=old_env, cwd=REPO,
                                  stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    arrivals = []
    assert subscriber.stdout.readline().strip() == "ready"
    threading.Thread(target=lambda: [arrivals.append(float(line)) for line in subscriber.stdout],
                     daemon=True).start()

    def start_publisher():
        launched = time.monotonic()
        process = subprocess.Popen([PYTHON, __file__, "--publisher"], env=new_env, cwd=REPO,
                                   stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        return process, launched, float(process.stdout.readline())

    delays, ways = [], []
    publisher, _launched, _first = start_publisher()
    try:
        time.sleep(3.0)
        # The subscriber started first: the first RTPS datagram on lo is its announcement.
        subscriber_prefix = capture.packets()[0][1] if capture and capture.frames else None
        for run in range(runs):
            os.kill(publisher.pid, signal.SIGKILL)
            publisher.wait()
            time.sleep(downtime)
            seen = len(arrivals)
            publisher, launched, first_publish = start_publisher()
            deadline = time.monotonic() + 10.0
            while len(arrivals) == seen and time.monotonic() < deadline:
                time.sleep(0.01)
            delay = arrivals[seen] - first_publish if len(arrivals) > seen else float("nan")
            delays.append(delay)
            way = classify(capture.packets(), subscriber_prefix, launched) if capture else ""
            ways.append(way)
            log("run %d: first publish -> first sample %.2f s  %s" % (run + 1, delay, way))
            # Random pause: restarts fall at any phase of the subscriber's 3 s announcements.
            time.sleep(2.0 + 3.0 * random.random())
    finally:
        publisher.kill()
        subscriber.kill()
        publisher.wait()
        subscriber.wait()
    return delays, ways


def main(argv=None):
    import argparse

    from ros_helpers import DomainLease

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=8)
    parser.add_argument("--downtime", type=float, default=1.0)
    parser.add_argument("--range", default="LOCALHOST", choices=("LOCALHOST", "SUBNET"),
                        help="ROS_AUTOMATIC_DISCOVERY_RANGE (SUBNET needs multicast on lo)")
    parser.add_argument("--no-capture", action="store_true", help="timings only")
    parser.add_argument("--old-profile", metavar="XML",
                        help="Fast DDS profiles file of the subscriber that stays up")
    parser.add_argument("--new-profile", metavar="XML",
                        help="Fast DDS profiles file of the publisher that restarts")
    args = parser.parse_args(argv)
    lease = DomainLease()
    env = dict(os.environ, ROS_DOMAIN_ID=str(lease.domain_id),
               ROS_AUTOMATIC_DISCOVERY_RANGE=args.range)
    try:
        delays, ways = measure(env, args.runs, args.downtime, with_capture=not args.no_capture,
                               old_profile=args.old_profile, new_profile=args.new_profile)
    finally:
        lease.release()
    finite = [d for d in delays if d == d]
    print("restarted rclpy publisher, first publish -> first sample: median %.2f s, max %.2f s"
          % (statistics.median(finite), max(finite)))
    late = sum(1 for way in ways if way.startswith("periodic"))
    if any(ways):
        print("runs that waited for the subscriber's periodic announcement: %d of %d"
              % (late, len(ways)))
    return 0


if __name__ == "__main__":
    if sys.argv[1:2] == ["--subscriber"]:
        subscriber_main()
    elif sys.argv[1:2] == ["--publisher"]:
        publisher_main()
    else:
        sys.exit(main())
