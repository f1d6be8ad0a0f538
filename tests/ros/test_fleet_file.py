"""Issue 53 item 2 end to end: ``xrce-agent --fleet FILE`` gives boards with IDENTICAL firmware
(our client over UDP: node ``mcu_node``, ``/chatter`` and ``/tf`` out, ``/cmd_vel`` in, a
``/double_it`` service) their own names by client key: robot 1 and robot 2 in the agent's domain
under /robot1 and /robot2, each hearing only its own cmd_vel and answering only its own service,
one /tf for both; robot 3's rule puts it in another domain, seen from an rclpy peer there.
``xrce-ros node list`` shows the given names. SIGHUP reads the file again for boards created
afterwards; a broken file keeps the rules loaded before."""

import os
import signal
import subprocess
import sys
import threading
import time

from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import String as RosString
from test_msgs.srv import BasicTypes

from agent_process import REPO, AgentProcess
from ros_helpers import DomainLease, RosPeer, ros_domain, ros_peer, wait_until  # noqa: F401
from test_ros_bridge import RawBasicTypes  # test_msgs/srv/BasicTypes as bytes
from xrce.client.session import Session
from xrce.msgs.std_msgs import String
from xrce.transports.udp import UdpTransport

KEYS = {1: "a1000001", 2: "a1000002", 3: "a1000003"}
RELIABLE = QoSProfile(depth=20, reliability=ReliabilityPolicy.RELIABLE)


class Board(threading.Thread):
    """One firmware image, the same for every robot but for its client key; in its own thread
    (a session is single-threaded, as on an MCU)."""

    def __init__(self, port, key_hex, domain_id):
        super().__init__(daemon=True, name="fleet-board-" + key_hex)
        self.session = Session(UdpTransport("127.0.0.1", port), key=bytes.fromhex(key_hex),
                               history=8)
        self.domain_id = domain_id
        self.cmd_vel, self.requests = [], []
        self.ready = threading.Event()
        self.failed = None
        self._halt = threading.Event()

    def run(self):
        session = self.session
        try:
            if not session.create(attempts=5, timeout_ms=1000):
                self.failed = "no agent"
                return
            node = session.create_participant(domain_id=self.domain_id, name="mcu_node")
            chatter = session.create_writer(node, "/chatter", String, reliable=True, depth=20)
            tf = session.create_writer(node, "/tf", String, reliable=True, depth=20)
            session.create_reader(node, "/cmd_vel", String, self.cmd_vel.append, reliable=True,
                                  depth=20)

            def serve(identity, body):
                request = deserialize_message(b"\x00\x01\x00\x00" + bytes(body),
                                              BasicTypes.Request)
                self.requests.append(request.int32_value)
                reply = BasicTypes.Response(int32_value=request.int32_value * 2)
                session.send_reply(replier, identity, serialize_message(reply)[4:])

            replier = session.create_service_server(node, "/double_it", RawBasicTypes, serve)
            if not session.run_until_all_status(10000):
                self.failed = "entities refused: %r" % (session.last_statuses,)
                return
            self.ready.set()
            next_at = time.monotonic()
            while not self._halt.is_set():
                if time.monotonic() >= next_at:
                    session.write(chatter, String(data="state"))
                    session.write(tf, String(data="tf"))
                    next_at += 0.1
                session.spin_once(10)
        except Exception as exc:  # reported by the test, which would otherwise only time out
            self.failed = repr(exc)
            raise
        finally:
            self.ready.set()

    def stop(self):
        self._halt.set()
        self.join(10)
        try:
            self.session.delete(attempts=2, timeout_ms=500)
        finally:
            self.session.close()


def write_fleet(path, text):
    path.write_text(text)
    return str(path)


def xrce_ros(domain_id, *args, timeout_s=60):
    script = os.path.join(os.path.dirname(sys.executable), "xrce-ros")
    command = [script] if os.path.exists(script) else [sys.executable, "-m", "xrce.tools.ros_cli"]
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env.pop("ROS_LOCALHOST_ONLY", None)
    done = subprocess.run(command + list(args), env=env, cwd=REPO, text=True,
                          capture_output=True, timeout=timeout_s)
    return done.stdout.splitlines()


