"""Action types from ``.action`` files: the generator's expansion (Goal, Result, Feedback, the
SendGoal/GetResult services and FeedbackMessage, as rosidl defines them) checked byte for byte
against rclpy's own serializer for test_msgs/action/Fibonacci, against rclpy's classes for
turtlebot3_msgs/action/Patrol once built, and the generator on a package of one's own."""

import os

import pytest
from rclpy.serialization import deserialize_message, serialize_message

from xrce.tools import msggen
from xrce.msgs import lookup
from xrce.msgs.test_msgs import Fibonacci


def _rclpy_fibonacci():
    from test_msgs.action import Fibonacci as RosFibonacci

    impl = RosFibonacci.Impl
    return {"Goal": RosFibonacci.Goal, "Result": RosFibonacci.Result, "Feedback": RosFibonacci.Feedback,
            "SendGoal_Request": impl.SendGoalService.Request,
            "SendGoal_Response": impl.SendGoalService.Response,
            "GetResult_Request": impl.GetResultService.Request,
            "GetResult_Response": impl.GetResultService.Response,
            "FeedbackMessage": impl.FeedbackMessage}


def _ours(part):
    descriptor, _, rest = part.partition("_")
    cls = getattr(Fibonacci, descriptor)
    return getattr(cls, rest) if rest else cls


def _filled(part):
    ours = _ours(part)()
    uuid = bytes(range(3, 19))
    if part == "Goal":
        ours.order = 7
    elif part in ("Result", "Feedback"):
        ours.sequence = [0, 1, 1, 2, 3, 5]
    elif part == "SendGoal_Request":
        ours.goal_id.uuid, ours.goal.order = uuid, 9
    elif part == "SendGoal_Response":
        ours.accepted, ours.stamp.sec, ours.stamp.nanosec = True, 1795727518, 123
    elif part == "GetResult_Request":
        ours.goal_id.uuid = uuid
    elif part == "GetResult_Response":
        ours.status, ours.result.sequence = 4, [0, 1, 1]
    else:
        ours.goal_id.uuid, ours.feedback.sequence = uuid, [0, 1]
    return ours


@pytest.mark.parametrize("part", sorted(_rclpy_fibonacci()))
def test_fibonacci_parts_match_rclpy(part):
    ros_class = _rclpy_fibonacci()[part]
    ours = _filled(part)
    data = ours.to_bytes()
    # XRCE carries the body without the 4-byte encapsulation header rclpy writes.
    ros_msg = deserialize_message(b"\x00\x01\x00\x00" + data, ros_class)
    # Compared after decoding: rclpy leaves garbage in CDR padding (after GetResult's int8 status).
    assert type(ours).from_bytes(serialize_message(ros_msg)[4:]).to_bytes() == data


def test_action_names_are_rosidl_s():
    assert Fibonacci.ROS_TYPE == "test_msgs/action/Fibonacci"
    assert Fibonacci.SendGoal.TYPE_NAME_REQUEST == "test_msgs::action::dds_::Fibonacci_SendGoal_Request_"
    assert Fibonacci.GetResult.TYPE_NAME_RESPONSE == "test_msgs::action::dds_::Fibonacci_GetResult_Response_"
    assert Fibonacci.FeedbackMessage.TYPE_NAME == "test_msgs::action::dds_::Fibonacci_FeedbackMessage_"
    assert lookup("test_msgs::action::dds_::Fibonacci_Goal_") is Fibonacci.Goal
    assert lookup("test_msgs/action/Fibonacci_FeedbackMessage") is Fibonacci.FeedbackMessage
    from xrce.msgs.test_msgs import Fibonacci_GetResult_Response

    assert Fibonacci_GetResult_Response is Fibonacci.GetResult.Response
    from xrce.msgs import test_msgs, turtlebot3_msgs

    assert test_msgs.SERVICES == {} and sorted(turtlebot3_msgs.SERVICES) == ["Dqn", "Goal", "Sound"]


def test_patrol_matches_the_built_turtlebot3_msgs():
    from xrce.agent import interfaces

    interfaces.build(names=["turtlebot3_msgs"])  # a cache hit after the first time
    try:
        from turtlebot3_msgs.action import Patrol as RosPatrol
    except ImportError:
        pytest.fail("turtlebot3_msgs did not build, so Patrol cannot be checked against rosidl")
    from xrce.msgs.turtlebot3_msgs import Patrol

    request = Patrol.SendGoal.Request()
    request.goal_id.uuid = bytes(range(16))
    request.goal.radius = 0.75
    ros_request = deserialize_message(b"\x00\x01\x00\x00" + request.to_bytes(),
                                      RosPatrol.Impl.SendGoalService.Request)
    assert ros_request.goal.radius == 0.75 and bytes(ros_request.goal_id.uuid) == bytes(range(16))
    feedback = RosPatrol.Impl.FeedbackMessage()
    feedback.feedback.left_time = 2.5
    assert Patrol.FeedbackMessage.from_bytes(serialize_message(feedback)[4:]).feedback.left_time == 2.5
    result = RosPatrol.Impl.GetResultService.Response()
    result.status, result.result.success = 6, True
    ours = Patrol.GetResult.Response.from_bytes(serialize_message(result)[4:])
    assert (ours.status, ours.result.success) == (6, True)


def test_generator_expands_an_action_of_any_package(tmp_path):
    pkg = tmp_path / "dock_msgs"
    (pkg / "action").mkdir(parents=True)
    (pkg / "action" / "Dock.action").write_text("int32 STATION=3\nint32 station\n---\nbool docked\n---\nfloat32 distance\n")
    out = tmp_path / "out"
    assert msggen.main([str(pkg), "-o", str(out)]) == 0  # UUID and Time: the shipped packages
    assert sorted(os.listdir(out / "dock_msgs")) == ["_Dock.py", "_Dock_Goal_constants.py", "__init__.py"]
    text = (out / "dock_msgs" / "_Dock.py").read_text()
    assert "'dock_msgs::action::dds_::Dock_SendGoal_Request_'" in text
    assert "(unique_identifier_msgs.UUID, Dock_Goal, )" in text
    assert "_SERVICE_CLASSES = ('Dock', )" in (out / "dock_msgs" / "__init__.py").read_text()


def test_generator_refuses_an_action_without_three_parts(tmp_path, capsys):
    pkg = tmp_path / "bad_msgs"
    (pkg / "action").mkdir(parents=True)
    (pkg / "action" / "Half.action").write_text("int32 a\n---\nbool b\n")
    assert msggen.main([str(pkg), "-o", str(tmp_path / "out")]) == 2
    assert "bad_msgs/action/Half.action: expected exactly two '---' separators" in capsys.readouterr().err
