"""Data reaches ROS soon after either side appears (issue 22), in the two start orders whose lost
discovery answer used to cost up to one Fast DDS announcement period (3 s):

- (a) the agent is up, then an rclpy subscriber starts (a new process: a new DDS participant), then
  a client creates its writer. The new participant loses the agent's answer to its first
  announcement and learns of the agent at the agent's next periodic announcement: the agent's
  profile announces every 0.5 s instead of 3 s.
- (b) the rclpy subscriber is up, then the agent starts, then the client. The agent's participant
  sent its first announcement before its receivers were attached and lost the subscriber's answer;
  the agent's profile makes the builtin writers asynchronous, so that announcement leaves after.

With the agent idle beside the subscriber before the client comes (it joins the domain only with
a client's participant), the agent's participant is the newcomer as in (b).

The announcement period is checked directly: a socket on the unicast discovery port of the 32nd
participant of the test's domain (where the agent's participant sends every announcement under
LOCALHOST) counts the agent's announcements over 3 s, about 6 with the profile and 1 without.

Each trial of (a) and (b) measures the time from the client's CREATE of the writer to the first
sample in rclpy (bench/restart/discovery.py gives the figures: under 1 s in 20 of 20 trials of each order
on an idle machine). Fast DDS still loses a race now and then on a loaded machine: 2 of 40
trials of (a) under four CPU hogs on 2 cores saw their first sample after ~3 s, when the
subscriber's own first periodic announcement went out, although both sides had exchanged their
endpoints by 0.7 s (the samples themselves go through shared memory, out of a capture's sight).
So a trial may be slow without failing the test: every trial must see its first sample within
DELIVERY_S, and all but a few within SLOW_S. With the old settings about half
the trials lost the race and waited 0-3 s.
"""

import collections
import os
import socket
import struct
import subprocess
import sys
import threading
import time

import pytest

from agent_process import AgentProcess
from ros_helpers import ros_domain, wait_until  # noqa: F401
from xrce.client import Session
from xrce.msgs.std_msgs import String
from xrce.transports.udp import UdpTransport

SLOW_S = 1.5
DELIVERY_S = 5.0
TRIALS_A = 5
TRIALS_B = 3
IDLE_S = 3.0
SPDP_WRITER = 0x000100C2

_SUBSCRIBER = """
import sys, time
import rclpy
from rclpy.node import Node
from std_msgs.msg import String
rclpy.init(args=["--ros-args", "--disable-external-lib-logs"])  # no log file in ~/.ros
node = Node("discovery_order_listener", start_parameter_services=False, enable_rosout=False)
node.create_subscription(String, sys.argv[1],
                         lambda _m: print("%.6f" % time.monotonic(), flush=True), 10)
print("ready", flush=True)
try:
    rclpy.spin(node)
except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
    pass
"""