def call(ros_peer, service, value):
    client = ros_peer.node.create_client(BasicTypes, service)
    try:
        assert client.wait_for_service(timeout_sec=10), service
        future = client.call_async(BasicTypes.Request(int32_value=value))
        assert wait_until(future.done, 10), service
        return future.result().int32_value
    finally:
        ros_peer.node.destroy_client(client)


def test_identical_boards_get_their_robots_names_and_domain(tmp_path, ros_peer, ros_domain):  # noqa: F811
    other = DomainLease()  # robot 3's, given by its rule
    other_peer = boards = None
    fleet = write_fleet(tmp_path / "fleet.toml", """
[[board]]
name = "robot1"
key = "0x%s"
namespace = "/robot1"

[[board]]
name = "robot2"
key = "0x%s"
namespace = "/robot2"

[[board]]
name = "robot3"
key = "0x%s"
namespace = "/robot3"
domain = %d
""" % (KEYS[1], KEYS[2], KEYS[3], other.domain_id))
    try:
        other_peer = RosPeer(other.domain_id)
        tf, robot3_chatter = [], []
        ros_peer.node.create_subscription(RosString, "/tf", tf.append, RELIABLE)
        other_peer.node.create_subscription(RosString, "/robot3/chatter", robot3_chatter.append,
                                            RELIABLE)
        with AgentProcess("udp4", "-m", "dds", "--fleet", fleet) as agent:
            # every board asks for the agent's (the peer's) domain; robot 3's rule moves it
            boards = {n: Board(agent.port, KEYS[n], ros_domain) for n in KEYS}
            for board in boards.values():
                board.start()
            for board in boards.values():
                assert board.ready.wait(30) and board.failed is None, board.failed
            _check_separate_robots(ros_peer, boards, tf)

            # Robot 3 is in its rule's domain, and nowhere in the agent's.
            assert wait_until(lambda: ("mcu_node", "/robot3") in other_peer.node_names(), 15), \
                other_peer.node_names()
            assert wait_until(lambda: len(robot3_chatter) >= 3, 10)
            assert ("mcu_node", "/robot3") not in ros_peer.node_names()
            assert ros_peer.node.count_publishers("/robot3/chatter") == 0
            assert other_peer.node.count_publishers("/tf") == 1  # robot 3's own /tf there

            # ros2 node list, as an operator sees the fleet
            expected = ["/robot1/mcu_node", "/robot2/mcu_node", "/xrce_test_peer"]
            for _ in range(3):
                listed = xrce_ros(ros_domain, "node", "list")
                if listed == expected:
                    break
            assert listed == expected
            assert "/robot3/mcu_node" in xrce_ros(other.domain_id, "node", "list")
            log = "".join(agent.output)
            assert "fleet file %s: 3 rules: robot1, robot2, robot3" % fleet in log, log
    finally:
        for board in (boards or {}).values():
            board.stop()
        if other_peer is not None:
            other_peer.close()
        other.release()


