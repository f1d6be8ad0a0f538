"""``xrce-ros node list`` with ros2node's options and output."""

from __future__ import annotations

import sys

from xrce.tools.ros_cli.arguments import add_graph_arguments
from xrce.tools.ros_cli.graph import CliNode

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
