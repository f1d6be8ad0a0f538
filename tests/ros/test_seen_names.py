"""Issue 53 item 3, "seen by the operator": an agent that names boards otherwise than they asked
(``--ros-args -r __ns:=/robot1 -r cmd_vel:=cmd_vel_safe``, ``--domain D``) shows the board's own
names beside the given ones and which naming gave them, in its ``-v 4`` lines, in ``xrce-agent
stats --json`` and on ``/diagnostics``; two boards given one service or one node name are one
WARNING each, naming both boards. Our client over UDP, a real agent process, real rclpy."""

import json
import re
import subprocess
import sys
import time

from rclpy.qos import QoSProfile, ReliabilityPolicy
from test_msgs.srv import BasicTypes

from agent_process import REPO, AgentProcess
from ros_helpers import DomainLease, ros_domain, ros_peer, wait_until  # noqa: F401
from xrce.client.session import Session
from xrce.msgs.std_msgs import String
from xrce.transports.udp import UdpTransport

NAMING = ("--ros-args", "-r", "__ns:=/robot1", "-r", "cmd_vel:=cmd_vel_safe", "--")


class RawBasicTypes:
    """A service type the client carries as bytes: only its name matters here."""
    TYPE_NAME_REQUEST = "test_msgs::srv::dds_::BasicTypes_Request_"
    TYPE_NAME_RESPONSE = "test_msgs::srv::dds_::BasicTypes_Response_"
    Request = None
    Response = None


def _stats_port(agent):
    match = re.search(r"stats on 127\.0\.0\.1:(\d+)", agent.banner)
    assert match, agent.banner
    return int(match.group(1))


def _board(agent, key):
    session = Session(UdpTransport("127.0.0.1", agent.port), key=key, history=8)
    assert session.create(attempts=5, timeout_ms=1000)
    return session


def _log_lines(agent, pattern):
    return [line for line in "".join(agent.output).splitlines() if re.search(pattern, line)]


