"""Issue 53 item 4, micro-ROS' graph: a board the agent gives a namespace and a remap
(``--ros-args -r __ns:=/robot1 -r mcu2/latched:=latched_out``) reads the Graph in its own names.

The graph firmware (``graph.jsonl.gz``, tests/golden/microros/README.md) replayed through a live
``xrce-agent -m dds``: rclpy sees the board's nodes, topics and services under the names the agent
gave (``/robot1/...``, the remapped ``/robot1/latched_out``), while the Graphs that reach the
board's own graph reader, read as rmw_microxrcedds reads them, list its nodes, topics and services
as the firmware created them; ROS names no board name becomes (another robot's) stay as they are,
and a ROS subscriber of ``/robot1/graph_probe`` is counted on the board's ``/graph_probe``.
"""

import pytest

from agent_process import AgentProcess
from microros_replay import BoardView, Capture, Replayer, UdpChannel, decode_graph
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from test_microros_graph import BOARD_NODES, _first_step, _graph_reader, _ros_types
from test_microros_replay import INTERFACES
from xrce.wire import constants as C

NAMING = ("--ros-args", "-r", "__ns:=/robot1", "-r", "mcu2/latched:=latched_out", "--")


@pytest.mark.timeout(180)
def test_board_reads_the_graph_in_its_own_names(ros_peer, ros_domain):  # noqa: F811
    capture = Capture("graph")
    reader = _graph_reader(capture)
    string = _ros_types()
    node = ros_peer.node
    node.create_subscription(string, "/robot1/graph_probe", lambda _m: None, 10)
    node.create_subscription(string, "/robot2/cmd_vel", lambda _m: None, 10)  # another robot's
    teardown = _first_step(capture, lambda data: data[4] == C.DELETE)

    def board_view():
        graphs = replay.answers.samples.get((0, reader), [])
        return BoardView(decode_graph(graphs[-1])) if graphs else None

    def board_sees_all():
        view = board_view()
        return view is not None and set(BOARD_NODES) <= set(view.nodes) and \
            "/mcu2/latched" in view.topics and "/robot2/cmd_vel" in view.topics and \
            view.counts[("subscriber", "/graph_probe")] == 1 and \
            "/mcu/feat_fw/get_parameters" in view.services

    def ros_sees_all():
        nodes = set(node.get_node_names_and_namespaces())
        topics = {name for name, _ in node.get_topic_names_and_types()}
        services = {name for name, _ in node.get_service_names_and_types()}
        return {("feat_fw", "/robot1/mcu"), ("feat_aux", "/robot1/mcu2"),
                ("microros_graph", "/robot1")} <= nodes and \
            {"/robot1/latched_out", "/robot1/big_out", "/parameter_events"} <= topics and \
            "/robot1/mcu/feat_fw/get_parameters" in services

    with AgentProcess("udp4", "-m", "dds", "-v", "0", "--interfaces", str(INTERFACES),
                      *NAMING) as agent:
        channel = UdpChannel(agent.port)
        try:
            replay = Replayer(capture, channel, domain_id=ros_domain)
            replay.run(until_step=teardown)
            assert wait_until(ros_sees_all, 20), (node.get_node_names_and_namespaces(),
                                                  node.get_topic_names_and_types())
            assert replay.wait(board_sees_all, 20), (reader, sorted(replay.answers.samples), board_view() and board_view().by_node)
            view = board_view()
            ros_topics = {name for name, _ in node.get_topic_names_and_types()}
        finally:
            channel.close()

    # In ROS: the names the agent gave, none of the board's own where they were moved.
    assert not {"/mcu2/latched", "/big_out", "/graph_probe", "/robot1/parameter_events"} & \
        ros_topics, sorted(ros_topics)
    # On the board: its own names, node by node, as the firmware created them.
    assert view.node_topics("/mcu2/feat_aux") == {
        ("publisher", "/mcu2/latched", ("std_msgs/msg/String",))}
    fw = {(kind, topic) for kind, topic, _ in view.node_topics("/mcu/feat_fw")}
    assert {("publisher", "/big_out"), ("publisher", "/graph_probe"),
            ("publisher", "/parameter_events"), ("subscriber", "/big_in")} <= fw, sorted(fw)
    assert {"/mcu/feat_fw/get_parameters", "/mcu/feat_fw/set_parameters"} <= set(view.services)
    # rcl_count_publishers("/graph_probe"): the board's one publisher; the ROS subscriber of
    # /robot1/graph_probe counted on the board's name.
    assert view.counts[("publisher", "/graph_probe")] == 1
    # Nothing of the agent's namespace is left in what the board reads; the ROS side's own
    # names, another robot's included, are there as ROS has them.
    names = set(view.nodes) | set(view.topics) | set(view.services)
    assert not [name for name in names if name.startswith("/robot1")], sorted(names)
    peer = "/" + node.get_name()
    assert peer in view.nodes and ("subscriber", "/robot2/cmd_vel", ("std_msgs/msg/String",)) \
        in view.node_topics(peer)
