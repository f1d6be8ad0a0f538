"""Two TurtleBot3s with the same firmware (xrce.examples.turtlebot3, our CPython build of it) behind
one agent with a fleet file matching their client keys: /robot1/cmd_vel drives robot 1 only,
/robot2/cmd_vel robot 2, each has its own /robotN/odom, and both publish on the one /tf."""

from geometry_msgs.msg import Twist as RosTwist
from nav_msgs.msg import Odometry as RosOdometry
from rclpy.qos import QoSProfile, ReliabilityPolicy

from agent_process import AgentProcess
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from test_turtlebot3 import RobotThread, drive, forward_twist, turtlebot3_msgs_types
from xrce.transports.udp import UdpTransport

RELIABLE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
KEYS = {1: bytes.fromhex("c0000001"), 2: bytes.fromhex("c0000002")}


def test_two_turtlebots_under_their_own_names_with_one_tf(tmp_path, ros_peer, ros_domain):  # noqa: F811
    _sensor_state, tf_message = turtlebot3_msgs_types()
    fleet = tmp_path / "fleet.toml"
    fleet.write_text("".join('[[board]]\nname = "tb3-%d"\nkey = "0x%s"\nnamespace = "/robot%d"\n\n'
                             % (n, key.hex(), n) for n, key in KEYS.items()))
    node = ros_peer.node
    tf, odom = [], {1: [], 2: []}
    node.create_subscription(tf_message, "/tf", tf.append, RELIABLE)
    for n in KEYS:
        node.create_subscription(RosOdometry, "/robot%d/odom" % n, odom[n].append, RELIABLE)
    robots = {}
    with AgentProcess("udp4", "-m", "dds", "--fleet", str(fleet)) as agent:
        try:
            for n, key in KEYS.items():
                robots[n] = RobotThread(UdpTransport("127.0.0.1", agent.port), ros_domain, True,
                                        key=key)
                robots[n].start()
            for robot in robots.values():
                assert robot.ready.wait(30) and robot.failed is None, robot.failed
            assert wait_until(lambda: {("turtlebot3_node", "/robot1"), ("turtlebot3_node", "/robot2")}
                              <= set(ros_peer.node_names()), 15), ros_peer.node_names()
            assert wait_until(lambda: node.count_subscribers("/robot1/cmd_vel") == 1
                              and node.count_subscribers("/robot2/cmd_vel") == 1
                              and node.count_publishers("/tf") == 2, 15)
            names = dict(node.get_topic_names_and_types())
            assert "/cmd_vel" not in names and "/robot1/tf" not in names
            assert wait_until(lambda: len(tf) >= 10 and all(len(o) >= 3 for o in odom.values()), 10)

            to_robot1 = node.create_publisher(RosTwist, "/robot1/cmd_vel", RELIABLE)
            assert wait_until(lambda: to_robot1.get_subscription_count() == 1, 10)
            drive(to_robot1, forward_twist(0.2), 1.0)
            assert wait_until(lambda: robots[1].robot.commands_received >= 20, 5)
            assert robots[2].robot.commands_received == 0
            assert robots[1].robot.x > 0.05 and robots[2].robot.x == 0.0
        finally:
            for robot in robots.values():
                robot.stop()
