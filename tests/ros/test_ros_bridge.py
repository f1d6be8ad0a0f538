"""``xrce-agent -m dds`` end to end: our client, a real agent process and rclpy in the test.

Each test leases its own ROS domain (the client's participant asks for it, as micro-ROS does) with
localhost-only discovery, and stops every process it starts.
"""

import threading
import time

import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import String as RosString
from geometry_msgs.msg import Twist as RosTwist
from test_msgs.srv import BasicTypes

from agent_process import AgentProcess
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from xrce.client.session import Session
from xrce.msgs.geometry_msgs import Twist, Vector3
from xrce.msgs.std_msgs import String
from xrce.transports.udp import UdpTransport

BASIC_TYPES_REQUEST = "test_msgs::srv::dds_::BasicTypes_Request_"
BASIC_TYPES_RESPONSE = "test_msgs::srv::dds_::BasicTypes_Response_"


class RawBasicTypes:
    """test_msgs/srv/BasicTypes for the client: the test hands it bytes rclpy serialized."""

    TYPE_NAME_REQUEST = BASIC_TYPES_REQUEST
    TYPE_NAME_RESPONSE = BASIC_TYPES_RESPONSE
    Request = None
    Response = None


def body(ros_msg):
    return serialize_message(ros_msg)[4:]  # XRCE carries the CDR body without its encapsulation


def from_body(data, ros_type):
    return deserialize_message(b"\x00\x01\x00\x00" + bytes(data), ros_type)


@pytest.fixture
def dds_agent(ros_domain):  # noqa: F811
    with AgentProcess("udp4", "-m", "dds") as agent:
        yield agent


@pytest.fixture
def session(dds_agent):
    client = Session(UdpTransport("127.0.0.1", dds_agent.port), history=8)
    assert client.create(attempts=5, timeout_ms=1000)
    yield client
    client.delete(attempts=2, timeout_ms=500)
    client.close()


def spin_until(session, predicate, seconds=10.0):
    deadline = time.monotonic() + seconds
    while not predicate() and time.monotonic() < deadline:
        session.spin_once(20)
    return predicate()


def test_topics_both_ways_and_the_node_in_the_ros_graph(session, ros_peer, ros_domain):  # noqa: F811
    strings, twists, got = [], [], []
    reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    ros_peer.node.create_subscription(RosString, "/chatter", strings.append, reliable)
    best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    ros_peer.node.create_subscription(RosTwist, "/cmd_vel", twists.append, best_effort)
    ros_pub = ros_peer.node.create_publisher(RosString, "/from_ros", reliable)

    node = session.create_participant(domain_id=ros_domain, name="mcu_node")
    chatter = session.create_writer(node, "/chatter", String, reliable=True, depth=50)
    cmd_vel = session.create_writer(node, "/cmd_vel", Twist, reliable=False)
    session.create_reader(node, "/from_ros", String, got.append, reliable=True, depth=50)
    assert session.run_until_all_status(5000), session.last_statuses
    assert wait_until(lambda: ("mcu_node", "/") in ros_peer.node_names(), 10)
    assert wait_until(lambda: ros_peer.node.count_subscribers("/from_ros") >= 1
                      and ros_peer.node.count_publishers("/chatter") >= 1, 10)

    for i in range(5):
        session.write(chatter, String(data="hello %d" % i))
        assert session.run_until_confirm_delivery(2000)
    assert wait_until(lambda: len(strings) >= 5, 10)
    assert [m.data for m in strings[:5]] == ["hello %d" % i for i in range(5)]

    deadline = time.monotonic() + 10
    while not twists and time.monotonic() < deadline:  # best effort: resend until one arrives
        session.write(cmd_vel, Twist(linear=Vector3(x=0.5), angular=Vector3(z=-0.25)),
                      stream_id=session.best_effort)
        session.run_until_timeout(50)
    assert twists and twists[0].linear.x == 0.5 and twists[0].angular.z == -0.25

    for i in range(3):
        ros_pub.publish(RosString(data="from ros %d" % i))
    assert spin_until(session, lambda: len(got) >= 3)
    assert [m.data for m in got] == ["from ros %d" % i for i in range(3)]

    # 2 KB on the reliable stream: fragmented client → agent and agent → client.
    big = "".join(chr(ord("a") + i % 26) for i in range(2048))
    session.write(chatter, String(data=big))
    assert session.run_until_confirm_delivery(3000)
    assert wait_until(lambda: any(m.data == big for m in strings), 10)
    ros_pub.publish(RosString(data=big.upper()))
    assert spin_until(session, lambda: any(m.data == big.upper() for m in got))


def test_services_in_both_directions(session, ros_peer, ros_domain):  # noqa: F811
    # ROS client → service served by the XRCE client (replier).
    node = session.create_participant(domain_id=ros_domain, name="mcu_services")
    served = []

    def serve(identity, request_body):
        request = from_body(request_body, BasicTypes.Request)
        served.append(request.int32_value)
        response = BasicTypes.Response(int32_value=request.int32_value * 2, string_value="doubled")
        session.send_reply(replier, identity, body(response))

    replier = session.create_service_server(node, "/double_it", RawBasicTypes, serve)
    # XRCE client (requester) → service served by rclpy.
    replies = {}
    requester = session.create_service_client(
        node, "/add_one", RawBasicTypes, lambda request_id, reply: replies.__setitem__(request_id, reply))
    assert session.run_until_all_status(5000), session.last_statuses

    def add_one(request, response):
        response.int32_value = request.int32_value + 1
        return response

    ros_peer.node.create_service(BasicTypes, "/add_one", add_one)
    ros_client = ros_peer.node.create_client(BasicTypes, "/double_it")
    assert ros_client.wait_for_service(timeout_sec=10)

    future = ros_client.call_async(BasicTypes.Request(int32_value=21))
    assert spin_until(session, lambda: future.done())
    assert served == [21] and future.result().int32_value == 42 and future.result().string_value == "doubled"

    request_id = session.send_request(requester, body(BasicTypes.Request(int32_value=41)))
    assert request_id
    assert spin_until(session, lambda: request_id in replies, 15)
    assert from_body(replies[request_id], BasicTypes.Response).int32_value == 42


def test_sigint_destroys_every_ros_entity(ros_peer, ros_domain):  # noqa: F811
    agent = AgentProcess("udp4", "-m", "dds").__enter__()
    try:
        client = Session(UdpTransport("127.0.0.1", agent.port))
        assert client.create()
        node = client.create_participant(domain_id=ros_domain, name="short_lived")
        client.create_writer(node, "/short_lived_topic", String)
        assert client.run_until_all_status(5000)
        assert wait_until(lambda: ("short_lived", "/") in ros_peer.node_names(), 10)
        assert wait_until(lambda: ros_peer.node.count_publishers("/short_lived_topic") == 1, 10)
        assert agent.stop() == 0
        client.close()
    finally:
        agent.stop()
    assert wait_until(lambda: ("short_lived", "/") not in ros_peer.node_names()
                      and ros_peer.node.count_publishers("/short_lived_topic") == 0, 15)
