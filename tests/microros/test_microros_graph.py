"""micro-ROS' view of the ROS graph, and a ROS graph with nothing of the agent's own in it (-m dds).

A firmware built with rmw_microxrcedds ``RMW_UXRCE_GRAPH=ON`` reads the DDS topic
``ros_to_microros_graph`` (``micro_ros_msgs/msg/Graph``) and answers ``rcl_get_topic_names_and_types``,
``rcl_count_subscribers`` and ``rcl_get_node_names`` from it. ``graph.jsonl.gz``
(tests/golden/microros/README.md) is such a firmware against micro_ros_agent: replayed here
through a live ``xrce-agent -m dds``, every STATUS must be micro_ros_agent's and the Graphs that
reach the board's reader must mean what micro_ros_agent's meant (the board's nodes with their
topics and types, its services, the rclpy ``/graph_probe`` subscriber counted once), not the same
bytes. Beside it, what ROS graph tools see must be what they see with micro_ros_agent: the
board's nodes, topics and services, nothing internal; and a domain where no client asked for the
graph gets no Graph.
"""

import os

import pytest

from agent_process import AgentProcess
from microros_replay import BoardView, Capture, Replayer, UdpChannel, decode_graph
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from test_microros_replay import INTERFACES
from xrce.wire import constants as C

BOARD_NODES = ("/mcu/feat_fw", "/mcu2/feat_aux", "/microros_graph")


def _graph_reader(capture: Capture) -> int:
    """The object id of the firmware's DataReader on ros_to_microros_graph (an XML CREATE)."""
    from microros_replay import _submessages

    for _boot, data in capture.steps:
        if data[0] <= 0x80:
            continue
        for sub_id, _flags, body in _submessages(data, 4):
            if sub_id == C.CREATE and b"<data_reader>" in body and \
                    b"ros_to_microros_graph" in body:
                return (body[2] << 8) | body[3]
    raise AssertionError("the capture creates no graph reader")


def _action_objects(capture: Capture) -> set:
    """Request ids of the CREATEs whose object has an action type (``pkg::action::``) or names
    such an object, and of the DELETEs of those objects."""
    from microros_replay import _submessages

    typed, requests = set(), set()
    for _boot, data in capture.steps:
        if data[0] <= 0x80:
            continue
        for sub_id, _flags, body in _submessages(data, 4):
            if len(body) < 4 or sub_id not in (C.CREATE, C.DELETE):
                continue
            rid, object_id = (body[0] << 8) | body[1], bytes(body[2:4])
            if sub_id == C.DELETE:
                if object_id in typed:
                    requests.add(rid)
            elif b"::action::" in body or any(ref in bytes(body[4:]) for ref in typed):
                typed.add(object_id)
                requests.add(rid)
    return requests


def _richest(graphs) -> BoardView:
    """The Graph with the most entities: all of the board's up, the ROS side too."""
    return BoardView(max(graphs, key=lambda graph: sum(len(e) for _, _, e in graph)))


def _ros_types():
    from xrce.agent import interfaces

    interfaces.build(names=["micro_ros_msgs"])  # a cache hit after the first time
    from std_msgs.msg import String

    return String


def _action_types_bridged() -> bool:
    """Whether this agent bridges action types (issue #29 item 1, done apart from this one)."""
    from xrce.agent.middleware import MiddlewareError
    from xrce.agent.middleware.ros.raw_types import raw_message_type

    try:
        raw_message_type("action_msgs::msg::dds_::GoalStatusArray_")  # a msg: always bridged
        raw_message_type("test_msgs::action::dds_::Fibonacci_FeedbackMessage_")
    except MiddlewareError:
        return False
    return True


def _action_typed(types) -> bool:
    return any("/action/" in type_name for type_name in types)


def _without_actions(entities) -> set:
    """Entities without an action type (``pkg/action/...``), which only item 1 bridges."""
    return {entity for entity in entities if not _action_typed(entity[2])}


