"""``xrce-ros param list | get | set`` with ros2param's options and output, through rclpy's own
parameter client."""

from __future__ import annotations

import re
import sys

from xrce.tools.ros_cli.arguments import CommandError, UsageError, add_graph_arguments
from xrce.tools.ros_cli.graph import CliNode, absolute_node_name, split_node_name

NAME = "param"
HELP = "Various param related sub-commands"
SERVICES_TIMEOUT_S = 5.0  # ros2param's wait for a node's parameter services
# How long a node whose endpoints are in the graph without parameter services is watched for them
# before it is taken to serve none.
NO_PARAMETERS_WAIT_S = 0.5
CALL_TIMEOUT_S = 5.0
CALL_ATTEMPTS = 3


def add_verbs(verbs):
    parser = verbs.add_parser("list", help="Output a list of available parameters")
    add_graph_arguments(parser)
    parser.add_argument("node_name", nargs="?", help="Name of the ROS node")
    parser.add_argument("--filter", help="Only parameters matching this regular expression")
    parser.add_argument("--include-hidden-nodes", action="store_true",
                        help="Consider hidden nodes as well")
    parser.add_argument("--param-prefixes", nargs="+", default=[],
                        help="Only list parameters with the provided prefixes")
    parser.add_argument("--param-type", action="store_true",
                        help="Print parameter types with parameter names")
    parser.set_defaults(run=list_parameters)

    parser = verbs.add_parser("get", help="Get parameter")
    add_graph_arguments(parser)
    parser.add_argument("node_name", help="Name of the ROS node")
    parser.add_argument("parameter_name", help="Name of the parameter")
    parser.add_argument("--include-hidden-nodes", action="store_true",
                        help="Consider hidden nodes as well")
    parser.add_argument("--hide-type", action="store_true", help="Hide the type information")
    parser.add_argument("--timeout", metavar="N", type=float, default=1.0,
                        help="Wait for N seconds until the node becomes available "
                             "(default %(default)s sec)")
    parser.set_defaults(run=get_parameter)

    parser = verbs.add_parser("set", help="Set parameter")
    add_graph_arguments(parser)
    parser.add_argument("node_name", help="Name of the ROS node")
    parser.add_argument("parameter_name", help="Name of the parameter")
    parser.add_argument("value", help="Value of the parameter (YAML: 7, 0.5, true, [1, 2], text)")
    parser.add_argument("--include-hidden-nodes", action="store_true",
                        help="Consider hidden nodes as well")
    parser.add_argument("--timeout", metavar="N", type=float, default=1.0,
                        help="Wait for N seconds until the node becomes available "
                             "(default %(default)s sec)")
    parser.set_defaults(run=set_parameter)


def _client(cli, node_name):
    from rclpy.parameter_client import AsyncParameterClient

    client = AsyncParameterClient(cli.node, node_name)
    if not cli.spin_until(client.services_are_ready, SERVICES_TIMEOUT_S):
        return None
    return client


def _serves_no_parameters(cli, node_name):
    """True when the graph shows the node's endpoints but no ``<node>/list_parameters`` service:
    a micro-ROS node without a parameter server, a node made with start_parameter_services=False.
    ros2param waits SERVICES_TIMEOUT_S on each such node; a node not in the graph yet with
    anything is waited for as there."""
    name, namespace = split_node_name(node_name)
    node = cli.node
    wanted = node_name + "/list_parameters"

    def has_service():
        return any(service == wanted
                   for service, _ in node.get_service_names_and_types_by_node(name, namespace))

    def has_endpoints():
        return bool(node.get_service_names_and_types_by_node(name, namespace)
                    or node.get_publisher_names_and_types_by_node(name, namespace)
                    or node.get_subscriber_names_and_types_by_node(name, namespace))

    if has_service() or not has_endpoints():
        return False
    # Discovery brings a node's endpoints one by one: give the service a moment to show up too.
    return not cli.spin_until(has_service, NO_PARAMETERS_WAIT_S)


def _answer(cli, node_name, call):
    """The response to ``call()`` (a parameter-service request, all of which are safe to repeat).
    A request sent while the node's server has not matched this client's response reader yet is
    answered into the void (the client calls the service ready before that side is matched):
    after CALL_TIMEOUT_S it is sent again, where ros2param would wait forever."""
    for _ in range(CALL_ATTEMPTS):
        future = call()
        if cli.spin_until_done(future, CALL_TIMEOUT_S):
            if future.result() is None:
                raise CommandError("Exception while calling service of node %s: %s"
                                   % (node_name, future.exception()))
            return future.result()
        future.cancel()
    raise CommandError("No answer from the parameter services of node %s" % node_name)


def _wait_for_node(cli, node_name, include_hidden, timeout_s):
    found = cli.spin_until(lambda: node_name in cli.node_full_names(include_hidden), timeout_s)
    if not found:
        raise CommandError("Node not found")


