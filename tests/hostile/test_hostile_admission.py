"""A stranger outside ``--allow-from`` who knows a board's client key, and a flood of refused
CREATEs, against a live agent on loopback (the two gaps issue 26 left; its CREATE_CLIENT
allow-list tests are in test_hostile_ros.py).

Loopback is all of 127.0.0.0/8 on Linux: the board speaks from 127.0.0.1, which the agent
admits, and the stranger from 127.0.0.2, which it does not.
"""

from __future__ import annotations

import re
import socket
import time

import pytest

from agent_process import AgentProcess
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from test_fastpath import CapturingTransport, Twist_ros, needs_extension, twist_datagrams, with_seq
from test_observability import stats_port
from xrce.wire import constants as C
from xrce.agent.observe.stats_view import fetch_stats
from xrce.client.session import Session
from xrce.msgs.geometry_msgs import Twist
from xrce.wire.submessages import Delete, encode_message
from xrce.transports.udp import UdpTransport

BOARD_KEY = 0x5AFE0B0A
STRANGER_ADDRESS = "127.0.0.2"


@pytest.mark.parametrize("switch", [pytest.param("1", marks=needs_extension), "0"],
                         ids=["compiled", "python"])
def test_a_stranger_with_the_key_changes_nothing_from_outside_allow_from(ros_peer, ros_domain,  # noqa: F811
                                                                         switch):
    """A keyed session (id < 0x80) is found by the key in each header. From an address outside
    --allow-from, a sample written with the board's key, a DELETE of its writer and a DELETE of
    the client itself are dropped before any session lookup, on the compiled receive path too;
    the board goes on publishing and its session is intact."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    received = []
    topic = "/allow_from_" + ("compiled" if switch == "1" else "python")
    ros_peer.node.create_subscription(Twist_ros(), topic, lambda m: received.append(m.linear.x),
                                      QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT))
    with AgentProcess("udp4", "-m", "dds", "-v", "5", "--allow-from", "127.0.0.1/32",
                      "--stats-port", "0", env={"XRCE_FASTPATH": switch}) as agent:
        port = stats_port(agent)
        board = Session(CapturingTransport(UdpTransport("127.0.0.1", agent.port)), key=BOARD_KEY,
                        session_id=0x01, history=8)
        stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            stranger.bind((STRANGER_ADDRESS, 0))
            stranger.settimeout(0.3)
            assert board.create(attempts=5, timeout_ms=1000)
            node = board.create_participant(domain_id=ros_domain, name="allowed_board")
            writer = board.create_writer(node, topic, Twist, reliable=False)
            assert board.run_until_all_status(5000), board.last_statuses
            assert wait_until(lambda: ros_peer.node.count_publishers(topic) > 0, 10)
            time.sleep(0.5)  # the subscriber's matching by the agent's publisher
            frames = twist_datagrams(board, writer, list(range(1, 11)) + [666])
            send = board.transport.inner.send
            for seq in range(5):  # the first take the Python path and register the compiled one
                send(with_seq(frames[seq], seq))
            assert wait_until(lambda: 5.0 in received, 10), received

            before = fetch_stats(port)["agent"]
            key = BOARD_KEY.to_bytes(4, "big")
            attack = [with_seq(frames[10], seq) for seq in range(0x100, 0x110)]  # newer samples
            attack.append(encode_message(0x01, C.STREAM_NONE, 0, key, [Delete(0x7001, writer)]))
            attack.append(encode_message(0x01, C.STREAM_NONE, 0, key,
                                         [Delete(0x7002, C.OBJECTID_CLIENT)]))
            for datagram in attack:
                stranger.sendto(datagram, ("127.0.0.1", agent.port))
                time.sleep(0.01)
            with pytest.raises(socket.timeout):  # no reply: nothing was read
                stranger.recvfrom(2048)

            # The board's next samples (numbers beyond the stranger's: a best-effort stream
            # would drop older ones had the stranger's been taken) still reach ROS.
            for seq, frame in zip(range(0x200, 0x205), frames[5:10]):
                send(with_seq(frame, seq))
            assert wait_until(lambda: 10.0 in received, 10), received
            assert 666.0 not in received
            assert ros_peer.node.count_publishers(topic) > 0
            assert board.ping(timeout_ms=1000)
            time.sleep(1.5)  # the compiled path's counters reach the stats within a second
            after = fetch_stats(port)["agent"]
            assert after["sources_refused"] - before["sources_refused"] == len(attack)
            assert after["dropped"] - before["dropped"] >= len(attack)
            board.delete(attempts=2, timeout_ms=500)
        finally:
            stranger.close()
            board.close()
        assert agent.stop() == 0
    output = "".join(agent.output)
    if switch == "1":  # the compiled path was in use, so the attack went through it first
        assert "best-effort samples take the compiled path" in output
    drops = re.findall(r"dropped a datagram of session 0x01 from udp4 127\.0\.0\.2:\d+: address "
                       r"127\.0\.0\.2 not in --allow-from", output)
    assert 1 <= len(drops) <= 5, output  # rate-limited: 18 datagrams, a few lines


def test_a_flood_of_refused_creates_logs_a_bounded_number_of_lines(ros_domain):  # noqa: F811
    """500 CREATEs of ROS topics whose names ROS refuses (a space in a token; a type name that is no
    ROS one is a plain DDS topic, and a well-formed name of a missing package is carried by name),
    from five sessions: each is answered ERR_DDS_ERROR, the first few are logged naming the topic,
    the rest are counted in a line instead of written each."""
    sessions, per_session = 5, 100
    with AgentProcess("udp4", "-m", "dds") as agent:
        for s in range(sessions):
            session = Session(UdpTransport("127.0.0.1", agent.port))
            try:
                assert session.create(attempts=5, timeout_ms=1000)
                node = session.create_participant(domain_id=ros_domain, name="flooder%d" % s)
                assert session.run_until_all_status(5000), session.last_statuses
                statuses = []
                for batch in range(0, per_session, 10):
                    for i in range(s * per_session + batch, s * per_session + batch + 10):
                        session.create_topic(node, "rt/flood%d x" % i, "std_msgs::msg::dds_::String_")
                    assert not session.run_until_all_status(20000)
                    statuses += list(session.last_statuses.values())
                assert statuses == [C.STATUS_ERR_DDS_ERROR] * per_session
                assert session.ping(timeout_ms=1000)
                session.delete(attempts=2, timeout_ms=500)
            finally:
                session.close()
        assert agent.stop() == 0
    output = "".join(agent.output)
    logged = re.findall(r"creating topic 0x[0-9A-F]{3}\(2\) failed: '(flood\d+) x' is not a valid ROS name", output)
    assert logged[:1] == ["flood0"], output[-3000:]  # the first one, named
    not_logged = sum(int(n) for n in re.findall(r"(\d+) more failed CREATEs not logged", output))
    assert len(logged) + not_logged == sessions * per_session, output[-3000:]  # logged or counted
    assert len(logged) <= 20, len(logged)  # 5 a window of 10 s: the flood takes far less than 40 s