@pytest.mark.timeout(240)
def test_graph_capture_replayed_gets_micro_ros_agents_graph(ros_peer, ros_domain):  # noqa: F811
    capture = Capture("graph")
    reader = _graph_reader(capture)
    string = _ros_types()
    from rclpy.qos import qos_profile_sensor_data

    # The recording's rclpy side subscribed to the board's /graph_probe: the board counted 1.
    ros_peer.node.create_subscription(string, "/graph_probe", lambda _m: None,
                                      qos_profile_sensor_data)
    with AgentProcess("udp4", "-m", "dds", "-v", "0", "--interfaces", str(INTERFACES)) as agent:
        channel = UdpChannel(agent.port)
        try:
            replay = Replayer(capture, channel, domain_id=ros_domain)
            ours = replay.run(speed=1.0)
        finally:
            channel.close()

    # Every STATUS as micro_ros_agent answered it; the action entities' only where this agent
    # bridges action types (item 1 of the issue, its own branch and tests).
    requests = {(boot, rid) for boot, rid, _ in capture.requests()}
    theirs = capture.eprosima
    mismatched = {"0x%04X" % rid: (theirs.statuses[(boot, rid)], ours.statuses.get((boot, rid)))
                  for boot, rid in sorted(requests)
                  if ours.statuses.get((boot, rid)) != theirs.statuses[(boot, rid)]}
    # Every comparison in full once nothing differs, whatever the capability check says.
    actions = _action_types_bridged() or not mismatched
    assert ours.status_agent == theirs.status_agent
    if not actions:
        # Only the action server's entities may differ: those created with an action type and
        # the endpoints and deletes that refer to them.
        action_objects = _action_objects(capture)
        assert {int(rid, 16) for rid in mismatched} <= action_objects, \
            (sorted(mismatched), sorted(action_objects))
    else:
        assert not mismatched, "(object, status) micro_ros_agent vs ours: %r" % mismatched

    their_graphs = [decode_graph(body) for body in theirs.samples[(0, reader)]]
    our_graphs = [decode_graph(body) for body in ours.samples[(0, reader)]]
    assert their_graphs and our_graphs, (len(their_graphs), len(our_graphs))
    their_view, our_view = _richest(their_graphs), _richest(our_graphs)

    # The nodes: the board's three (its graph participant is a node, as micro_ros_agent has
    # it), the ROS side's, and nothing of the agent's own.
    peer = "/" + ros_peer.node.get_name()
    assert set(BOARD_NODES) <= set(their_view.nodes)
    assert set(our_view.nodes) == set(BOARD_NODES) | {peer}, our_view.nodes
    # The board's own topics with their types, node by node.
    for node in BOARD_NODES:
        expected, got = their_view.node_topics(node), our_view.node_topics(node)
        if not actions:
            expected, got = _without_actions(expected), _without_actions(got)
        assert got == expected, (node, sorted(expected ^ got))
    # rcl_count_subscribers("/graph_probe"): the one rclpy subscriber.
    assert their_view.counts[("subscriber", "/graph_probe")] == 1
    assert our_view.counts[("subscriber", "/graph_probe")] == 1
    assert our_view.counts[("publisher", "/graph_probe")] == 1
    # rcl_get_topic_names_and_types: the board's topics, and the ROS side's as rclpy sees them.
    peer_topics = {name for name, _ in ros_peer.node.get_publisher_names_and_types_by_node(
        ros_peer.node.get_name(), "/")} | {"/graph_probe"}
    board_topics = {entity for node in BOARD_NODES for _, entity, _ in their_view.by_node[node]
                    if entity in their_view.topics}
    if not actions:
        board_topics = {topic for topic in board_topics
                        if not _action_typed(their_view.topics[topic])}
    assert set(our_view.topics) == board_topics | peer_topics, sorted(our_view.topics)
    for topic in board_topics:
        assert our_view.topics[topic] == their_view.topics[topic], topic
    # The board's services (its parameter server's; the action server's where bridged), listed
    # under every node as micro_ros_agent lists them.
    their_services = {name for name in their_view.services if name.startswith("/mcu/")}
    our_services = {name for name in our_view.services if name.startswith("/mcu/")}
    if not actions:
        their_services = {name for name in their_services
                          if not _action_typed(their_view.services[name])}
    assert our_services == their_services, sorted(our_services ^ their_services)
    for entities in our_view.by_node.values():
        listed = {(kind, entity) for kind, entity, _ in entities if kind.startswith("service")}
        assert {("service server", name) for name in our_services} <= listed

    # The board's nodes leave its Graph as they are deleted (teardown), as with micro_ros_agent.
    assert not ({"/mcu2/feat_aux"} & set(BoardView(our_graphs[-1]).nodes)), \
        BoardView(our_graphs[-1]).nodes
    if not actions:
        pytest.xfail("actions are not bridged on this branch: the action server's entities were "
                     "left out of the comparison (%d STATUS differ: %s)"
                     % (len(mismatched), sorted(mismatched)))


def _first_step(capture: Capture, predicate) -> int:
    return next(i for i, (_b, data) in enumerate(capture.steps)
                if data[0] > 0x80 and len(data) > 4 and predicate(data))


def _ros_graph(node) -> tuple:
    """What rclpy's graph API lists, hidden names included: (topics, nodes, services)."""
    return ({name for name, _ in node.get_topic_names_and_types()},
            set(node.get_node_names_and_namespaces()),
            {name for name, _ in node.get_service_names_and_types()})


def _node_owned(node, nodes) -> tuple:
    """(topics, services) of ``nodes`` (name, namespace) by rclpy's per-node listings."""
    topics, services = set(), set()
    for name, namespace in nodes:
        for listing, into in ((node.get_publisher_names_and_types_by_node, topics),
                              (node.get_subscriber_names_and_types_by_node, topics),
                              (node.get_service_names_and_types_by_node, services),
                              (node.get_client_names_and_types_by_node, services)):
            into.update(entry for entry, _ in listing(name, namespace))
    return topics, services


