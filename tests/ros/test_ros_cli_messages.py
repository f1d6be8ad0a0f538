"""``xrce-ros``'s YAML, which stands in for rosidl_runtime_py (not in the PyPI wheels): messages print
as ``ros2 topic echo`` prints them and YAML fills them as ``ros2 topic pub`` reads it. The expected
texts are ros2's for these messages: fields in definition order, block style, nested messages
indented, sequences as ``- item`` lines at the key's indentation, a cut sequence ending in
``- '...'`` and a cut string in ``...``, ``--no-arr`` summaries as ``<sequence type: T, length:
N>``."""

import pytest
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseArray, Twist
from nav_msgs.msg import Odometry
from std_msgs.msg import Header, String
from test_msgs.msg import BoundedSequences, UnboundedSequences

from xrce.tools.ros_cli.arguments import UsageError
from xrce.tools.ros_cli.messages import (build_command, interface_class, missing_type_reason, message_to_yaml, parse_yaml_values,
                                         set_message_fields)


def test_nested_messages_print_as_ros2_topic_echo():
    twist = Twist()
    twist.linear.x = 0.5
    twist.angular.z = -0.25
    assert message_to_yaml(twist) == (
        "linear:\n  x: 0.5\n  y: 0.0\n  z: 0.0\nangular:\n  x: 0.0\n  y: 0.0\n  z: -0.25\n")
    header = Header(frame_id="odom", stamp=Time(sec=3, nanosec=7))
    assert message_to_yaml(header) == "stamp:\n  sec: 3\n  nanosec: 7\nframe_id: odom\n"


def test_sequences_cut_and_summarised_as_ros2_does():
    msg = UnboundedSequences(int32_values=[0, 1, 2, 3, 4], string_values=["abcdefgh"],
                             byte_values=[b"a", b"b"])
    text = message_to_yaml(msg, truncate_length=3)
    assert "int32_values:\n- 0\n- 1\n- 2\n- '...'\n" in text
    assert "string_values:\n- abc...\n" in text
    assert "byte_values:\n- a\n- b\n" in text
    assert "bool_values: []\n" in text
    text = message_to_yaml(msg, no_arr=True)
    assert "int32_values: '<sequence type: int32, length: 5>'\n" in text
    assert "basic_types_values: '<sequence type: test_msgs/msg/BasicTypes, length: 0>'\n" in text
    bounded = message_to_yaml(BoundedSequences(), no_arr=True)
    assert "bool_values: '<sequence type: boolean[3], length: 0>'\n" in bounded
    covariance = message_to_yaml(Odometry(), no_arr=True)
    assert "\n  covariance: '<array type: double[36]>'\n" in covariance
    assert message_to_yaml(String(data="hello"), no_str=True) == "data: '<string length: <5>>'\n"
    assert message_to_yaml(String(data="x" * 200), truncate_length=128) == (
        "data: " + "x" * 128 + "...\n")
    assert message_to_yaml(Twist(), flow_style=True) == (
        "{linear: {x: 0.0, y: 0.0, z: 0.0}, angular: {x: 0.0, y: 0.0, z: 0.0}}\n")


def test_yaml_fills_messages_as_ros2_topic_pub_reads_it():
    twist = Twist()
    set_message_fields(twist, parse_yaml_values("{linear: {x: 1}, angular: {z: -0.5}}"))
    assert twist.linear.x == 1.0 and isinstance(twist.linear.x, float) and twist.angular.z == -0.5
    poses = PoseArray()
    set_message_fields(poses, parse_yaml_values(
        "{header: {frame_id: map}, poses: [{position: {x: 1.5}}, {orientation: {w: 1}}]}"))
    assert poses.header.frame_id == "map" and len(poses.poses) == 2
    assert poses.poses[0].position.x == 1.5 and poses.poses[1].orientation.w == 1.0
    seq = UnboundedSequences()
    set_message_fields(seq, {"int32_values": [1, 2, 3]})
    assert list(seq.int32_values) == [1, 2, 3]
    # 'auto' and 'now' (ros2 topic pub): stamped at each publish through the setters returned.
    odom = Odometry()
    setters = set_message_fields(odom, parse_yaml_values("{header: auto, child_frame_id: base}"),
                                 expand_header_auto=True, expand_time_now=True)
    header = Header()
    stamp_setters = set_message_fields(header, {"stamp": "now"}, expand_time_now=True)
    for setter in setters + stamp_setters:
        setter(Time(sec=42, nanosec=1))
    assert odom.header.stamp.sec == 42 and odom.child_frame_id == "base"
    assert header.stamp.sec == 42 and header.stamp.nanosec == 1


