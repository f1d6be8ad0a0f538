"""``xrce-ros topic list | info | echo | hz | pub`` with ros2topic's options and output."""

from __future__ import annotations

import math
import sys
import time

from xrce.tools.ros_cli.arguments import (PROG, CommandError, UsageError, add_graph_arguments,
                                          add_qos_arguments, nonnegative_int, positive_float,
                                          positive_int, qos_from_arguments, qos_overridden)
from xrce.tools.ros_cli.graph import CliNode, checked_name
from xrce.tools.ros_cli.messages import (interface_class, message_to_yaml, missing_type_reason,
                                         parse_yaml_values, set_message_fields)

NAME = "topic"
HELP = "Various topic related sub-commands"
TRUNCATE_LENGTH = 128
HZ_WINDOW = 10000
PUB_WAIT_STEP_S = 0.1


def add_verbs(verbs):
    parser = verbs.add_parser("list", help="Output a list of available topics")
    add_graph_arguments(parser)
    parser.add_argument("-t", "--show-types", action="store_true",
                        help="Additionally show the topic type")
    parser.add_argument("-c", "--count-topics", action="store_true",
                        help="Only display the number of topics discovered")
    parser.add_argument("--include-hidden-topics", action="store_true",
                        help="Consider hidden topics as well")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="List full details about each topic")
    parser.set_defaults(run=list_topics)

    parser = verbs.add_parser("info", help="Print information about a topic")
    add_graph_arguments(parser)
    parser.add_argument("topic_name", help="Name of the ROS topic to get info (e.g. '/chatter')")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="Also print each publisher's and subscription's node, type, type "
                             "hash, GID and QoS profile")
    parser.set_defaults(run=info)

    parser = verbs.add_parser("echo", help="Output messages from a topic")
    add_graph_arguments(parser)
    parser.add_argument("topic_name", help="Name of the ROS topic to listen to (e.g. '/chatter')")
    parser.add_argument("message_type", nargs="?",
                        help="Type of the ROS message (e.g. 'std_msgs/msg/String')")
    add_qos_arguments(parser, "subscribe", "sensor_data")
    parser.add_argument("--field", help="Echo a selected field of a message ('.' for sub-fields)")
    parser.add_argument("-f", "--full-length", action="store_true",
                        help="Output all elements of arrays, bytes and strings")
    parser.add_argument("-l", "--truncate-length", type=nonnegative_int, default=TRUNCATE_LENGTH,
                        help="The length to truncate arrays, bytes and strings to "
                             "(default: %(default)s)")
    parser.add_argument("--no-arr", action="store_true", help="Don't print array fields")
    parser.add_argument("--no-str", action="store_true", help="Don't print string fields")
    parser.add_argument("--flow-style", action="store_true",
                        help="Print collections in the flow style")
    parser.add_argument("--once", action="store_true",
                        help="Print the first message received and then exit")
    parser.add_argument("--timeout", metavar="N", type=positive_float,
                        help="Set a timeout in seconds for waiting")
    parser.set_defaults(run=echo)

    parser = verbs.add_parser("hz", help="Print the average publishing rate to screen")
    add_graph_arguments(parser)
    parser.add_argument("topic_name", help="Name of the ROS topic to listen to (e.g. '/chatter')")
    parser.add_argument("-w", "--window", dest="window_size", metavar="WINDOW", type=positive_int,
                        default=HZ_WINDOW, help="window size, in # of messages, for calculating "
                                                "rate (default: %(default)s)")
    parser.add_argument("--wall-time", dest="use_wtime", action="store_true",
                        help="calculate the rate with the wall clock instead of ROS time")
    parser.set_defaults(run=hz)

    parser = verbs.add_parser("pub", help="Publish a message to a topic")
    parser.add_argument("topic_name", help="Name of the ROS topic to publish to (e.g. '/chatter')")
    parser.add_argument("message_type", help="Type of the ROS message (e.g. 'std_msgs/String')")
    parser.add_argument("values", nargs="?", default="{}",
                        help="Values to fill the message with in YAML format "
                             "(e.g. 'data: Hello World')")
    parser.add_argument("-r", "--rate", metavar="N", type=positive_float, default=1.0,
                        help="Publishing rate in Hz (default: 1)")
    parser.add_argument("-p", "--print", metavar="N", type=int, default=1,
                        help="Only print every N-th published message (default: 1)")
    times = parser.add_mutually_exclusive_group()
    times.add_argument("-1", "--once", action="store_true", help="Publish one message and exit")
    times.add_argument("-t", "--times", type=nonnegative_int, default=0,
                       help="Publish this number of times and then exit")
    parser.add_argument("-w", "--wait-matching-subscriptions", type=nonnegative_int,
                        help="Wait until finding this number of matching subscriptions "
                             "(default: 1 with --once/--times, otherwise 0)")
    parser.add_argument("--max-wait-time-secs", type=positive_float,
                        help="Longest wait for the matching subscriptions")
    parser.add_argument("--keep-alive", metavar="N", type=positive_float, default=0.1,
                        help="Keep the node alive for N seconds after the last message "
                             "(default: 0.1)")
    parser.add_argument("-n", "--node-name", help="Name of the created publishing node")
    add_qos_arguments(parser, "publish", "default")
    add_graph_arguments(parser)
    parser.set_defaults(run=pub)


