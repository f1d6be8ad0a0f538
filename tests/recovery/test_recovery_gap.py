"""Issue 12: after an agent crash or a board reset, data is back in ROS soon, and the agent says
where the time went.

- the agent is killed with SIGKILL and started again 1 s later on the same port while a client
  publishes at 20 Hz: the longest gap in an rclpy subscriber stays within a generous bound, and
  the agent's own share (first datagram of the unknown session to first sample into ROS, from its
  recovery timeline) is well under a second;
- the board resets (a new session with the same key, the old one abandoned): same bound;
- the timeline line is in the agent's log at the default verbosity and in ``xrce-agent stats``;
- samples that reach the agent's datareader before the client's READ_DATA are delivered when it
  comes, up to the reader's history depth (what eProsima's agent does).

The bench (bench/restart/restart_gap.py) reports the figures; the bounds here only catch regressions such
as the 5-8 s gaps before issue 12 (a best-effort stream that swallowed every sample for seconds).
"""

import re
import subprocess
import sys
import time

import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String as RosString

from agent_process import REPO, AgentProcess
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from test_recovery_client import free_udp_port
from xrce.client.session import Session
from xrce.msgs.std_msgs import String
from xrce.transports.udp import UdpTransport

RATE_HZ = 20.0
BOARD_KEY = 0x1DC0FFEE
# Generous: the bench measures 1.4-4.6 s on the shared 2-core machine (1 s of it the downtime,
# up to ~3 s Fast DDS matching the restarted agent's writer); before issue 12 it was 5.2-8.6 s.
AGENT_RESTART_GAP_BOUND_S = 6.5
BOARD_RESET_GAP_BOUND_S = 3.0
TIMELINE = re.compile(r"client ([0-9a-f]{8}) recovery timeline \(([^)]*)\): first datagram \+0\.000 s, "
                      r"session established \+([\d.]+) s, entities re-created \+([\d.]+) s \((\d+)\), "
                      r"READ_DATAs restored (\S+)(?: s)? \((\d+)\), first sample into ROS \+([\d.]+) s")


class Board:
    """``xrce-client pub ... --rate 20`` as the user ran it (issue 12): its session recovers on
    its own; ``reset`` kills it (no DELETE) and boots it again with the same key."""

    def __init__(self, port, domain_id, topic, key=BOARD_KEY):
        self.args = [sys.executable, "-m", "xrce.client", "pub", "udp4", "-p", str(port),
                     "--topic", topic, "--type", "std_msgs/msg/String", "--data", "hello",
                     "--rate", str(RATE_HZ), "--count", "0", "--key", "%08X" % key,
                     "--domain", str(domain_id), "--node", "gap_board"]
        self.proc = self._start()

    def _start(self):
        return subprocess.Popen(self.args, cwd=REPO, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)

    def reset(self):
        self.proc.kill()
        self.proc.wait(10)
        self.proc = self._start()

    def close(self):
        if self.proc.poll() is None:
            self.proc.terminate()
        try:
            self.proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.communicate()


def longest_gap(arrivals, since):
    times = [t for t in list(arrivals)]
    start = max((i for i, t in enumerate(times) if t < since), default=0)
    return max((b - a for a, b in zip(times[start:], times[start + 1:])), default=None)


def subscribe(ros_peer, topic):  # noqa: F811
    arrivals = []
    best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    ros_peer.node.create_subscription(RosString, topic, lambda _m: arrivals.append(time.monotonic()),
                                      best_effort)
    return arrivals


def the_one_timeline(text):
    """The match of the single recovery timeline line in ``text`` (the agent's log or the output
    of ``xrce-agent stats``): one agent restart or board reset makes exactly one."""
    found = [m for m in map(TIMELINE.search, text.splitlines()) if m]
    assert len(found) == 1, text
    return found[0]


def stats_port(agent):
    return int(re.search(r"stats on 127\.0\.0\.1:(\d+)", agent.banner).group(1))


