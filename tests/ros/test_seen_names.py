"""Issue 53 item 3, "seen by the operator": an agent that names boards otherwise than they asked
(``--ros-args -r __ns:=/robot1 -r cmd_vel:=cmd_vel_safe``, ``--domain D``) shows the board's own
names beside the given ones and which naming gave them, in its ``-v 4`` lines, in ``xrce-agent
stats --json`` and on ``/diagnostics``; two boards given one service or one node name are one
WARNING each, naming both boards. Our client over UDP, a real agent process, real rclpy."""

import json
import logging
import re
import subprocess
import sys
import time

from rclpy.qos import QoSProfile, ReliabilityPolicy
from test_msgs.srv import BasicTypes

from agent_process import REPO, AgentProcess
from ros_helpers import DomainLease, ros_domain, ros_peer, wait_until  # noqa: F401
from test_ros_bridge import RawBasicTypes  # test_msgs/srv/BasicTypes as bytes
from xrce.agent.middleware import ClientOrigin, EndpointQosSpec, ServiceSpec
from xrce.agent.middleware.ros.collisions import NameClaims
from xrce.agent.middleware.ros.ros_middleware import RosMiddleware
from xrce.agent.middleware.ros.naming import Naming
from xrce.client.session import Session
from xrce.msgs.std_msgs import String
from xrce.transports.udp import UdpTransport

NAMING = ("--ros-args", "-r", "__ns:=/robot1", "-r", "cmd_vel:=cmd_vel_safe", "--")


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
                table = subprocess.run([sys.executable, "-m", "xrce.agent", "stats", "-p",
                                        str(_stats_port(agent)), "--once"], cwd=REPO,
                                       capture_output=True, text=True, timeout=30).stdout

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

    for text in ("/robot1/mcu_node (domain %d; board's /mcu_node, domain %d)" % (ros_domain, asked),
                 "naming", "command line", "/robot1/cmd_vel_safe (board's /cmd_vel)",
                 "/robot1/add_two_ints (board's /add_two_ints)"):
        assert text in table, table

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
    service = [w for w in warnings if "service /robot1/add_two_ints in ROS domain %d " % ros_domain
               in w]
    assert len(service) == 2, warnings
    assert "client 0000a001 (command-line naming) and client 0000b002 (command-line naming)" \
        in service[0], service
    assert "client 0000b002 (command-line naming) and client 0000c003 (command-line naming)" \
        in service[1], service
    nodes = [w for w in warnings if "node /robot1/mcu_node in ROS domain %d " % ros_domain in w]
    assert len(nodes) == 1 and "client 0000a001" in nodes[0] and "client 0000b002" in nodes[0], \
        warnings
    assert len(warnings) == 3, warnings


class TwoRobotRules:
    """A fleet (``RosMiddleware(fleet=...)``: ``assign(origin)`` -> (Naming, rule name)) whose
    two rules give two boards one namespace by mistake, the second naming the domain too (the
    one both boards ask for)."""

    def __init__(self, domain_id):
        self.rules = {bytes.fromhex("0000a001"): (Naming("/robot1"), "robot1"),
                      bytes.fromhex("0000b002"): (Naming("/robot1", domain=domain_id), "robot2")}

    def assign(self, origin):
        return self.rules[bytes(origin.client_key)]


async def test_fleet_rules_are_named_in_what_is_shown_and_warned(ros_domain, caplog):  # noqa: F811
    """The ROS middleware itself, with a fleet of two rules: ``given_names`` says which rule
    named each board, and the collision warning names both boards' rules."""
    middleware = RosMiddleware(fleet=TwoRobotRules(ros_domain))
    await middleware.start()
    try:
        qos = EndpointQosSpec(reliable=True, keep_last=True, depth=10, durability="volatile")
        service = ServiceSpec("/add_two_ints", RawBasicTypes.TYPE_NAME_REQUEST,
                              RawBasicTypes.TYPE_NAME_RESPONSE)
        with caplog.at_level(logging.WARNING, logger="xrce.agent.ros"):
            for board in ("0000a001", "0000b002"):
                key = int(board, 16)
                middleware.create_participant((key, 0x11), ros_domain, "mcu_node",
                                              ClientOrigin(bytes.fromhex(board)))
                middleware.create_replier((key, 0x18), (key, 0x11), service, qos,
                                          lambda *_: None)
        first = middleware.given_names((0xA001, 0x11))
        assert first == {"rule": "robot1", "node": "/robot1/mcu_node", "board_node": "/mcu_node",
                         "domain": ros_domain, "namespace": "/robot1", "remaps": []}
        assert middleware.given_names((0xB002, 0x11))["rule"] == "robot2"
        assert middleware.given_names((0xB002, 0x18)) == {"rule": "robot2",
                                                          "name": "/robot1/add_two_ints"}
        warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
        assert len(warnings) == 2, warnings
        assert all("client 0000a001 (rule robot1) and client 0000b002 (rule robot2)" in w
                   for w in warnings), warnings
        assert warnings[0].startswith("node /robot1/mcu_node in ROS domain %d " % ros_domain)
        assert warnings[1].startswith("service /robot1/add_two_ints in ROS domain %d "
                                      % ros_domain)
    finally:
        await middleware.close()


def test_one_name_in_two_domains_is_no_collision(caplog):
    """Robots given domains of their own may all serve ``/add_two_ints``; a board's own two
    servers of one name are its own business (ROS warns of those itself); released names are
    free again."""
    claims = NameClaims()
    with caplog.at_level(logging.WARNING, logger="xrce.agent.ros"):
        claims.claim("service", 1, "/add_two_ints", (0xA001, 0x18), (0xA001, 0x11), "robot1")
        claims.claim("service", 2, "/add_two_ints", (0xB002, 0x18), (0xB002, 0x11), "robot2")
        claims.claim("service", 1, "/add_two_ints", (0xA001, 0x28), (0xA001, 0x11), "robot1")
        claims.release((0xA001, 0x11))  # the participant: its servers go with it
        claims.claim("service", 1, "/add_two_ints", (0xC003, 0x18), (0xC003, 0x11), None)
    assert [r for r in caplog.records if r.levelno >= logging.WARNING] == []
    with caplog.at_level(logging.WARNING, logger="xrce.agent.ros"):
        claims.claim("service", 2, "/add_two_ints", (0xC003, 0x28), (0xC003, 0x11), None)
    assert [r.getMessage() for r in caplog.records] == [
        "service /add_two_ints in ROS domain 2 is served by two boards, client 0000b002 (rule "
        "robot2) and client 0000c003 (command-line naming): a caller reaches either one. A remap "
        "or fleet rule gives both the same name"]