def _type_label(parameter_type):
    from rcl_interfaces.msg import ParameterType as T

    return {T.PARAMETER_BOOL: "boolean", T.PARAMETER_INTEGER: "integer",
            T.PARAMETER_DOUBLE: "double", T.PARAMETER_STRING: "string",
            T.PARAMETER_BYTE_ARRAY: "byte array", T.PARAMETER_BOOL_ARRAY: "boolean array",
            T.PARAMETER_INTEGER_ARRAY: "integer array", T.PARAMETER_DOUBLE_ARRAY: "double array",
            T.PARAMETER_STRING_ARRAY: "string array", T.PARAMETER_NOT_SET: "not set"
            }[parameter_type]


def list_parameters(args):
    try:
        pattern = re.compile(args.filter) if args.filter is not None else None
    except re.error as error:
        raise UsageError("--filter: %s" % error) from None
    with CliNode(spin_time=args.spin_time) as cli:
        # A name twice in the graph is listed once, as ros2param lists it (its answers by name).
        node_names = sorted(set(cli.node_full_names(args.include_hidden_nodes)))
        if args.node_name:
            wanted = absolute_node_name(args.node_name)
            if wanted not in node_names:
                raise CommandError("Node not found")
            node_names = [wanted]
        for node_name in node_names:
            client = None if _serves_no_parameters(cli, node_name) else _client(cli, node_name)
            if client is None:
                print("Wait for service timed out waiting for parameter services for node %s"
                      % node_name)
                continue
            try:
                listed = _answer(cli, node_name,
                                 lambda: client.list_parameters(prefixes=args.param_prefixes))
            except CommandError as error:
                print(error, file=sys.stderr)
                continue
            names = sorted(listed.result.names)
            if pattern is not None:
                names = [name for name in names if pattern.match(name)]
            if not args.node_name and names:
                print("%s:" % node_name)
            types = {}
            if args.param_type and names:
                described = _answer(cli, node_name, lambda: client.describe_parameters(names))
                types = {d.name: _type_label(d.type) for d in described.descriptors}
            for name in names:
                print("  %s (type: %s)" % (name, types[name]) if args.param_type else "  %s" % name)


def _value_line(value):
    """ros2param get's label and value for a ParameterValue."""
    from rcl_interfaces.msg import ParameterType as T

    kinds = {
        T.PARAMETER_BOOL: ("Boolean value is:", lambda v: v.bool_value),
        T.PARAMETER_INTEGER: ("Integer value is:", lambda v: v.integer_value),
        T.PARAMETER_DOUBLE: ("Double value is:", lambda v: v.double_value),
        T.PARAMETER_STRING: ("String value is:", lambda v: v.string_value),
        T.PARAMETER_BYTE_ARRAY: ("Byte values are:", lambda v: v.byte_array_value),
        T.PARAMETER_BOOL_ARRAY: ("Boolean values are:", lambda v: v.bool_array_value),
        T.PARAMETER_INTEGER_ARRAY: ("Integer values are:",
                                    lambda v: v.integer_array_value.tolist()),
        T.PARAMETER_DOUBLE_ARRAY: ("Double values are:", lambda v: v.double_array_value.tolist()),
        T.PARAMETER_STRING_ARRAY: ("String values are:", lambda v: v.string_array_value),
        T.PARAMETER_NOT_SET: ("Parameter not set.", lambda v: None),
    }
    if value.type not in kinds:
        raise CommandError("Unknown parameter type '%s'" % value.type)
    label, read = kinds[value.type]
    return label, read(value)


def get_parameter(args):
    node_name = absolute_node_name(args.node_name)
    with CliNode(spin_time=args.spin_time) as cli:
        _wait_for_node(cli, node_name, args.include_hidden_nodes, args.timeout)
        client = _client(cli, node_name)
        if client is None:
            raise CommandError("Wait for service timed out waiting for parameter services for "
                               "node %s" % node_name)
        response = _answer(cli, node_name,
                           lambda: client.get_parameters([args.parameter_name]))
    if not response.values:
        raise CommandError("Parameter not set")
    label, value = _value_line(response.values[0])
    if args.hide_type:
        print(value)
    elif value is None:
        print(label)
    else:
        print(label, value)


def set_parameter(args):
    from rcl_interfaces.msg import Parameter
    from rclpy.parameter import get_parameter_value

    node_name = absolute_node_name(args.node_name)
    parameter = Parameter(name=args.parameter_name,
                          value=get_parameter_value(string_value=args.value))
    with CliNode(spin_time=args.spin_time) as cli:
        _wait_for_node(cli, node_name, args.include_hidden_nodes, args.timeout)
        client = _client(cli, node_name)
        if client is None:
            raise CommandError("Wait for service timed out waiting for parameter services for "
                               "node %s" % node_name)
        response = _answer(cli, node_name, lambda: client.set_parameters([parameter]))
    result = response.results[0]
    if result.successful:
        print("Set parameter successful" + (": " + result.reason if result.reason else ""))
        return 0
    # ros2param prints this on stderr and still exits 0; a script needs to see the refusal.
    print("Setting parameter failed" + (": " + result.reason if result.reason else ""),
          file=sys.stderr)
    return 1
