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


def test_rcl_global_names_stay_whatever_the_global_topics():
    for naming in (Naming("/robot1"), Naming("/robot1", global_names=["/map"])):
        assert naming.name("/parameter_events") == "/parameter_events"
        assert naming.name("/rosout") == "/rosout"
        assert naming.board_name("/parameter_events") == "/parameter_events"
    assert Naming("/r", [("rosout", "log")]).name("/rosout") == "/r/log"  # a remap still moves it


def test_names_translated_back():
    naming = Naming("/robot3", [("cmd_vel", "cmd_vel_safe"), ("/odom", "/shared/odom")])
    for board in ("/chatter", "/a/b/c", "/cmd_vel", "/odom", "/tf", "/clock", "/parameter_events",
                  "/mcu/feat_fw/get_parameters", "/fib/_action/send_goal"):
        assert naming.board_name(naming.name(board)) == board, board
    # No board name becomes these: they come back as they are, absolute.
    assert naming.board_name("/robot2/cmd_vel") == "/robot2/cmd_vel"  # another robot's
    assert naming.board_name("/robot3/cmd_vel") == "/robot3/cmd_vel"  # the remap's original
    assert naming.board_name("/robot3/tf") == "/robot3/tf"  # /tf is global: the board's is /tf
    assert naming.board_name("/robot30/x") == "/robot30/x"  # a prefix that is not the namespace
    assert naming.board_name("/chatter") == "/chatter"
    # Nodes: namespaces back without the agent's namespace, another one as it is.
    for board_namespace in ("/", "/mcu", "/a/b"):
        assert naming.board_node_namespace(naming.node_namespace(board_namespace)) == \
            board_namespace
    assert naming.board_node_namespace("/robot2") == "/robot2"
    assert naming.board_node_namespace("/robot30/x") == "/robot30/x"
    assert naming.ros_node("/tb3_params") == "/robot3/tb3_params"
    assert naming.ros_node("/mcu/feat_fw") == "/robot3/mcu/feat_fw"
    assert naming.board_node("/robot3/tb3_params") == "/tb3_params"
    assert naming.board_node("/robot3/mcu/feat_fw") == "/mcu/feat_fw"
    assert naming.board_node("/robot2/tb3_params") == "/robot2/tb3_params"
    assert naming.moves_nodes and not Naming(remaps=[("a", "b")]).moves_nodes


def test_remaps_alone_translated_back():
    naming = Naming(remaps=[("cmd_vel", "cmd_vel_safe")])
    assert naming.name("/cmd_vel") == "/cmd_vel_safe"  # absolute: not under the board's node
    assert naming.board_name("/cmd_vel_safe") == "/cmd_vel"
    assert naming.board_name("/cmd_vel") == "/cmd_vel"  # someone else's: no board name reaches it
    assert naming.board_name("/odom") == "/odom"
    assert naming.board_node_namespace("/mcu") == "/mcu" and naming.board_node("/n") == "/n"
    assert Naming().board_name("/x") == "/x" and Naming().ros_node("/n") == "/n"


def test_a_plain_dds_topic_moves_only_by_a_remap_naming_it():
    naming = Naming("/robot1", [("board_hello", "/HelloWorldTopic"), ("chatter", "talk")])
    assert naming.dds_name("HelloWorldTopic") == "HelloWorldTopic"  # no namespace for DDS
    assert naming.dds_name("board_hello") == "HelloWorldTopic"  # no leading slash in DDS
    assert naming.dds_name("/board_hello") == "/HelloWorldTopic"  # rclpy's form kept
    assert naming.dds_name("chatter") == "talk"
    assert naming.name("/chatter") == "/robot1/talk"  # the ROS topic of that name


def test_an_action_remap_moves_its_hidden_topics_and_services_and_back():
    naming = Naming("/robot1", [("fibonacci", "fib")])
    for part in ("_action/send_goal", "_action/get_result", "_action/feedback", "_action/status"):
        given = naming.name("/fibonacci/" + part)
        assert given == "/robot1/fib/" + part
        assert naming.board_name(given) == "/fibonacci/" + part
    assert naming.name("/other/_action/feedback") == "/robot1/other/_action/feedback"
