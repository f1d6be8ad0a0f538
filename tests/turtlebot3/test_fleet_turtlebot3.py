"""Two TurtleBot3s with the same firmware (xrce.examples.turtlebot3, our CPython build of it) behind
one agent with a fleet file matching their client keys: /robot1/cmd_vel drives robot 1 only,
/robot2/cmd_vel robot 2, each has its own /robotN/odom, and both publish on the one /tf; each
robot's parameters and action answer under its own namespace only."""

import threading

import pytest
from geometry_msgs.msg import Twist as RosTwist
from nav_msgs.msg import Odometry as RosOdometry
from rclpy.qos import QoSProfile, ReliabilityPolicy

from agent_process import AgentProcess
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from test_turtlebot3 import RobotThread, drive, forward_twist, turtlebot3_msgs_types
from xrce.examples.turtlebot3 import TurtleBot3
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


def _done(future, seconds=30.0):
    assert wait_until(future.done, seconds), "no answer in %.0f s" % seconds
    return future.result()


def test_two_turtlebots_parameters_and_actions_answer_only_their_own_robot(tmp_path, ros_peer,  # noqa: F811
                                                                           ros_domain):  # noqa: F811
    """The same firmware with its parameters and /patrol action (ros_extras): /robot1's
    parameter services and action reach robot 1 only, /robot2's robot 2; robot 1's rule also
    remaps the action (patrol:=lap), which moves its hidden topics and services with it."""
    if turtlebot3_msgs_types() is None:
        pytest.fail("turtlebot3_msgs cannot be built here: the Patrol action needs it")
    from action_msgs.msg import GoalStatus
    from rclpy.action import ActionClient
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient
    from turtlebot3_msgs.action import Patrol

    fleet = tmp_path / "fleet.toml"
    fleet.write_text('[[board]]\nname = "tb3-1"\nkey = "0x%s"\nnamespace = "/robot1"\n'
                     'remaps = { patrol = "lap" }\n\n'
                     '[[board]]\nname = "tb3-2"\nkey = "0x%s"\nnamespace = "/robot2"\n'
                     % (KEYS[1].hex(), KEYS[2].hex()))
    node = ros_peer.node
    robots, runners, halt = {}, [], threading.Event()
    with AgentProcess("udp4", "-m", "dds", "--fleet", str(fleet)) as agent:
        try:
            for n, key in KEYS.items():
                robot = robots[n] = TurtleBot3(UdpTransport("127.0.0.1", agent.port),
                                               domain_id=ros_domain, key=key,
                                               log=lambda text: None, ros_extras=True)
                assert robot.connect(timeout_ms=500, attempts=20) is not None and robot.setup()
                assert robot.failed_topics == [], robot.failed_topics
                runner = threading.Thread(target=robot.run, kwargs={"should_stop": halt.is_set},
                                          daemon=True)
                runner.start()
                runners.append(runner)
            params = {n: AsyncParameterClient(node, "/robot%d/turtlebot3_node" % n) for n in KEYS}
            assert all(p.wait_for_services(30) for p in params.values())
            assert not AsyncParameterClient(node, "/turtlebot3_node").wait_for_services(0.5)
            results = _done(params[1].set_parameters([Parameter("wheel_radius", value=0.05)]))
            assert [r.successful for r in results.results] == [True]
            assert robots[1].extras.wheel_radius == 0.05
            assert robots[2].extras.wheel_radius != 0.05
            got = _done(params[2].get_parameters(["wheel_radius"])).values
            assert [v.double_value for v in got] == [robots[2].extras.wheel_radius]

            lap = ActionClient(node, Patrol, "/robot1/lap")
            patrol = ActionClient(node, Patrol, "/robot2/patrol")
            assert lap.wait_for_server(30) and patrol.wait_for_server(30)
            names = dict(node.get_topic_names_and_types())
            assert "/robot1/lap/_action/feedback" in names, sorted(names)
            assert not any(name.startswith(("/robot1/patrol", "/patrol")) for name in names)
            handle = _done(patrol.send_goal_async(Patrol.Goal(radius=1.0)))
            assert handle.accepted
            assert wait_until(lambda: robots[2].linear > 0, 10)
            assert robots[1].linear == 0.0
            _done(handle.cancel_goal_async())
            assert _done(handle.get_result_async()).status == GoalStatus.STATUS_CANCELED
            handle = _done(lap.send_goal_async(Patrol.Goal(radius=1.0)))
            assert handle.accepted and wait_until(lambda: robots[1].linear > 0, 10)
            _done(handle.cancel_goal_async())
            assert _done(handle.get_result_async()).status == GoalStatus.STATUS_CANCELED
        finally:
            halt.set()
            for runner in runners:
                runner.join(10)
            for robot in robots.values():
                robot.shutdown()