def _check_separate_robots(ros_peer, boards, tf):
    node = ros_peer.node
    assert wait_until(lambda: {("mcu_node", "/robot1"), ("mcu_node", "/robot2")}
                      <= set(ros_peer.node_names()), 15), ros_peer.node_names()
    assert wait_until(lambda: node.count_subscribers("/robot1/cmd_vel") == 1
                      and node.count_subscribers("/robot2/cmd_vel") == 1
                      and node.count_publishers("/robot1/chatter") == 1
                      and node.count_publishers("/robot2/chatter") == 1
                      and node.count_publishers("/tf") == 2, 15)
    names = dict(node.get_topic_names_and_types())
    assert "/cmd_vel" not in names and "/chatter" not in names
    assert "/robot1/tf" not in names and "/robot2/tf" not in names
    assert wait_until(lambda: len(tf) >= 6, 10)  # one /tf tree for the whole fleet

    # A command for robot 1 reaches robot 1 only, and robot 2's its own.
    to_robot = {n: node.create_publisher(RosString, "/robot%d/cmd_vel" % n, RELIABLE)
                for n in (1, 2)}
    assert wait_until(lambda: all(p.get_subscription_count() == 1 for p in to_robot.values()), 10)
    for i in range(3):
        to_robot[1].publish(RosString(data="go %d" % i))
    assert wait_until(lambda: len(boards[1].cmd_vel) >= 3, 10)
    to_robot[2].publish(RosString(data="stop"))
    assert wait_until(lambda: len(boards[2].cmd_vel) >= 1, 10)
    time.sleep(0.3)  # time for a wrongly routed sample to arrive too
    assert [m.data for m in boards[1].cmd_vel] == ["go 0", "go 1", "go 2"]
    assert [m.data for m in boards[2].cmd_vel] == ["stop"]
    assert boards[3].cmd_vel == []

    # Each robot's service is answered by that robot alone.
    assert call(ros_peer, "/robot1/double_it", 21) == 42
    assert call(ros_peer, "/robot2/double_it", 5) == 10
    assert boards[1].requests == [21] and boards[2].requests == [5] and boards[3].requests == []


# ----------------------------------------------------------------------------- SIGHUP

def _participant(port, key_hex, domain_id):
    """A board that creates its node and nothing else; its session stays open (the caller
    deletes it)."""
    session = Session(UdpTransport("127.0.0.1", port), key=bytes.fromhex(key_hex))
    assert session.create(attempts=5, timeout_ms=1000)
    session.create_participant(domain_id=domain_id, name="mcu_node")
    assert session.run_until_all_status(10000), session.last_statuses
    return session


def _wait_log(agent, text, timeout_s=10):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        agent.drain()
        if text in "".join(agent.output):
            return True
        time.sleep(0.05)
    return False


def test_sighup_reloads_for_boards_created_afterwards(tmp_path, ros_peer, ros_domain):  # noqa: F811
    rules = '[[board]]\nname = "%s"\nkey = [%s]\nnamespace = "%s"\n'
    path = tmp_path / "fleet.toml"
    fleet = write_fleet(path, rules % ("first", '"%s"' % KEYS[1], "/robot1"))
    sessions = []
    try:
        with AgentProcess("udp4", "-m", "dds", "--fleet", fleet) as agent:
            sessions.append(_participant(agent.port, KEYS[1], ros_domain))
            assert wait_until(lambda: ("mcu_node", "/robot1") in ros_peer.node_names(), 15)

            write_fleet(path, rules % ("second", '"%s", "%s"' % (KEYS[2], KEYS[3]), "/robot9"))
            agent.proc.send_signal(signal.SIGHUP)
            assert _wait_log(agent, "fleet file %s: 1 rule: second" % fleet), agent.output
            sessions.append(_participant(agent.port, KEYS[2], ros_domain))
            assert wait_until(lambda: ("mcu_node", "/robot9") in ros_peer.node_names(), 15)
            # the board there before keeps its names
            assert ("mcu_node", "/robot1") in ros_peer.node_names()

            path.write_text(rules % ("third", '"%s"' % KEYS[3], "robot5"))  # not absolute
            agent.proc.send_signal(signal.SIGHUP)
            assert _wait_log(agent, "the 1 rule(s) loaded before stay"), agent.output
            warning = [line for line in "".join(agent.output).splitlines()
                       if "loaded before stay" in line]
            assert len(warning) == 1 and "WARNING" in warning[0] and \
                "fleet file %s line 4: key 'namespace'" % fleet in warning[0], warning
            # a board after the bad reload: the rules of the last good file
            sessions.append(_participant(agent.port, KEYS[3], ros_domain))
            assert wait_until(lambda: [n for n in ros_peer.node_names() if n[0] == "mcu_node"]
                              .count(("mcu_node", "/robot9")) == 2, 15), ros_peer.node_names()
            assert ("mcu_node", "/robot5") not in ros_peer.node_names()
            assert agent.proc.poll() is None  # SIGHUP did not stop the agent
    finally:
        for session in sessions:
            session.delete(attempts=2, timeout_ms=500)
            session.close()