@pytest.mark.timeout(240)
@pytest.mark.parametrize("diagnostics", (False, True))
def test_ros_graph_beside_a_board_shows_only_the_board(diagnostics, ros_peer,
                                                       ros_domain):  # noqa: F811
    """With the graph firmware up (two nodes, parameter server, graph reader), rclpy's graph API
    lists the board's nodes, topics and services and the test's own, nothing of the agent's: no
    node (its entities live on a board's node while there is one), not its wake topic, not the
    graph topic (DDS-level, as with eProsima's agents), no service. With /diagnostics on (the
    default), that topic, which the agent publishes on purpose, and the hidden node that
    publishes it (``_xrce_agent``, which ``ros2 node list`` leaves out) are the only additions."""
    capture = Capture("graph")
    _ros_types()
    teardown = _first_step(capture, lambda data: data[4] == C.DELETE)
    agent_topics = {"/diagnostics"} if diagnostics else set()
    agent_nodes = {("_xrce_agent", "/")} if diagnostics else set()
    options = () if diagnostics else ("--no-diagnostics",)
    with AgentProcess("udp4", "-m", "dds", "-v", "0", *options,
                      "--interfaces", str(INTERFACES)) as agent:
        channel = UdpChannel(agent.port)
        try:
            replay = Replayer(capture, channel, domain_id=ros_domain)
            replay.run(until_step=teardown)
            board = {("feat_fw", "/mcu"), ("feat_aux", "/mcu2"), ("microros_graph", "/")}
            own = (ros_peer.node.get_name(), "/")
            node = ros_peer.node

            def settled():
                topics, nodes, _services = _ros_graph(node)
                return board | {own} | agent_nodes <= nodes and "/mcu2/latched" in topics \
                    and "/mcu/feat_fw/get_parameters" in _ros_graph(node)[2]
            assert wait_until(settled, 20), _ros_graph(node)
            topics, nodes, services = _ros_graph(node)
            raw = {name for name, _ in node.get_topic_names_and_types(no_demangle=True)}
            board_topics, board_services = _node_owned(node, board)
            own_topics, own_services = _node_owned(node, [own])
            agents_topics, agents_services = _node_owned(node, agent_nodes)
        finally:
            channel.close()
    assert nodes == board | {own} | agent_nodes, sorted(nodes)
    assert all(name.startswith("_") for name, _ in agent_nodes)  # rclpy.node.HIDDEN_NODE_PREFIX
    assert agents_topics == agent_topics and not agents_services, (agents_topics, agents_services)
    assert topics == board_topics | own_topics | agent_topics, \
        sorted(topics - board_topics - own_topics)
    assert not agent_topics & board_topics  # not under a board's node: the board would list it
    assert services == board_services | own_services, \
        sorted(services - board_services - own_services)
    assert "/mcu/feat_fw/get_parameters" in services and "/mcu2/latched" in topics
    listed = (topics | services) - own_topics - own_services
    assert not [name for name in listed if "xrce" in name or "graph" in name
                and name != "/graph_probe"], sorted(listed)
    # They exist, at DDS level only: the graph topic (board reader, agent writer), and the wake
    # topic of the events executor (the single-threaded one is woken by a guard condition).
    assert "/ros_to_microros_graph" in raw
    if os.environ.get("XRCE_ROS_EXECUTOR", "events") == "events":
        assert any("/_xrce_agent/wake_" in name for name in raw), sorted(raw)


@pytest.mark.timeout(240)
def test_no_graph_where_no_client_asked(ros_peer, ros_domain):  # noqa: F811
    """A board without graph support (main capture) gets the agent to publish no Graph: no
    writer on the graph topic, nothing for a DDS-level reader of it; a graph firmware that then
    joins the same domain gets one at once (the check is not blind)."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    _ros_types()
    from micro_ros_msgs.msg import Graph

    graphs = []
    dds_level = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL,
                           avoid_ros_namespace_conventions=True)
    ros_peer.node.create_subscription(Graph, "ros_to_microros_graph", graphs.append, dds_level)

    def writers():
        return ros_peer.node.get_publishers_info_by_topic("/ros_to_microros_graph",
                                                          no_mangle=True)

    plain, graph = Capture("main"), Capture("graph")
    with AgentProcess("udp4", "-m", "dds", "-v", "0", "--interfaces", str(INTERFACES)) as agent:
        channels = [UdpChannel(agent.port), UdpChannel(agent.port)]
        try:
            Replayer(plain, channels[0], domain_id=ros_domain).run(
                until_step=_first_step(plain, lambda data: data[4] == C.WRITE_DATA))
            assert wait_until(lambda: ros_peer.node.count_publishers("/sensor_state") >= 1, 15)
            # Nothing to wait for but time: the agent's check period is 0.5 s.
            assert not wait_until(lambda: graphs or writers(), 3), (graphs, writers())

            reader = _graph_reader(graph)
            Replayer(graph, channels[1], domain_id=ros_domain).run(
                until_step=_first_step(graph, lambda data: data[4] == C.WRITE_DATA))
            assert reader and wait_until(lambda: len(writers()) == 1 and graphs, 15), \
                (writers(), len(graphs))
            names = {node.node_name for node in graphs[-1].nodes}
            assert {"feat_fw", "tb3_fw", ros_peer.node.get_name()} <= names, names
        finally:
            for channel in channels:
                channel.close()
