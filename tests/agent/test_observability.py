"""Agent observability through real agent processes: counters served on --stats-port move as the
traffic says (a corrupted serial frame is one CRC drop, a malformed message one decode error), the
``xrce-agent stats`` view renders them, --capture files decode back, and /diagnostics reaches an
rclpy subscriber in an isolated domain."""

import json
import os
import re
import socket
import subprocess
import sys
import time

import pytest

from rclpy.qos import QoSProfile, ReliabilityPolicy

from agent_process import REPO, AgentProcess
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from xrce.wire import constants as C
from xrce.agent.observe.capture import decode_capture, read_capture
from xrce.agent.observe.stats_view import fetch_stats
from xrce.client.session import Session
from xrce.msgs.std_msgs import String
from xrce.wire.submessages import CreateClient, Delete, GetInfo, Info, Status, StatusAgent, encode_message
from xrce.transports.framing import encode_frame
from xrce.transports.serial import SerialTransport
from xrce.transports import TransportError
from xrce.transports.udp import UdpTransport


def stats_port(agent):
    match = re.search(r"stats on 127\.0\.0\.1:(\d+)", agent.banner)
    assert match, agent.banner
    return int(match.group(1))


def client_row(snapshot, session):
    """The one client's row, named by the key the client sent: these tests read the stats as
    the agent's own user (tests/hostile/test_hostile_ros.py reads them as another)."""
    rows = [row for row in snapshot["clients"] if row["key"] == session.key.hex()]
    assert len(rows) == 1 and rows[0]["session_id"] == session.session_id, snapshot["clients"]
    assert snapshot["keys_shown"] and re.fullmatch("[0-9a-f]{8}", rows[0]["tag"])
    return rows[0]


def test_a_corrupted_serial_frame_is_one_crc_drop_and_traffic_is_counted():
    with AgentProcess("pseudoterminal", "-m", "ced", "--stats-port", "0") as agent:
        port = stats_port(agent)
        device = agent.device.rstrip(";")  # the banner continues "; stats on ..."
        transport = SerialTransport(device, local_addr=1)
        session = Session(transport, history=8)
        try:
            assert session.create(attempts=5, timeout_ms=1000)
            for _ in range(3):
                assert session.ping(timeout_ms=1000)
            before = fetch_stats(port)
            assert [link["crc_errors"] for link in before["links"]] == [0]
            row = client_row(before, session)
            # CREATE_CLIENT is session-less; the 3 pings are the client's in-session messages.
            assert row["messages_in"] == 3 and row["messages_out"] == 3
            assert row["decode_errors"] == 0

            ping = encode_message(session.session_id, C.STREAM_NONE, 0, None, [GetInfo()])
            frame = bytearray(encode_frame(ping, 1, 0))
            frame[-1] ^= 0x55  # the CRC no longer matches
            fd = os.open(device, os.O_WRONLY | os.O_NOCTTY)
            try:
                os.write(fd, bytes(frame))
            finally:
                os.close(fd)
            assert session.ping(timeout_ms=1000)  # the link resynchronises on the next flag
            after = fetch_stats(port)
            assert [link["crc_errors"] for link in after["links"]] == [1]
            assert after["links"][0]["drops"] == before["links"][0]["drops"] + 1
            row = client_row(after, session)
            assert row["messages_in"] == 4 and row["decode_errors"] == 0

            view = subprocess.run([sys.executable, "-m", "xrce.agent", "stats", "-p", str(port),
                                   "--once"], cwd=REPO, capture_output=True, text=True, timeout=30)
            assert view.returncode == 0, view.stderr
            assert row["key"] in view.stdout and row["tag"] in view.stdout
            assert "pseudoterminal " + device in view.stdout  # where the board is
            assert re.search(r"^pseudoterminal\s+\d+\s+\d+\s+\d+\s+\d+\s+1\s+1$", view.stdout,
                             re.MULTILINE), view.stdout
            session.delete(attempts=2, timeout_ms=500)
        finally:
            session.close()


