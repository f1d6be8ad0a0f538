"""Issue 53 item 1, end to end: ``xrce-agent --ros-args -r __ns:=/robot3 -r cmd_vel:=cmd_vel_safe
--domain D`` gives an unchanged board (our client over UDP, asking for another domain) the names
and the domain of robot 3, seen from rclpy in domain D; ``/tf`` stays global."""

import time

from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import String as RosString
from test_msgs.srv import BasicTypes

from agent_process import AgentProcess
from ros_helpers import DomainLease, ros_domain, ros_peer, wait_until  # noqa: F401
from test_ros_bridge import RawBasicTypes  # test_msgs/srv/BasicTypes as bytes
from xrce.client.session import Session
from xrce.msgs.std_msgs import String
from xrce.transports.udp import UdpTransport


def spin_until(session, predicate, seconds=10.0):
    deadline = time.monotonic() + seconds
    while not predicate() and time.monotonic() < deadline:
        session.spin_once(20)
    return predicate()


def test_namespace_remap_and_domain_given_by_the_agent(ros_peer, ros_domain):  # noqa: F811
    board_domain = DomainLease()  # what the board asks for: nobody else's, and never joined
    try:
        with AgentProcess("udp4", "-m", "dds", "--ros-args", "-r", "__ns:=/robot3",
                          "-r", "cmd_vel:=cmd_vel_safe", "--", "--domain", str(ros_domain)) as agent:
            session = Session(UdpTransport("127.0.0.1", agent.port), history=8)
            try:
                assert session.create(attempts=5, timeout_ms=1000)
                _exchange(session, ros_peer, board_domain.domain_id)
            finally:
                session.delete(attempts=2, timeout_ms=500)
                session.close()
    finally:
        board_domain.release()


def _exchange(session, ros_peer, board_domain):
    reliable = QoSProfile(depth=20, reliability=ReliabilityPolicy.RELIABLE)
    chatter, tf, unspaced, got = [], [], [], []
    ros_peer.node.create_subscription(RosString, "/robot3/chatter", chatter.append, reliable)
    ros_peer.node.create_subscription(RosString, "/chatter", unspaced.append, reliable)
    ros_peer.node.create_subscription(RosString, "/tf", tf.append, reliable)
    to_board = ros_peer.node.create_publisher(RosString, "/robot3/cmd_vel_safe", reliable)

    node = session.create_participant(domain_id=board_domain, name="mcu_node")
    writer = session.create_writer(node, "/chatter", String, reliable=True, depth=20)
    tf_writer = session.create_writer(node, "/tf", String, reliable=True, depth=20)
    session.create_reader(node, "/cmd_vel", String, got.append, reliable=True, depth=20)
    served = []

    def serve(identity, request_body):
        request = deserialize_message(b"\x00\x01\x00\x00" + bytes(request_body), BasicTypes.Request)
        served.append(request.int32_value)
        reply = BasicTypes.Response(int32_value=request.int32_value * 2)
        session.send_reply(replier, identity, serialize_message(reply)[4:])

    replier = session.create_service_server(node, "/double_it", RawBasicTypes, serve)
    assert session.run_until_all_status(5000), session.last_statuses

    # The node is robot 3's, in the agent's domain (the peer's), not in the one the board asked.
    assert wait_until(lambda: ("mcu_node", "/robot3") in ros_peer.node_names(), 10), \
        ros_peer.node_names()
    assert wait_until(lambda: ros_peer.node.count_publishers("/robot3/chatter") >= 1
                      and ros_peer.node.count_publishers("/tf") >= 1
                      and ros_peer.node.count_subscribers("/robot3/cmd_vel_safe") >= 1, 10)
    names = dict(ros_peer.node.get_topic_names_and_types())
    # (the peer's own subscription keeps /chatter in the graph: nobody publishes there)
    assert ros_peer.node.count_publishers("/chatter") == 0
    assert "/cmd_vel" not in names and "/robot3/cmd_vel" not in names
    assert "/robot3/tf" not in names

    for i in range(3):
        session.write(writer, String(data="state %d" % i))
        session.write(tf_writer, String(data="tf %d" % i))
        assert session.run_until_confirm_delivery(2000)
    assert wait_until(lambda: len(chatter) >= 3 and len(tf) >= 3, 10)
    assert [m.data for m in chatter[:3]] == ["state %d" % i for i in range(3)]
    assert [m.data for m in tf[:3]] == ["tf %d" % i for i in range(3)] and unspaced == []

    for i in range(3):
        to_board.publish(RosString(data="go %d" % i))
    assert spin_until(session, lambda: len(got) >= 3)
    assert [m.data for m in got] == ["go %d" % i for i in range(3)]

    client = ros_peer.node.create_client(BasicTypes, "/robot3/double_it")
    assert client.wait_for_service(timeout_sec=10)
    future = client.call_async(BasicTypes.Request(int32_value=21))
    assert spin_until(session, future.done)
    assert served == [21] and future.result().int32_value == 42