# ----------------------------------------------------------------------------- list

def list_topics(args):
    with CliNode(spin_time=args.spin_time) as cli:
        topics = cli.topic_names_and_types(args.include_hidden_topics)
        counts = {name: (cli.node.count_publishers(name), cli.node.count_subscribers(name))
                  for name, _ in topics} if args.verbose else {}
    if args.count_topics:
        print(len(topics))
    elif args.verbose and topics:
        for index, (role, noun) in enumerate((("Published", "publisher"),
                                              ("Subscribed", "subscriber"))):
            lines = ["%s topics:" % role]
            for name, types in topics:
                count = counts[name][index]
                if count:
                    lines.append(" * %s [%s] %d %s%s" % (name, ", ".join(types), count, noun,
                                                         "s" if count > 1 else ""))
            print("\n".join(lines) + "\n")
    else:
        for name, types in topics:
            print("%s [%s]" % (name, ", ".join(types)) if args.show_types else name)


# ----------------------------------------------------------------------------- info

def info(args):
    """ros2topic info: the name is matched as typed (a relative one is unknown there too); with -v
    each endpoint as rclpy's TopicEndpointInfo prints itself, which is what ros2 prints, QoS
    included, and a blank line after every block."""
    with CliNode(spin_time=args.spin_time) as cli:
        types = dict(cli.topic_names_and_types(include_hidden=True)).get(args.topic_name)
        if types is None:
            raise CommandError("Unknown topic '%s'" % args.topic_name)
        node = cli.node
        publishers = node.get_publishers_info_by_topic(args.topic_name) if args.verbose else ()
        subscriptions = (node.get_subscriptions_info_by_topic(args.topic_name)
                         if args.verbose else ())
        counts = (node.count_publishers(args.topic_name), node.count_subscribers(args.topic_name))
    end = "\n\n" if args.verbose else "\n"
    print("Type: %s" % (types[0] if len(types) == 1 else types), end=end)
    for label, count, endpoints in (("Publisher", counts[0], publishers),
                                    ("Subscription", counts[1], subscriptions)):
        print("%s count: %d" % (label, count), end=end)
        for endpoint in endpoints:
            print(endpoint, end=end)
    if args.verbose:
        # ros2's lines as they are on stdout; what an INVALID hash of a type this venv lacks means,
        # and its fix, beside them.
        for type_name in types:
            try:
                interface_class(type_name, "msg")
            except UsageError:
                sys.stderr.write("%s: %s is not a type this venv has (%s); its endpoints carried by "
                                 "name show Topic type hash: INVALID\n"
                                 % (PROG, type_name, _missing_reason(type_name)))


# ----------------------------------------------------------------------------- echo