def test_a_renamed_board_is_shown_with_its_own_names(ros_peer, ros_domain):  # noqa: F811
    from diagnostic_msgs.msg import DiagnosticArray

    arrays = []
    ros_peer.node.create_subscription(DiagnosticArray, "/diagnostics", arrays.append,
                                      QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    board_domain = DomainLease()  # what the board asks for, overridden by --domain
    try:
        with AgentProcess("udp4", "-m", "dds", "--stats-port", "0", *NAMING,
                          "--domain", str(ros_domain)) as agent:
            session = _board(agent, 0x0BADC0DE)
            try:
                node = session.create_participant(domain_id=board_domain.domain_id,
                                                  name="mcu_node")
                session.create_writer(node, "/chatter", String, reliable=True)
                session.create_reader(node, "/cmd_vel", String, lambda _m: None, reliable=True)
                session.create_service_server(node, "/add_two_ints", RawBasicTypes,
                                              lambda *_: None)
                assert session.run_until_all_status(5000), session.last_statuses
                out = subprocess.run([sys.executable, "-m", "xrce.agent", "stats", "-p",
                                      str(_stats_port(agent)), "--json"], cwd=REPO,
                                     capture_output=True, text=True, timeout=30)
                assert out.returncode == 0, out.stderr
                snapshot = json.loads(out.stdout)

                def diagnosed():
                    return [s for a in list(arrays) for s in a.status
                            if s.name.startswith("xrce_agent: client ")]

                deadline = time.monotonic() + 15
                while not diagnosed() and time.monotonic() < deadline:
                    session.run_until_timeout(100)  # stay alive for the agent
                assert diagnosed(), [s.name for a in arrays for s in a.status]
                session.delete(attempts=2, timeout_ms=500)
            finally:
                session.close()
            assert agent.stop() == 0
    finally:
        board_domain.release()
    asked = board_domain.domain_id

    # -v 4: the board's names, then what ROS was given and by which naming.
    assert _log_lines(agent, r"created participant .*: name 'mcu_node', ROS domain %d -> %d, "
                             r"command line: namespace /robot1, remaps /cmd_vel -> "
                             r"/robot1/cmd_vel_safe, board's node /mcu_node -> node "
                             r"/robot1/mcu_node$" % (asked, ros_domain)), agent.output
    assert _log_lines(agent, r"created datawriter .*: topic /chatter \(DDS rt/chatter\) -> "
                             r"/robot1/chatter \(command line\), type std_msgs/msg/String .*, "
                             r"ROS domain %d, " % ros_domain)
    assert _log_lines(agent, r"created datareader .*: topic /cmd_vel \(DDS rt/cmd_vel\) -> "
                             r"/robot1/cmd_vel_safe \(command line\)")
    assert _log_lines(agent, r"created replier .*: service /add_two_ints -> /robot1/add_two_ints "
                             r"\(command line\), type test_msgs/srv/BasicTypes")
    assert not _log_lines(agent, "WARNING"), agent.output  # one board collides with no one

    # xrce-agent stats --json: ROS's names and domain, the board's beside them.
    row = next(c for c in snapshot["clients"] if c["key"] == "0badc0de")
    assert row["rule"] is None
    [participant] = row["participants"]
    assert {k: participant[k] for k in ("node", "board_node", "domain", "board_domain", "rule",
                                        "namespace", "remaps")} == {
        "node": "node /robot1/mcu_node", "board_node": "node /mcu_node", "domain": ros_domain,
        "board_domain": asked, "rule": None, "namespace": "/robot1",
        "remaps": ["/cmd_vel -> /robot1/cmd_vel_safe"]}
    names = sorted((e["kind"], e.get("topic") or e.get("service"),
                    e.get("board_topic") or e.get("board_service"), e["domain"])
                   for e in row["endpoints"])
    assert names == [("datareader", "/robot1/cmd_vel_safe", "/cmd_vel", ros_domain),
                     ("datawriter", "/robot1/chatter", "/chatter", ros_domain),
                     ("replier", "/robot1/add_two_ints", "/add_two_ints", ros_domain)]

    # /diagnostics: the same, as key-value pairs of the board's status.
    values = {kv.key: kv.value for kv in diagnosed()[-1].values}
    assert values["rule"] == "command line" and values["namespace"] == "/robot1"
    assert values["domain"] == str(ros_domain)
    assert values["remaps"] == "/cmd_vel -> /robot1/cmd_vel_safe"
    assert values["nodes"] == "/robot1/mcu_node (domain %d; board's /mcu_node, domain %d)" % (
        ros_domain, asked)
    assert "/robot1/cmd_vel_safe (board's /cmd_vel) std_msgs/msg/String from_ros" in \
        values["endpoints"], values["endpoints"]


def test_two_boards_given_one_service_are_one_warning_naming_both(ros_domain):  # noqa: F811
    """Both boards ask for node ``mcu_node`` and service ``/add_two_ints``; the namespace makes
    both ``/robot1/...``: one warning for the node, one for the service, whatever the boards do
    after. A board that let go of the service is not named when a third board takes it."""
    with AgentProcess("udp4", "-m", "dds", *NAMING) as agent:
        boards = [_board(agent, key) for key in (0x0000A001, 0x0000B002, 0x0000C003)]
        try:
            first, second, third = boards
            nodes, servers = [], []
            for board, name in ((first, "mcu_node"), (second, "mcu_node"),
                                (third, "other_node")):
                nodes.append(board.create_participant(domain_id=ros_domain, name=name))
                if board is not third:
                    servers.append(board.create_service_server(nodes[-1], "/add_two_ints",
                                                               RawBasicTypes, lambda *_: None))
                assert board.run_until_all_status(5000), board.last_statuses
            # The second board's server again, and the first board's gone: no new warning for
            # the pair already told; the third board's server then collides with the second only.
            second.delete_entity(servers[1])
            second.create_service_server(nodes[1], "/add_two_ints", RawBasicTypes,
                                         lambda *_: None)
            assert second.run_until_all_status(5000), second.last_statuses
            first.delete_entity(servers[0])
            assert first.run_until_all_status(5000), first.last_statuses
            third.create_service_server(nodes[2], "/add_two_ints", RawBasicTypes, lambda *_: None)
            assert third.run_until_all_status(5000), third.last_statuses
            for board in boards:
                board.delete(attempts=2, timeout_ms=500)
        finally:
            for board in boards:
                board.close()
        assert agent.stop() == 0
    warnings = _log_lines(agent, "WARNING")
    service = [w for w in warnings if "service /robot1/add_two_ints" in w]
    assert len(service) == 2, warnings
    assert "client 0000a001 (command-line naming) and client 0000b002 (command-line naming)" \
        in service[0], service
    assert "client 0000b002 (command-line naming) and client 0000c003 (command-line naming)" \
        in service[1], service
    nodes = [w for w in warnings if "node /robot1/mcu_node" in w]
    assert len(nodes) == 1 and "client 0000a001" in nodes[0] and "client 0000b002" in nodes[0], \
        warnings
    assert len(warnings) == 3, warnings