class Subscriber:
    """A plain rclpy subscriber in a process of its own (default reliable QoS, depth 10)."""

    def __init__(self, topic):
        self.proc = subprocess.Popen([sys.executable, "-c", _SUBSCRIBER, topic],
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        self.arrivals = []
        self.ready = threading.Event()
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()
        assert self.ready.wait(60), "the rclpy subscriber did not start"

    def _read(self):
        for line in self.proc.stdout:
            if line.startswith("ready"):
                self.ready.set()
            else:
                self.arrivals.append(float(line))

    def close(self):
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.thread.join(5)


def first_sample_delay(port, domain_id, topic, subscriber, key):
    """Create a session, participant and reliable writer on ``topic``; write every 20 ms until the
    subscriber reports a sample or DELIVERY_S pass. Seconds from the writer's CREATE to the
    first sample (None: none arrived)."""
    session = Session(UdpTransport("127.0.0.1", port), key=key)
    try:
        assert session.create()
        node = session.create_participant(domain_id=domain_id, name="discovery_order_client")
        assert session.run_until_all_status(5000), session.last_statuses
        created = time.monotonic()
        writer = session.create_writer(node, topic, String, reliable=True, depth=10)
        assert session.run_until_all_status(5000), session.last_statuses
        message = String(data="hello")
        while time.monotonic() - created < DELIVERY_S:
            if subscriber.arrivals:
                return subscriber.arrivals[0] - created
            session.write(writer, message)
            session.run_until_timeout(20)
        return None
    finally:
        session.delete()
        session.close()


def test_agent_then_subscriber_then_client(ros_domain):  # noqa: F811
    delays = []
    with AgentProcess("udp4", "-m", "dds") as agent:
        for trial in range(TRIALS_A):
            topic = "/discovery_order_a_%d_%d" % (os.getpid(), trial)
            subscriber = Subscriber(topic)
            try:
                delays.append(first_sample_delay(agent.port, ros_domain, topic, subscriber,
                                                 0x22A00000 + trial))
            finally:
                subscriber.close()
    # Two of five: the race left in Fast DDS (module docstring) hit 2 of 40 trials under four
    # CPU hogs; the announcement period itself is checked exactly by the test below.
    assert_fast_enough(delays, slow_allowed=2)


def test_subscriber_then_agent_then_client(ros_domain):  # noqa: F811
    delays = []
    topic = "/discovery_order_b_%d" % os.getpid()
    subscriber = Subscriber(topic)
    try:
        for trial in range(TRIALS_B):
            with AgentProcess("udp4", "-m", "dds") as agent:
                delays.append(first_sample_delay(agent.port, ros_domain, topic, subscriber,
                                                 0x22B00000 + trial))
            subscriber.arrivals.clear()
    finally:
        subscriber.close()
    assert_fast_enough(delays, slow_allowed=1)


def test_subscriber_then_idle_agent_then_client(ros_domain):  # noqa: F811
    """The agent joins a domain only with a client's participant: an agent that sat idle beside
    the subscriber has no participant the subscriber knows, and the first sample must still come
    within the discovery bound once a client connects (the agent's participant is then the
    newcomer, as in order (b)). Each trial starts with the domain left again."""
    delays = []
    topic = "/discovery_order_idle_%d" % os.getpid()
    subscriber = Subscriber(topic)
    try:
        with AgentProcess("udp4", "-m", "dds", "--domain-linger", "0.5") as agent:
            for trial in range(TRIALS_B):
                assert wait_until(lambda: not participant_threads(agent.proc.pid), 20)
                time.sleep(IDLE_S)
                delays.append(first_sample_delay(agent.port, ros_domain, topic, subscriber,
                                                 0x22D00000 + trial))
                subscriber.arrivals.clear()
    finally:
        subscriber.close()
    assert_fast_enough(delays, slow_allowed=1)


def participant_threads(pid):
    """The Fast DDS threads of participants in process ``pid`` (dds.udp.7400, dds.ev.0,
    dds.asyn.0.0, dds.shm.7411, ...; Python's threads keep the process's name). Not the
    shared-memory watchdog (dds.shm.wdog): a process-wide singleton that Fast DDS starts with the
    first participant and keeps until the process ends (it wakes once a second)."""
    names = []
    for tid in os.listdir("/proc/%d/task" % pid):
        try:
            with open("/proc/%d/task/%s/comm" % (pid, tid)) as comm:
                names.append(comm.read().strip())
        except OSError:
            pass
    return [name for name in names if name.startswith("dds.") and name != "dds.shm.wdog"]


def assert_fast_enough(delays, slow_allowed):
    assert all(d is not None for d in delays), "a trial saw no sample within %.1f s: %r" % (
        DELIVERY_S, delays)
    slow = [d for d in delays if d > SLOW_S]
    assert len(slow) <= slow_allowed, "%d of %d trials slower than %.1f s: %r" % (
        len(slow), len(delays), SLOW_S, delays)


def spdp_sender(datagram):
    """The GUID prefix of an RTPS datagram that carries a participant announcement, else None."""
    if datagram[:4] != b"RTPS" or len(datagram) < 20:
        return None
    offset = 20
    while offset + 4 <= len(datagram):
        kind, flags = datagram[offset], datagram[offset + 1]
        length = struct.unpack("<H" if flags & 1 else ">H", datagram[offset + 2:offset + 4])[0]
        if kind == 0x15 and length >= 12 and \
                struct.unpack(">I", datagram[offset + 12:offset + 16])[0] == SPDP_WRITER:
            return datagram[8:20]
        if not length:
            return None
        offset += 4 + length
    return None


def test_agent_announces_its_participant_every_half_second(ros_domain):  # noqa: F811
    # Fast DDS's well-known metatraffic unicast port of participant 31 in this domain
    # (7400 + 250 * domain + 10 + 2 * 31): nothing of this test's uses it, the agent's
    # participant sends each announcement there as to the 31 others.
    port = 7400 + 250 * ros_domain + 10 + 2 * 31
    listener = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    listener.bind(("127.0.0.1", port))
    session = None
    try:
        with AgentProcess("udp4", "-m", "dds") as agent:
            # The agent has a participant in a domain once a client has one there.
            session = Session(UdpTransport("127.0.0.1", agent.port), key=0x22C00000)
            assert session.create()
            session.create_participant(domain_id=ros_domain, name="announced")
            assert session.run_until_all_status(5000), session.last_statuses
            time.sleep(1.0)  # past the participant's 5 initial announcements (100 ms apart)
            listener.setblocking(False)
            while True:  # what queued up since the bind: the initial ones, not the period
                try:
                    listener.recv(65536)
                except BlockingIOError:
                    break
            listener.settimeout(0.2)
            announcements = collections.Counter()
            end = time.monotonic() + 3.0
            while time.monotonic() < end:
                try:
                    datagram = listener.recv(65536)
                except socket.timeout:
                    continue
                sender = spdp_sender(datagram)
                if sender is not None:
                    announcements[sender] += 1
            session.delete()
    finally:
        if session is not None:
            session.close()
        listener.close()
    assert len(announcements) == 1, announcements  # the agent's participant, alone in the domain
    count = max(announcements.values())
    assert count >= 4, "%d announcements in 3 s: the 0.5 s period of the agent's profile is not " \
                       "in force" % count


@pytest.fixture(autouse=True)
def _no_user_fast_dds_profile(monkeypatch):
    # The agent installs its own profile only when the user has none
    # (xrce/agent/middleware/ros/fastdds_profile.py); these tests are about that profile, so a profiles file in
    # the environment must not replace it.
    monkeypatch.delenv("FASTRTPS_DEFAULT_PROFILES_FILE", raising=False)
    monkeypatch.delenv("FASTDDS_DEFAULT_PROFILES_FILE", raising=False)
    monkeypatch.delenv("RMW_IMPLEMENTATION", raising=False)