def test_values_that_do_not_fit_are_refused():
    with pytest.raises(AttributeError):
        set_message_fields(String(), {"nope": 1})
    with pytest.raises(TypeError):
        set_message_fields(Twist(), {"linear": 5})
    with pytest.raises(UsageError, match="dictionary"):
        parse_yaml_values("[1, 2]")
    with pytest.raises(UsageError, match="not YAML"):
        parse_yaml_values("{a: [}")
    assert parse_yaml_values("") == {}


def test_type_names_as_ros2_takes_them():
    assert interface_class("std_msgs/msg/String", "msg") is String
    assert interface_class("std_msgs/String", "msg") is String
    assert interface_class("test_msgs/srv/BasicTypes", "srv").__name__ == "BasicTypes"
    assert interface_class("test_msgs/action/Fibonacci", "action").__name__ == "Fibonacci"
    for name, kind in (("std_msgs/msg/Nope", "msg"), ("std_msgs/msg/String", "srv"),
                       ("os/msg/path", "msg"), ("a/b/c/d", "msg"), ("../x", "msg")):
        with pytest.raises(UsageError, match="invalid"):
            interface_class(name, kind)


def test_a_type_this_venv_lacks_is_named_with_the_build_that_fixes_it():
    with pytest.raises(UsageError) as missing:
        interface_class("wheel_msgs/msg/WheelTicks", "msg")
    assert str(missing.value) == (
        "The passed message type is invalid: 'wheel_msgs/msg/WheelTicks' (package wheel_msgs is not built "
        "for this venv: `xrce-agent build-interfaces DIR --package wheel_msgs`, DIR holding wheel_msgs/ "
        "with its package.xml)")
    with pytest.raises(UsageError, match="xrce-agent build-interfaces DIR --package wheel_msgs"):
        interface_class("wheel_msgs/srv/SetLed", "srv")
    # A package xrce ships the files of (xrce/ros_interfaces/) builds with no directory given.
    assert build_command("turtlebot3_msgs") == "xrce-agent build-interfaces --package turtlebot3_msgs"
    assert build_command("wheel_msgs") == "xrce-agent build-interfaces DIR --package wheel_msgs"
    # A package of the ROS in use that lacks the type: no build of ours fixes that.
    assert missing_type_reason("std_msgs", "Nope") == "no such type in this venv"


def test_yaml_words_read_as_booleans_get_the_hint_to_quote_them():
    from test_msgs.srv import BasicTypes

    # {led: 1, on: true}: YAML 1.1 reads the key `on` as True.
    with pytest.raises(AttributeError) as key:
        set_message_fields(BasicTypes.Request(), parse_yaml_values("{int32_value: 1, on: true}"))
    assert str(key.value) == ("'BasicTypes_Request' object has no attribute 'True': YAML reads an unquoted "
                              "on as the boolean True: quote the key ('\"on\": ...')")
    with pytest.raises(AttributeError, match="unquoted off as the boolean False"):
        set_message_fields(BasicTypes.Request(), parse_yaml_values("{off: 1}"))
    # A string field given yes: it would be sent as "True".
    with pytest.raises(TypeError, match="field 'string_value' wants str, and YAML read the unquoted value "
                                        "as the boolean True .*quote it"):
        set_message_fields(BasicTypes.Request(), parse_yaml_values("{string_value: yes}"))
    with pytest.raises(TypeError, match="field 'data' wants str"):
        set_message_fields(String(), parse_yaml_values("{data: on}"))
    # Quoted, each is what was written; numbers into strings and booleans into numbers stay as ros2 takes them.
    request = BasicTypes.Request()
    set_message_fields(request, parse_yaml_values('{string_value: "yes"}'))
    assert request.string_value == "yes"
    set_message_fields(request, parse_yaml_values("{string_value: 12, int32_value: true, bool_value: 1}"))
    assert (request.string_value, request.int32_value, request.bool_value) == ("12", 1, True)