def test_decode_errors_and_topic_samples_are_counted_per_client():
    with AgentProcess("udp4", "-m", "ced", "--stats-port", "0") as agent:
        port = stats_port(agent)
        session = Session(UdpTransport("127.0.0.1", agent.port), history=8)
        try:
            assert session.create(attempts=5, timeout_ms=1000)
            node = session.create_participant(domain_id=0, name="counted")
            writer = session.create_writer(node, "/counted", String, reliable=False)
            assert session.run_until_all_status(3000), session.last_statuses
            for i in range(25):
                session.write(writer, String(data="sample %d" % i), stream_id=session.best_effort)
                session.flush()
            assert session.ping(timeout_ms=1000)
            # A best-effort message whose only submessage claims more bytes than the datagram has.
            bad = bytes((session.session_id, C.BUILTIN_BEST_EFFORT, 0x40, 0x00,
                         C.WRITE_DATA, 0x01, 0xFF, 0x00, 1, 2, 3, 4))
            session.transport.send(bad)
            assert session.ping(timeout_ms=1000)
            snapshot = fetch_stats(port)
            row = client_row(snapshot, session)
            assert row["decode_errors"] == 1
            assert snapshot["agent"]["decode_errors"] == 1
            topics = [t for t in snapshot["topics"] if t["topic"] == "/counted"]
            assert len(topics) == 1 and topics[0]["direction"] == "to_ros"
            assert topics[0]["dds_topic"] == "rt/counted" and \
                topics[0]["type"] == "std_msgs/msg/String"
            assert topics[0]["samples"] == 25 and topics[0]["endpoints"] == 1
            # XCDR1 string: 4-byte length, the characters and a NUL.
            assert topics[0]["bytes"] == sum(4 + len("sample %d" % i) + 1 for i in range(25))
            session.delete(attempts=2, timeout_ms=500)
        finally:
            session.close()


def test_capture_file_decodes_back_in_order(tmp_path):
    capture = tmp_path / "agent.capture"
    with AgentProcess("udp4", "-m", "ced", "--capture", str(capture)) as agent:
        session = Session(UdpTransport("127.0.0.1", agent.port), history=8)
        try:
            assert session.create(attempts=5, timeout_ms=1000)
            assert session.ping(timeout_ms=1000)
            assert session.delete(attempts=2, timeout_ms=1000)
        finally:
            session.close()
        assert agent.stop() == 0
    records = list(read_capture(str(capture)))
    decoded = list(decode_capture(str(capture)))
    assert len(records) == len(decoded) == 6
    kinds = [(record.direction, [type(p) for p in payloads]) for record, _, payloads in decoded]
    assert kinds == [("in", [CreateClient]), ("out", [StatusAgent]), ("in", [GetInfo]),
                     ("out", [Info]), ("in", [Delete]), ("out", [Status])]
    # The key is masked by one pseudonym, the same wherever it appears (xrce.agent.observe.capture).
    pseudonym = decoded[0][2][0].client_key
    assert pseudonym != session.key and len(pseudonym) == 4
    assert session.key.hex() not in capture.read_text()
    assert all(r.link == "udp4" and r.endpoint.startswith("127.0.0.1:") for r in records)
    times = [r.time for r in records]
    assert times == sorted(times) and abs(times[0] - time.time()) < 120


def test_capture_names_an_ipv6_endpoint_in_brackets(tmp_path):
    if not socket.has_ipv6:
        pytest.skip("no IPv6")
    capture = tmp_path / "agent6.capture"
    with AgentProcess("udp6", "-m", "ced", "--capture", str(capture)) as agent:
        try:
            transport = UdpTransport("::1", agent.port)
        except TransportError:
            pytest.skip("no IPv6 loopback")
        port = transport._sock.getsockname()[1]
        session = Session(transport, history=8)
        try:
            assert session.create(attempts=5, timeout_ms=1000)
        finally:
            session.close()
        assert agent.stop() == 0
    records = list(read_capture(str(capture)))
    assert len(records) == 2
    assert {r.endpoint for r in records} == {"[::1]:%d" % port}