def test_agent_sigkill_and_restart_1s_later_gap_and_timeline(ros_peer, ros_domain):  # noqa: F811
    arrivals = subscribe(ros_peer, "/gap_chatter")
    port = free_udp_port()
    agent = AgentProcess("udp4", "-p", str(port), "-m", "dds").__enter__()
    board = None
    try:
        board = Board(port, ros_domain, "/gap_chatter")
        assert wait_until(lambda: len(arrivals) >= 10, 20)
        killed = time.monotonic()
        agent.proc.kill()  # a crash: no DELETE, nothing flushed
        agent.proc.wait(10)
        time.sleep(1.0)
        # Default verbosity, as a user runs it, with the stats server on.
        agent = AgentProcess("udp4", "-p", str(port), "-m", "dds", "--stats-port", "0").__enter__()
        before = len(arrivals)
        assert wait_until(lambda: len(arrivals) >= before + 20, 20), "no data after the restart"
        gap = longest_gap(arrivals, killed)
        print("longest gap %.2f s (agent down for 1 s)" % gap)
        assert gap < AGENT_RESTART_GAP_BOUND_S

        stats = subprocess.run([sys.executable, "-m", "xrce.agent", "stats", "-p",
                                str(stats_port(agent)), "--once"], cwd=REPO, capture_output=True,
                               text=True, timeout=60)
        assert stats.returncode == 0, stats.stderr
        in_stats = the_one_timeline(stats.stdout)
        # The agent's own user (this test's) finds the board by the key it sent; other local
        # users get its tag, never the key, the session's credential (test_hostile_ros).
        assert in_stats.group(1) == "%08x" % BOARD_KEY
        assert in_stats.group(2) == "session unknown to this agent"
        assert int(in_stats.group(5)) == 4  # participant, topic, publisher, datawriter
        assert float(in_stats.group(8)) < 1.5  # the agent's own share of the gap
    finally:
        if board is not None:
            board.close()
        agent.stop()
    in_log = the_one_timeline("".join(agent.output))
    # The operator's own log names the key (as eProsima's does); the rest of the line is the same.
    assert in_log.group(1) == "%08x" % BOARD_KEY
    assert in_log.group(0).split(" ", 2)[2] == in_stats.group(0).split(" ", 2)[2]


def test_board_reset_with_the_same_key_gap_and_timeline(ros_peer, ros_domain):  # noqa: F811
    arrivals = subscribe(ros_peer, "/reset_gap")
    board = None
    with AgentProcess("udp4", "-m", "dds") as agent:
        try:
            board = Board(agent.port, ros_domain, "/reset_gap")
            assert wait_until(lambda: len(arrivals) >= 10, 20)
            reset = time.monotonic()
            board.reset()  # killed, and boots again with the same key
            before = len(arrivals)
            assert wait_until(lambda: len(arrivals) >= before + 20, 20), "no data after the reset"
            gap = longest_gap(arrivals, reset)
            print("longest gap %.2f s across the board reset" % gap)
            assert gap < BOARD_RESET_GAP_BOUND_S
        finally:
            if board is not None:
                board.close()
        agent.stop()
    in_log = the_one_timeline("".join(agent.output))
    assert in_log.group(2) == "session restarted by the client"
    assert int(in_log.group(5)) == 4 and float(in_log.group(8)) < 1.0


READER_XML = ("<dds><data_reader><topic><kind>NO_KEY</kind><name>rt/early</name>"
              "<dataType>std_msgs::msg::dds_::String_</dataType><historyQos><kind>KEEP_LAST</kind>"
              "<depth>%d</depth></historyQos></topic><qos><reliability><kind>RELIABLE</kind>"
              "</reliability></qos></data_reader></dds>")


@pytest.mark.parametrize("representation", ["binary", "xml"])
def test_samples_before_read_data_are_delivered_up_to_the_history_depth(  # noqa: F811
        ros_peer, ros_domain, representation):  # noqa: F811
    depth = 5
    publisher = ros_peer.node.create_publisher(RosString, "/early", QoSProfile(
        depth=20, reliability=ReliabilityPolicy.RELIABLE))
    with AgentProcess("udp4", "-m", "dds") as agent:
        session = Session(UdpTransport("127.0.0.1", agent.port), history=16)
        try:
            assert session.create(attempts=5, timeout_ms=1000)
            node = session.create_participant(domain_id=ros_domain, name="late_reader")
            topic = session.create_topic(node, "rt/early", String.TYPE_NAME)
            subscriber = session.create_subscriber(node)
            if representation == "xml":
                reader = session.create_datareader(subscriber, xml=READER_XML % depth)
            else:
                reader = session.create_datareader(subscriber, topic, session.endpoint_qos(
                    reliable=True, keep_last=True, depth=depth))
            got = []
            session.set_reader_callback(reader, lambda msg: got.append(msg.data), String)
            assert session.run_until_all_status(5000), session.last_statuses
            assert wait_until(lambda: publisher.get_subscription_count() == 1, 15)
            for i in range(1, 9):  # 8 samples, no READ_DATA yet
                publisher.publish(RosString(data="early %d" % i))
            session.run_until_timeout(1000)  # they reach the agent's reader meanwhile
            assert got == []  # nothing is delivered without a READ_DATA
            session.read_data(reader, session.reliable)
            deadline = time.monotonic() + 5
            while len(got) < depth and time.monotonic() < deadline:
                session.spin_once(50)
            session.run_until_timeout(300)  # and nothing beyond the depth follows
        finally:
            session.close()
    assert got == ["early %d" % i for i in range(9 - depth, 9)]
