"""``xrce-ros node list | info`` with ros2node's options and output."""

from __future__ import annotations

import sys

from xrce.tools.ros_cli.arguments import CommandError, add_graph_arguments
from xrce.tools.ros_cli.graph import CliNode, is_hidden_name, split_node_name

NAME = "node"
HELP = "Various node related sub-commands"


def add_verbs(verbs):
    parser = verbs.add_parser("list", help="Output a list of available nodes")
    add_graph_arguments(parser)
    parser.add_argument("-a", "--all", action="store_true",
                        help="Display all nodes even hidden ones")
    parser.add_argument("-c", "--count-nodes", action="store_true",
                        help="Only display the number of nodes discovered")
    parser.set_defaults(run=list_nodes)

    parser = verbs.add_parser("info", help="Output information about a node")
    add_graph_arguments(parser)
    parser.add_argument("node_name", help="Fully qualified node name to request information")
    parser.add_argument("--include-hidden", action="store_true",
                        help="Display hidden topics, services, and actions as well")
    parser.set_defaults(run=node_info)


def list_nodes(args):
    with CliNode(spin_time=args.spin_time) as cli:
        names = sorted(cli.node_full_names(include_hidden=args.all))
    if args.count_nodes:
        print(len(names))
    elif names:
        if len(set(names)) < len(names):
            print("WARNING: Be aware that there are nodes in the graph that share an exact name, "
                  "which can have unintended side effects.", file=sys.stderr)
        print("\n".join(names))


def node_info(args):
    """ros2node info: the node's endpoints by kind, each kind's names sorted by the graph and
    indented, hidden ones (a part starting with an underscore) left out unless asked for; an empty
    kind is a blank line, as ros2 prints it. The name is matched as typed, as there."""
    import rclpy.action

    with CliNode(spin_time=args.spin_time) as cli:
        count = cli.node_full_names(include_hidden=args.include_hidden).count(args.node_name)
        if not count:
            raise CommandError("Unable to find node '%s'" % args.node_name)
        name, namespace = split_node_name(args.node_name)
        node = cli.node
        kinds = [
            ("Subscribers", node.get_subscriber_names_and_types_by_node(name, namespace)),
            ("Publishers", node.get_publisher_names_and_types_by_node(name, namespace)),
            ("Service Servers", node.get_service_names_and_types_by_node(name, namespace)),
            ("Service Clients", node.get_client_names_and_types_by_node(name, namespace)),
            ("Action Servers",
             rclpy.action.get_action_server_names_and_types_by_node(node, name, namespace)),
            ("Action Clients",
             rclpy.action.get_action_client_names_and_types_by_node(node, name, namespace)),
        ]
    if count > 1:
        print('There are %d nodes in the graph with the exact name "%s". You are seeing '
              "information about only one of them." % (count, args.node_name), file=sys.stderr)
    print(args.node_name)
    for label, names_and_types in kinds:
        print("  %s:" % label)
        print("\n".join("    %s: %s" % (entry, ", ".join(types))
                        for entry, types in names_and_types
                        if args.include_hidden or not is_hidden_name(entry)))
