"""The simulated TurtleBot3 with ``ros_extras=True`` (xrce/examples/turtlebot3_extras.py): its
calibration parameters and the /patrol action (turtlebot3_msgs/action/Patrol) reached by rclpy's
parameter client and ActionClient through a live ``xrce-agent -m dds``."""

import threading

import pytest

from agent_process import AgentProcess
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from test_turtlebot3 import turtlebot3_msgs_types
from xrce.examples.turtlebot3 import TurtleBot3
from xrce.transports.udp import UdpTransport


def _done(future, seconds=30.0):
    assert wait_until(future.done, seconds), "no answer in %.0f s" % seconds
    return future.result()


@pytest.mark.timeout(180)
def test_parameters_and_patrol_reach_the_robot(ros_peer, ros_domain):  # noqa: F811
    if turtlebot3_msgs_types() is None:
        pytest.fail("turtlebot3_msgs cannot be built here: the Patrol action needs it")
    from action_msgs.msg import GoalStatus
    from rclpy.action import ActionClient
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient
    from turtlebot3_msgs.action import Patrol

    with AgentProcess("udp4", "-m", "dds") as agent:
        robot = TurtleBot3(UdpTransport("127.0.0.1", agent.port), domain_id=ros_domain,
                           log=lambda text: None, ros_extras=True)
        assert robot.connect(timeout_ms=500, attempts=20) is not None and robot.setup()
        assert robot.failed_topics == [], robot.failed_topics
        halt = threading.Event()
        runner = threading.Thread(target=robot.run, kwargs={"should_stop": halt.is_set}, daemon=True)
        runner.start()
        try:
            params = AsyncParameterClient(ros_peer.node, "/turtlebot3_node")
            assert params.wait_for_services(30)
            names = _done(params.list_parameters()).result.names
            assert sorted(names) == ["failsafe_ms", "model", "wheel_radius"]
            results = _done(params.set_parameters([
                Parameter("wheel_radius", value=0.05), Parameter("wheel_radius", value=0.5),
                Parameter("model", value="waffle"), Parameter("failsafe_ms", value=800)])).results
            assert [(r.successful, r.reason) for r in results] == [
                (True, ""), (False, "Value out of range"), (False, "Read only parameter"), (True, "")]
            assert robot.extras.wheel_radius == 0.05 and robot.failsafe_ms == 800

            patrol = ActionClient(ros_peer.node, Patrol, "/patrol")
            assert patrol.wait_for_server(30)
            feedback = []
            handle = _done(patrol.send_goal_async(Patrol.Goal(radius=0.05),
                                                  feedback_callback=lambda m: feedback.append(m.feedback.left_time)))
            assert handle.accepted
            outcome = _done(handle.get_result_async())
            assert outcome.status == GoalStatus.STATUS_SUCCEEDED and outcome.result.success
            # One lap of 2π·0.05 m at 0.1 m/s: ~3.1 s, feedback every second counting down.
            assert feedback and all(0.0 < left < 3.2 for left in feedback) and feedback == sorted(feedback, reverse=True)
            assert abs(robot.x) < 0.05 and abs(robot.y) < 0.05  # back where it started
            assert not _done(patrol.send_goal_async(Patrol.Goal(radius=5.0))).accepted  # too wide
            handle = _done(patrol.send_goal_async(Patrol.Goal(radius=1.0)))
            assert wait_until(lambda: robot.linear > 0, 10)
            _done(handle.cancel_goal_async())
            outcome = _done(handle.get_result_async())
            assert outcome.status == GoalStatus.STATUS_CANCELED and not outcome.result.success
            assert robot.linear == 0.0
        finally:
            halt.set()
            runner.join(10)
            robot.shutdown()
