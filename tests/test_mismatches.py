"""Mismatches that silently lose data, named (issue 38): a real agent process, real rclpy peers
and real sockets. A board's best-effort publisher beside a reliable ROS subscription, a ROS
publisher whose type differs from the board's subscription, and samples from ROS larger than the
board's stream can carry each give ONE WARNING naming the board (key and address), the topic,
both sides and the fix, counted in the stats."""

from __future__ import annotations

import re
import time

from rclpy.qos import QoSProfile, ReliabilityPolicy

from agent_process import AgentProcess
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from xrce.agent.observe.stats_view import fetch_stats
from xrce.client.session import Session
from xrce.msgs.std_msgs import String
from xrce.transports.udp import UdpTransport


def stats_port(agent):
    return int(re.search(r"stats on 127\.0\.0\.1:(\d+)", agent.banner).group(1))


def warnings(agent, what):
    return [line for line in "".join(agent.output).splitlines()
            if "WARNING" in line and what in line]


def mismatches(port):
    return fetch_stats(port)["agent"]["mismatches"]


def keep_alive_until(session, predicate, timeout_s=20.0):
    deadline = time.monotonic() + timeout_s
    while not predicate() and time.monotonic() < deadline:
        session.run_until_timeout(100)
    return predicate()


def test_best_effort_board_publisher_and_reliable_ros_subscription(ros_peer, ros_domain):  # noqa: F811
    from std_msgs.msg import String as RosString

    with AgentProcess("udp4", "-m", "dds", "--stats-port", "0") as agent:
        port = stats_port(agent)
        session = Session(UdpTransport("127.0.0.1", agent.port), history=8)
        try:
            assert session.create(attempts=5, timeout_ms=1000)
            node = session.create_participant(domain_id=ros_domain, name="sensor_board")
            session.create_writer(node, "/chatter", String, reliable=False)
            assert session.run_until_all_status(5000), session.last_statuses
            # The ROS side asks for reliable delivery: no sample of the board's ever reaches it.
            ros_peer.node.create_subscription(
                RosString, "/chatter", lambda _m: None,
                QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
            assert keep_alive_until(session, lambda: mismatches(port) >= 1), fetch_stats(port)
            # More ROS activity on the topic: still one line for this pair.
            ros_peer.node.create_publisher(RosString, "/chatter", 10)
            session.run_until_timeout(1500)
            snapshot = fetch_stats(port)
            assert snapshot["agent"]["mismatches"] == 1
            row = snapshot["clients"][0]
            key = session.key.hex()
            assert row["key"] == key
            writer = [e for e in row["endpoints"] if e["kind"] == "datawriter"]
            assert len(writer) == 1 and len(writer[0]["mismatches"]) == 1, writer
            named = writer[0]["mismatches"][0]
            session.delete(attempts=2, timeout_ms=500)
        finally:
            session.close()
        assert agent.stop() == 0
    lines = warnings(agent, "incompatible QoS")
    assert len(lines) == 1, lines
    line = lines[0]
    assert re.search(r"client %s at udp4 127\.0\.0\.1:\d+, datawriter 0x[0-9A-F]{3}\(5\): "
                     r"/chatter: " % key, line), line
    assert line.endswith(named)
    assert "the board's publisher is best_effort, volatile, depth 10" in line, line
    assert "the ROS subscription of node /xrce_test_peer is reliable, volatile;" in line, \
        line
    assert "fix: make the ROS subscription best-effort (qos_profile_sensor_data) or the " \
        "board's publisher reliable" in line, line


def test_a_ros_publisher_of_another_type_on_the_boards_topic(ros_peer, ros_domain):  # noqa: F811
    from std_msgs.msg import Int32

    with AgentProcess("udp4", "-m", "dds", "--stats-port", "0") as agent:
        port = stats_port(agent)
        session = Session(UdpTransport("127.0.0.1", agent.port), history=8)
        try:
            assert session.create(attempts=5, timeout_ms=1000)
            node = session.create_participant(domain_id=ros_domain, name="display_board")
            session.create_reader(node, "/status", String, lambda _m: None)
            assert session.run_until_all_status(5000), session.last_statuses
            ros_peer.node.create_publisher(Int32, "/status", 10)
            assert keep_alive_until(session, lambda: mismatches(port) >= 1), fetch_stats(port)
            session.run_until_timeout(1000)
            assert mismatches(port) == 1
            session.delete(attempts=2, timeout_ms=500)
        finally:
            session.close()
        assert agent.stop() == 0
    lines = warnings(agent, "type mismatch")
    assert len(lines) == 1, "".join(agent.output)
    assert re.search(r"client %s at udp4 127\.0\.0\.1:\d+, datareader 0x[0-9A-F]{3}\(6\): /status: "
                     r"type mismatch, nothing matches: the board's subscription has type "
                     r"std_msgs/msg/String, the ROS publisher of node /xrce_test_peer has "
                     r"std_msgs/msg/Int32; fix: " % session.key.hex(), lines[0]), lines[0]
