"""micro-ROS' Graph as one board calls what is in it (xrce.agent.middleware.ros.graph.graph_for_board)."""

from xrce.agent.middleware.ros.graph import (PUBLISHER, SERVICE_SERVER, SUBSCRIBER,
                                             board_graph_reader, decode_graph, encode_graph,
                                             graph_for_board)
from xrce.agent.middleware.ros.naming import Naming

STRING = ("std_msgs/msg/String",)
GRAPH = [
    ("/robot1/mcu", "feat_fw", [(PUBLISHER, "/robot1/cmd_vel_safe", STRING),
                                (PUBLISHER, "/tf", ("tf2_msgs/msg/TFMessage",)),
                                (SUBSCRIBER, "/robot1/cmd_vel", STRING),
                                (SERVICE_SERVER, "/robot1/mcu/feat_fw/get_parameters",
                                 ("rcl_interfaces/srv/GetParameters",))]),
    ("/robot2", "feat_fw", [(PUBLISHER, "/robot2/chatter", STRING)]),
    ("/", "teleop", [(PUBLISHER, "/robot1/mcu/fib/_action/status",
                      ("action_msgs/msg/GoalStatusArray",))]),
]


def test_a_board_reads_its_own_names_and_others_as_they_are():
    naming = Naming("/robot1", [("cmd_vel", "cmd_vel_safe")])
    body = encode_graph(GRAPH)
    assert decode_graph(body) == [(ns, name, [tuple(e) for e in entities])
                                  for ns, name, entities in GRAPH]
    assert decode_graph(graph_for_board(body, naming)) == [
        ("/mcu", "feat_fw", [(PUBLISHER, "/cmd_vel", STRING),
                             (PUBLISHER, "/tf", ("tf2_msgs/msg/TFMessage",)),
                             # a ROS /robot1/cmd_vel is not the board's /cmd_vel (remapped away)
                             (SUBSCRIBER, "/robot1/cmd_vel", STRING),
                             (SERVICE_SERVER, "/mcu/feat_fw/get_parameters",
                              ("rcl_interfaces/srv/GetParameters",))]),
        ("/robot2", "feat_fw", [(PUBLISHER, "/robot2/chatter", STRING)]),
        ("/", "teleop", [(PUBLISHER, "/mcu/fib/_action/status",
                          ("action_msgs/msg/GoalStatusArray",))]),
    ]


def test_what_is_not_a_graph_is_delivered_as_it_came():
    got = []
    deliver = board_graph_reader(got.append, Naming("/robot1"))
    deliver(b"\xff\xff\xff\x7f")  # a count no body follows
    body = encode_graph(GRAPH)
    deliver(body)
    assert got[0] == b"\xff\xff\xff\x7f" and got[1] != body
    assert decode_graph(got[1])[0][0] == "/mcu"
