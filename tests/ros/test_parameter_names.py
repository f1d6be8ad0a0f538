"""Issue 53 item 4, parameters: a board's parameter server (our client's
``xrce.client.parameters``, which writes events as rclc does) behind
``xrce-agent --ros-args -r __ns:=/robot1``.

``/parameter_events`` stays global, as rcl has it; a ROS parameter client (rclpy's
``AsyncParameterClient``, what ``ros2 param`` does) reaches the board's node as
``/robot1/tb3_params``; the events the board writes name it so in ROS (rclc writes the base name,
``tb3_params``, which would not tell robots apart); and the board, reading ``/parameter_events``,
sees the nodes of its namespace as it names them (``/robot1/tuner`` -> ``/tuner``), other nodes as
they are.
"""

import threading
import time

import pytest
from rcl_interfaces.msg import ParameterEvent as RosParameterEvent
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile, ReliabilityPolicy

from agent_process import AgentProcess
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from xrce.client.parameters import ParameterServer
from xrce.client.session import Session
from xrce.msgs.rcl_interfaces import ParameterEvent
from xrce.transports.udp import UdpTransport

RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


class Board:
    """The board's session spun on a thread of its own while the test waits on ROS."""

    def __init__(self, port: int, domain_id: int):
        self.session = Session(UdpTransport("127.0.0.1", port), history=8)
        assert self.session.create(attempts=5, timeout_ms=1000)
        node = self.session.create_participant(domain_id=domain_id, name="tb3_params")
        self.params = ParameterServer(self.session, node, "/tb3_params")
        self.params.declare("motor_kp", 120, min_value=0, max_value=1000)
        self.read = []
        self.session.create_reader(node, "/parameter_events", ParameterEvent,
                                   lambda event: self.read.append(event.node), depth=20)
        assert self.session.run_until_all_status(5000), self.session.last_statuses
        self.stopping = False
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        while not self.stopping:
            self.session.spin_once(20)

    def close(self):
        self.stopping = True
        self.thread.join(5)
        self.session.delete(attempts=2, timeout_ms=500)
        self.session.close()


def _wait(future, seconds=15.0):
    assert wait_until(future.done, seconds), "no answer from the board"
    return future.result()


@pytest.mark.timeout(120)
def test_parameters_of_a_namespaced_board(ros_peer, ros_domain):  # noqa: F811
    node = ros_peer.node
    events = []
    node.create_subscription(RosParameterEvent, "/parameter_events", events.append, RELIABLE)
    others = node.create_publisher(RosParameterEvent, "/parameter_events", RELIABLE)
    client = AsyncParameterClient(node, "/robot1/tb3_params")
    with AgentProcess("udp4", "-m", "dds", "-v", "0",
                      "--ros-args", "-r", "__ns:=/robot1", "--") as agent:
        board = Board(agent.port, ros_domain)
        try:
            assert client.wait_for_services(20), node.get_service_names_and_types()
            values = _wait(client.get_parameters(["motor_kp"])).values
            assert [v.integer_value for v in values] == [120]
            results = _wait(client.set_parameters([Parameter("motor_kp", value=150)])).results
            assert [r.successful for r in results] == [True]
            assert board.params["motor_kp"] == 150

            def changed():
                return [(e.node, p.name, p.value.integer_value) for e in events
                        for p in e.changed_parameters]
            assert wait_until(lambda: changed(), 10), [e.node for e in events]
            assert changed() == [("/robot1/tb3_params", "motor_kp", 150)]
            # Every event of the board names its node as ROS has it, none the board's way.
            board_events = [e.node for e in events if "tb3_params" in e.node]
            assert board_events and set(board_events) == {"/robot1/tb3_params"}, board_events
            topics = {name for name, _ in node.get_topic_names_and_types()}
            assert "/robot1/parameter_events" not in topics and "/parameter_events" in topics

            # What the board reads of /parameter_events: its namespace's nodes in its names.
            for name in ("/robot1/tuner", "/robot2/tb3_params", "/tuner_at_root"):
                others.publish(RosParameterEvent(node=name))
            assert wait_until(lambda: "/tuner_at_root" in board.read, 10), board.read
            time.sleep(0.2)  # (published in order: the first two came before the last)
            read = [name for name in board.read if "tuner" in name or "robot2" in name]
            assert read == ["/tuner", "/robot2/tb3_params", "/tuner_at_root"], board.read
        finally:
            board.close()
