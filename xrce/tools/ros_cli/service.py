"""``xrce-ros service list | call`` with ros2service's options and output."""

from __future__ import annotations

import time

from xrce.tools.ros_cli.arguments import (CommandError, UsageError, add_graph_arguments,
                                          positive_float)
from xrce.tools.ros_cli.graph import NODE_NAME_PREFIX, CliNode, checked_name
from xrce.tools.ros_cli.messages import interface_class, parse_yaml_values, set_message_fields

NAME = "service"
HELP = "Various service related sub-commands"


def add_verbs(verbs):
    parser = verbs.add_parser("list", help="Output a list of available services")
    add_graph_arguments(parser)
    parser.add_argument("-t", "--show-types", action="store_true",
                        help="Additionally show the service type")
    parser.add_argument("-c", "--count-services", action="store_true",
                        help="Only display the number of services discovered")
    parser.add_argument("--include-hidden-services", action="store_true",
                        help="Consider hidden services as well")
    parser.set_defaults(run=list_services)

    parser = verbs.add_parser("call", help="Call a service")
    parser.add_argument("service_name",
                        help="Name of the ROS service to call to (e.g. '/add_two_ints')")
    parser.add_argument("service_type",
                        help="Type of the ROS service (e.g. 'std_srvs/srv/Empty')")
    parser.add_argument("values", nargs="?", default="{}",
                        help="Values to fill the service request with in YAML format "
                             "(e.g. '{a: 1, b: 2}')")
    parser.add_argument("-r", "--rate", metavar="N", type=positive_float,
                        help="Repeat the call at a specific rate in Hz")
    parser.set_defaults(run=call)


def list_services(args):
    with CliNode(spin_time=args.spin_time) as cli:
        services = cli.service_names_and_types(args.include_hidden_services)
    if args.count_services:
        print(len(services))
    else:
        for name, types in services:
            print("%s [%s]" % (name, ", ".join(types)) if args.show_types else name)


def call(args):
    checked_name(args.service_name, is_service=True)
    service_class = interface_class(args.service_type, "srv")
    request = service_class.Request()
    try:
        set_message_fields(request, parse_yaml_values(args.values))
    except UsageError:
        raise
    except Exception as error:
        raise UsageError("Failed to populate field: %s" % error) from None
    package = args.service_type.split("/")[0]
    name = "%s_requester_%s_%s" % (NODE_NAME_PREFIX, package, service_class.__name__)
    period_s = 1.0 / args.rate if args.rate else None
    with CliNode(name=name) as cli:
        client = cli.node.create_client(service_class, args.service_name)
        if not client.service_is_ready():
            print("waiting for service to become available...")
            cli.spin_until(client.service_is_ready)
        while True:
            print("requester: making request: %r\n" % request)
            started = time.monotonic()
            future = client.call_async(request)
            cli.spin_until_done(future)
            if future.exception() is not None:
                raise CommandError("Exception while calling service: %r" % future.exception())
            print("response:\n%r\n" % future.result())
            if period_s is None:
                return
            cli.spin_for(max(0.0, started + period_s - time.monotonic()))