def _topic_class(cli, topic_name, wait_s=None):
    """The class of the one type ``topic_name`` has in the graph. As ros2topic's hz does (and echo
    here too: a board that is still connecting is the usual case, where ros2 echo gives up at
    once), waits for the topic after saying so once, ``wait_s`` at most (None: until Ctrl-C)."""
    full_name = checked_name(topic_name)

    def types_now():
        for name, types in cli.topic_names_and_types(include_hidden=True):
            if name == full_name:
                return types
        return None

    types = types_now()
    if types is None:
        print("WARNING: topic [%s] does not appear to be published yet" % topic_name)
        if not cli.spin_until(lambda: types_now() is not None, wait_s):
            raise CommandError("Could not determine the type for the passed topic")
        types = types_now()
    if len(types) > 1:
        raise CommandError("Cannot echo topic '%s', as it contains more than one type: [%s]"
                           % (topic_name, ", ".join(types)))
    try:
        return interface_class(types[0], "msg")
    except UsageError:
        raise CommandError("The message type '%s' is invalid (%s)" % (
            types[0], _missing_reason(types[0]))) from None


def _missing_reason(type_name):
    parts = type_name.split("/")
    return missing_type_reason(parts[0], parts[-1])


def _echo_qos(cli, args):
    """ros2topic echo's choice: the --qos-* options when given, else the sensor-data preset made
    reliable / transient-local when every publisher of the topic offers it."""
    from rclpy.qos import QoSDurabilityPolicy, QoSPresetProfiles, QoSReliabilityPolicy

    if qos_overridden(args):
        return qos_from_arguments(args)
    profile = QoSPresetProfiles.get_from_short_key(args.qos_profile)
    publishers = cli.node.get_publishers_info_by_topic(args.topic_name)
    if not publishers:
        return profile
    reliable = sum(p.qos_profile.reliability == QoSReliabilityPolicy.RELIABLE for p in publishers)
    if reliable == len(publishers):
        profile.reliability = QoSReliabilityPolicy.RELIABLE
    else:
        if reliable:
            print("Some, but not all, publishers are offering QoSReliabilityPolicy.RELIABLE. "
                  "Falling back to QoSReliabilityPolicy.BEST_EFFORT as it will connect to all "
                  "publishers")
        profile.reliability = QoSReliabilityPolicy.BEST_EFFORT
    lasting = sum(p.qos_profile.durability == QoSDurabilityPolicy.TRANSIENT_LOCAL
                  for p in publishers)
    if lasting == len(publishers):
        profile.durability = QoSDurabilityPolicy.TRANSIENT_LOCAL
    else:
        if lasting:
            print("Some, but not all, publishers are offering "
                  "QoSDurabilityPolicy.TRANSIENT_LOCAL. Falling back to "
                  "QoSDurabilityPolicy.VOLATILE as it will connect to all publishers")
        profile.durability = QoSDurabilityPolicy.VOLATILE
    return profile


def echo(args):
    field = None
    if args.field is not None:
        field = [part for part in args.field.split(".") if part]
        if not field:
            raise UsageError("Invalid field value '%s'" % args.field)
    truncate_length = None if args.full_length else args.truncate_length
    checked_name(args.topic_name)
    message_class = interface_class(args.message_type, "msg") if args.message_type else None
    with CliNode(spin_time=args.spin_time) as cli:
        if message_class is None:
            message_class = _topic_class(cli, args.topic_name, args.timeout)
        qos = _echo_qos(cli, args)
        printed = []

        def show(msg):
            shown = msg
            for part in field or ():
                try:
                    shown = getattr(shown, part)
                except AttributeError as error:
                    raise CommandError("Invalid field '%s': %s" % (".".join(field), error))
            if hasattr(shown, "get_fields_and_field_types"):
                print(message_to_yaml(shown, truncate_length, args.no_arr, args.no_str,
                                      args.flow_style), end="---\n")
            else:
                print(shown, end="\n---\n")
            printed.append(True)

        cli.node.create_subscription(message_class, args.topic_name, show, qos)
        cli.spin_until(lambda: args.once and printed, args.timeout)


# ----------------------------------------------------------------------------- hz

