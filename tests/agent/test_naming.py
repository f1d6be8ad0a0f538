"""The names the agent gives a board's ROS entities (xrce.agent.middleware.ros.naming)."""

import pytest

from xrce.agent.middleware.ros.naming import Naming, NamingError, parse_ros_args, split_ros_args


def test_no_flags_change_nothing():
    naming = Naming()
    assert not naming.changes_names and naming.domain_id(7) == 7
    for name in ("/chatter", "/tf", "/fmu/out/vehicle_status"):
        assert naming.name(name) == name
    assert naming.node_namespace("/") == "/" and naming.node_namespace("/ns") == "/ns"


def test_namespace_remaps_and_global_names():
    naming = Naming("/robot3", [("cmd_vel", "cmd_vel_safe"), ("/odom", "/shared/odom")], domain=4)
    assert naming.name("/chatter") == "/robot3/chatter"
    assert naming.name("/fmu/out/vehicle_status") == "/robot3/fmu/out/vehicle_status"
    assert naming.name("/cmd_vel") == "/robot3/cmd_vel_safe"  # relative TO: under the namespace
    assert naming.name("/odom") == "/shared/odom"  # absolute TO: as given
    assert [naming.name(n) for n in ("/tf", "/tf_static", "/clock")] == ["/tf", "/tf_static", "/clock"]
    assert naming.node_namespace("/") == "/robot3" and naming.node_namespace("/a/b") == "/robot3/a/b"
    assert naming.domain_id(0) == 4
    assert Naming("/r", global_names=["/map"]).name("/tf") == "/r/tf"


def test_ros_args_split_at_the_double_dash_or_the_end():
    assert split_ros_args(["udp4", "--ros-args", "-r", "a:=b", "--", "-r", "refs.xml"]) == \
        (["udp4", "-r", "refs.xml"], ["-r", "a:=b"])
    assert split_ros_args(["udp4", "-p", "1"]) == (["udp4", "-p", "1"], None)
    assert split_ros_args(["udp4", "--ros-args", "--remap", "x:=y"]) == (["udp4"], ["--remap", "x:=y"])
    assert parse_ros_args(["-r", "__ns:=/r3", "--remap=a:=/b"]) == ("/r3", [("a", "/b")])


@pytest.mark.parametrize("tokens", [["-r", "foo"], ["-r", "__ns:=rel"], ["-r", "n:a:=b"],
                                    ["--log-level", "debug"], ["-r", "a:="], ["-r", "a/:=b"]])
def test_bad_ros_args(tokens):
    with pytest.raises(NamingError):
        parse_ros_args(tokens)


def _cli(*extra):
    """What the command line makes of the naming options (``startup.make_naming``)."""
    from xrce.agent.cli.startup import make_naming
    from xrce.agent.cli.subcommands import build_parser
    from xrce.agent.middleware.ros.naming import split_ros_args

    argv, ros_args = split_ros_args(["udp4", "-p", "0", *extra])
    args = build_parser(argv).parse_args(argv)
    args.ros_args = ros_args
    return make_naming(args)


def test_command_line_naming():
    assert _cli() is None and _cli("--global-topics", "/map") is None  # nothing given: unchanged
    assert _cli("--namespace", "robot3").namespace == "/robot3"  # made absolute, as rcl does
    naming = _cli("--ros-args", "-r", "__ns:=/r3", "-r", "odom:=/odom", "--", "--domain", "9",
                  "--global-topics", "/map,/tf")
    assert (naming.namespace, naming.domain) == ("/r3", 9)
    assert [naming.name(n) for n in ("/map", "/tf", "/clock", "/odom")] == \
        ["/map", "/tf", "/r3/clock", "/odom"]
    assert _cli("--domain", "0").domain == 0 and _cli("--domain", "0").name("/a") == "/a"


def test_a_plain_dds_topic_moves_only_by_a_remap_naming_it():
    naming = Naming("/robot1", [("board_hello", "/HelloWorldTopic"), ("chatter", "talk")])
    assert naming.dds_name("HelloWorldTopic") == "HelloWorldTopic"  # no namespace for DDS
    assert naming.dds_name("board_hello") == "HelloWorldTopic"  # no leading slash in DDS
    assert naming.dds_name("/board_hello") == "/HelloWorldTopic"  # rclpy's form kept
    assert naming.dds_name("chatter") == "talk"
    assert naming.name("/chatter") == "/robot1/talk"  # the ROS topic of that name