def test_diagnostics_name_the_client(ros_peer, ros_domain):  # noqa: F811
    from diagnostic_msgs.msg import DiagnosticArray

    arrays = []
    ros_peer.node.create_subscription(DiagnosticArray, "/diagnostics", arrays.append,
                                      QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    with AgentProcess("udp4", "-m", "dds") as agent:
        session = Session(UdpTransport("127.0.0.1", agent.port), history=8)
        try:
            assert session.create(attempts=5, timeout_ms=1000)
            node = session.create_participant(domain_id=ros_domain, name="diagnosed")
            assert session.run_until_all_status(5000), session.last_statuses
            prefix = "xrce_agent: client "

            def named():
                return any(status.name.startswith(prefix) for array in list(arrays)
                           for status in array.status)

            deadline = time.monotonic() + 15
            while not named() and time.monotonic() < deadline:
                session.run_until_timeout(100)  # stay alive for the agent
            assert named(), [s.name for a in arrays for s in a.status]
            status = next(s for a in arrays for s in a.status if s.name.startswith(prefix))
            values = {kv.key: kv.value for kv in status.values}
            assert values["link"] == "udp4" and int(values["messages_in"]) >= 1
            # Findable without the key: its address and its node, domain and topics.
            assert re.fullmatch(r"udp4 127\.0\.0\.1:\d+", values["address"]), values
            assert values["nodes"] == "/diagnosed (domain %d)" % ros_domain, values
            assert "key" not in values and "tag" not in values
            # Named by its tag: the key would let any ROS node take the session over.
            assert re.fullmatch("[0-9a-f]{8}", status.hardware_id) and \
                status.name == prefix + status.hardware_id
            assert status.hardware_id != session.key.hex()
            session.delete_entity(node)
            session.delete(attempts=2, timeout_ms=500)
        finally:
            session.close()


def _main_thread_switches(pid):
    with open("/proc/%d/task/%d/schedstat" % (pid, pid)) as schedstat:
        return int(schedstat.read().split()[2])


def _main_thread_wakes_over(pid, seconds):
    before = _main_thread_switches(pid)
    time.sleep(seconds)
    return _main_thread_switches(pid) - before


def test_the_agent_sleeps_until_someone_subscribes_to_diagnostics(ros_peer, ros_domain):  # noqa: F811
    """No --stats-port, nobody on /diagnostics: the agent's loop thread does not wake at all (it
    used to, once a second, to count rates nobody read), with no client and with a silent
    client's participant in the domain. A subscription starts the rounds (the publisher's matched
    event), its end stops them again. (The agent joins the domain, where /diagnostics goes out,
    only with a client participant there.)"""
    from diagnostic_msgs.msg import DiagnosticArray

    with AgentProcess("udp4", "-m", "dds") as agent:
        pid = agent.proc.pid
        time.sleep(2)  # start-up settles
        assert _main_thread_wakes_over(pid, 3) <= 1

        session = Session(UdpTransport("127.0.0.1", agent.port), history=8)
        try:
            assert session.create(attempts=5, timeout_ms=1000)
            session.create_participant(domain_id=ros_domain, name="silent")
            assert session.run_until_all_status(5000), session.last_statuses
            # The domain's start-up and DDS discovery settle: the node is in the peer's graph, then
            # 6 s (what is measured is the steady state; 2 s was too short on a slowed host).
            assert wait_until(lambda: ("silent", "/") in ros_peer.node_names(), 20)
            time.sleep(6)
            assert _main_thread_wakes_over(pid, 3) <= 1

            arrays = []
            subscription = ros_peer.node.create_subscription(
                DiagnosticArray, "/diagnostics", arrays.append,
                QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
            assert wait_until(lambda: arrays, timeout_s=15), "no /diagnostics once subscribed"
            assert arrays[-1].status[0].name == "xrce_agent"

            ros_peer.node.destroy_subscription(subscription)
            time.sleep(2)  # the unmatch reaches the agent
            count = len(arrays)
            assert _main_thread_wakes_over(pid, 3) <= 1
            assert len(arrays) == count
        finally:
            session.close()


def test_stats_json_finds_a_board_by_key_address_nodes_and_ros_names(ros_domain):  # noqa: F811
    """`xrce-agent stats --json`, read as the agent's own user: the board's key as it sent it,
    its address, its node and domain, its topics and types as ROS tools name them."""
    with AgentProcess("udp4", "-m", "dds", "--stats-port", "0") as agent:
        port = stats_port(agent)
        session = Session(UdpTransport("127.0.0.1", agent.port), key=0x0BADC0DE, history=8)
        try:
            assert session.create(attempts=5, timeout_ms=1000)
            local_port = session.transport._sock.getsockname()[1]
            node = session.create_participant(domain_id=ros_domain, name="turtlebot3_core")
            session.create_writer(node, "/chatter", String, reliable=False)
            session.create_reader(node, "/cmd_text", String, lambda _m: None)
            assert session.run_until_all_status(5000), session.last_statuses
            out = subprocess.run([sys.executable, "-m", "xrce.agent", "stats", "-p", str(port),
                                  "--json"], cwd=REPO, capture_output=True, text=True, timeout=30)
            assert out.returncode == 0, out.stderr
            snapshot = json.loads(out.stdout)
            table = subprocess.run([sys.executable, "-m", "xrce.agent", "stats", "-p", str(port),
                                    "--once"], cwd=REPO, capture_output=True, text=True,
                                   timeout=30).stdout
            session.delete(attempts=2, timeout_ms=500)
        finally:
            session.close()
        assert agent.stop() == 0
    row = snapshot["clients"][0]
    assert row["key"] == "0badc0de" and row["address"] == "udp4 127.0.0.1:%d" % local_port
    assert [(p["name"], p["node"], p["domain"]) for p in row["participants"]] == \
        [("turtlebot3_core", "node /turtlebot3_core", ros_domain)]
    assert sorted((e["kind"], e["topic"], e["type"], e["dds_topic"], e["qos"])
                  for e in row["endpoints"]) == [
        ("datareader", "/cmd_text", "std_msgs/msg/String", "rt/cmd_text",
         "reliable, volatile, keep_last 10"),
        ("datawriter", "/chatter", "std_msgs/msg/String", "rt/chatter",
         "best_effort, volatile, keep_last 10")]
    assert sorted(t["topic"] for t in snapshot["topics"]) == ["/chatter", "/cmd_text"]
    for text in ("0badc0de", "udp4 127.0.0.1:%d" % local_port, "/turtlebot3_core (domain %d)"
                 % ros_domain, "/chatter", "/cmd_text", "std_msgs/msg/String"):
        assert text in table, table