class RateMeter:
    """ros2topic hz's figures: the intervals between arrivals (the last ``window`` of them) and
    a report at most once a second of arrivals, only when a message came since the last one."""

    def __init__(self, window, clock_ns):
        self.window = window
        self.clock_ns = clock_ns
        self.intervals = []
        self.last_ns = None
        self.reported_at_ns = None

    def arrived(self, _msg=None):
        now = self.clock_ns()
        if now == 0:  # simulated time not running yet
            if self.intervals:
                print("time has reset, resetting counters")
                self.intervals = []
            return
        if self.last_ns is None or self.last_ns > now:
            self.intervals = []
        else:
            self.intervals.append(now - self.last_ns)
            del self.intervals[:-self.window]
        self.last_ns = now

    def report(self):
        """The report line when one is due, else None."""
        if not self.intervals:
            return None
        if self.reported_at_ns is None:
            self.reported_at_ns = self.last_ns  # the first report waits for a second of data
            return None
        if self.last_ns < self.reported_at_ns + 1_000_000_000:
            return None
        count = len(self.intervals)
        mean = sum(self.intervals) / count
        deviation = math.sqrt(sum((x - mean) ** 2 for x in self.intervals) / count)
        self.reported_at_ns = self.last_ns
        return ("average rate: %.3f\n\tmin: %.3fs max: %.3fs std dev: %.5fs window: %s"
                % (1e9 / mean if mean > 0 else 0.0, min(self.intervals) * 1e-9,
                   max(self.intervals) * 1e-9, deviation * 1e-9, count))


def hz(args):
    from rclpy.qos import qos_profile_sensor_data

    checked_name(args.topic_name)
    with CliNode(spin_time=args.spin_time) as cli:
        message_class = _topic_class(cli, args.topic_name)
        if args.use_wtime:
            clock_ns = time.time_ns
        else:
            ros_clock = cli.node.get_clock()
            clock_ns = lambda: ros_clock.now().nanoseconds  # noqa: E731
        meter = RateMeter(args.window_size, clock_ns)
        cli.node.create_subscription(message_class, args.topic_name, meter.arrived,
                                     qos_profile_sensor_data)
        while True:
            cli.spin_once()
            line = meter.report()
            if line is not None:
                print(line)


# ----------------------------------------------------------------------------- pub

def pub(args):
    checked_name(args.topic_name)
    message_class = interface_class(args.message_type, "msg")
    values = parse_yaml_values(args.values)
    qos = qos_from_arguments(args)
    times = 1 if args.once else args.times
    wanted = args.wait_matching_subscriptions
    if wanted is None:
        wanted = 1 if times else 0
    if not wanted and args.max_wait_time_secs is not None:
        raise UsageError("--max-wait-time-secs option is only effective with "
                         "--wait-matching-subscriptions, --once or --times")
    if args.node_name is not None:
        from rclpy.validate_node_name import validate_node_name

        validate_node_name(args.node_name)  # before rclpy half-builds a node with it
    msg = message_class()
    try:
        stamp_setters = set_message_fields(msg, values, expand_header_auto=True,
                                           expand_time_now=True)
    except Exception as error:
        raise UsageError("Failed to populate field: %s" % error) from None
    with CliNode(name=args.node_name, spin_time=args.spin_time) as cli:
        publisher = cli.node.create_publisher(message_class, args.topic_name, qos)
        waited = 0.0
        steps = 0
        while publisher.get_subscription_count() < wanted:
            if steps % 10 == 0:
                print("Waiting for at least %d matching subscription(s)..." % wanted)
            if args.max_wait_time_secs is not None and waited >= args.max_wait_time_secs:
                raise CommandError("Timed out waiting for subscribers: Expected %d subcribers but "
                                   "only got %d subscribers"
                                   % (wanted, publisher.get_subscription_count()))
            steps += 1
            cli.spin_for(PUB_WAIT_STEP_S)
            waited += PUB_WAIT_STEP_S
        print("publisher: beginning loop")
        count = 0
        period_ns = int(1e9 / args.rate)
        next_ns = time.monotonic_ns()
        while not times or count < times:
            now_ns = time.monotonic_ns()
            if now_ns < next_ns:
                cli.spin_once(min((next_ns - now_ns) / 1e9, 0.1))
                continue
            next_ns += period_ns
            stamp = cli.node.get_clock().now().to_msg()
            for setter in stamp_setters:
                setter(stamp)
            count += 1
            if args.print and count % args.print == 0:
                print("publishing #%d: %r\n" % (count, msg))
            publisher.publish(msg)
        # Reliable samples still in the writer's history are lost with the node: give them the
        # keep-alive to go out (ros2topic's --keep-alive).
        cli.spin_for(args.keep_alive)
