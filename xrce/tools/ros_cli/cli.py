"""The ``xrce-ros`` command line: ``xrce-ros <group> <verb> ...`` as ``ros2 <group> <verb> ...``.

Exit codes: 0 done; 1 the graph did not give what was asked (ros2cli prints the same sentence on
stderr and exits 1 there too); 2 a bad argument, in one line on stderr (ros2cli prints a usage
dump: scripts and tests read one line); 130 Ctrl-C (ros2cli exits 2 there, which would read as a
bad argument).
"""

from __future__ import annotations

import argparse
import sys

PROG = "xrce-ros"
EXIT_FAILED = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130
DEFAULT_SPIN_TIME_S = 0.5  # ros2cli's discovery wait without a daemon


class UsageError(Exception):
    """An argument argparse accepted but the command cannot use (a type name, a YAML value)."""


class CommandError(Exception):
    """The command ran and failed; the text is ros2cli's sentence for the same case."""


class ArgumentParser(argparse.ArgumentParser):
    """argparse with a one-line error report: scripts and tests read stderr, not a usage dump."""

    def error(self, message):
        usage_exit(message)


def usage_exit(message):
    sys.stderr.write("%s: error: %s\n" % (PROG, message))
    sys.stderr.flush()
    raise SystemExit(EXIT_USAGE)


# ----------------------------------------------------------------------------- argument types

def positive_int(text):
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value <= 0:
        raise argparse.ArgumentTypeError("value must be a positive integer, not %r" % text)
    return value


def nonnegative_int(text):
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError("value must be 0 or a positive integer, not %r" % text)
    return value


def positive_float(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError("expects a floating point number, not %r" % text)
    if not 0.0 < value < float("inf"):
        raise argparse.ArgumentTypeError("value must be positive, not %r" % text)
    return value


def add_graph_arguments(parser):
    """The options of ros2cli's node strategy that mean something without a daemon."""
    parser.add_argument("--spin-time", type=positive_float, default=DEFAULT_SPIN_TIME_S,
                        help="seconds to wait for discovery (default: %(default)s)")
    # Accepted so that a ros2 command line pasted here runs: there is never a daemon.
    parser.add_argument("--no-daemon", action="store_true", help=argparse.SUPPRESS)


def add_qos_arguments(parser, direction, default_profile):
    """ros2topic's QoS options, their values rclpy's own short keys."""
    from rclpy.qos import (QoSDurabilityPolicy, QoSHistoryPolicy, QoSLivelinessPolicy,
                           QoSPresetProfiles, QoSReliabilityPolicy)

    parser.add_argument("--qos-profile", choices=QoSPresetProfiles.short_keys(),
                        default=default_profile,
                        help="QoS preset profile to %s with (default: %s)"
                             % (direction, default_profile))
    parser.add_argument("--qos-depth", metavar="N", type=nonnegative_int,
                        help="queue size to %s with" % direction)
    parser.add_argument("--qos-history", choices=QoSHistoryPolicy.short_keys())
    parser.add_argument("--qos-reliability", choices=QoSReliabilityPolicy.short_keys())
    parser.add_argument("--qos-durability", choices=QoSDurabilityPolicy.short_keys())
    parser.add_argument("--qos-liveliness", choices=QoSLivelinessPolicy.short_keys())
    parser.add_argument("--qos-liveliness-lease-duration-seconds", type=positive_float)


def qos_from_arguments(args, profile=None):
    """The preset named by --qos-profile (or ``profile``) with the --qos-* overrides applied, as
    ros2topic applies them (a transient-local depth of 0 becomes 1)."""
    from rclpy.duration import Duration
    from rclpy.qos import (QoSDurabilityPolicy, QoSHistoryPolicy, QoSLivelinessPolicy,
                           QoSPresetProfiles, QoSReliabilityPolicy)

    if profile is None:
        profile = QoSPresetProfiles.get_from_short_key(args.qos_profile)
    if args.qos_history:
        profile.history = QoSHistoryPolicy.get_from_short_key(args.qos_history)
    if args.qos_durability:
        profile.durability = QoSDurabilityPolicy.get_from_short_key(args.qos_durability)
    if args.qos_reliability:
        profile.reliability = QoSReliabilityPolicy.get_from_short_key(args.qos_reliability)
    if args.qos_liveliness:
        profile.liveliness = QoSLivelinessPolicy.get_from_short_key(args.qos_liveliness)
    if args.qos_liveliness_lease_duration_seconds:
        profile.liveliness_lease_duration = Duration(
            seconds=args.qos_liveliness_lease_duration_seconds)
    if args.qos_depth:
        profile.depth = args.qos_depth
    elif profile.durability == QoSDurabilityPolicy.TRANSIENT_LOCAL and profile.depth == 0:
        profile.depth = 1
    return profile


def qos_overridden(args):
    return any(getattr(args, name) is not None for name in (
        "qos_reliability", "qos_durability", "qos_depth", "qos_history", "qos_liveliness",
        "qos_liveliness_lease_duration_seconds"))


# ----------------------------------------------------------------------------- parser

def build_parser():
    from xrce.tools.ros_cli import action, node, param, service, topic

    parser = ArgumentParser(
        prog=PROG,
        description="The ros2 verbs a micro-ROS user needs to see a board, on this venv's rclpy "
                    "(ros2cli's syntax and output; no daemon).")
    groups = parser.add_subparsers(dest="group", metavar="COMMAND", required=True)
    for module in (action, node, param, service, topic):
        group = groups.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        verbs = group.add_subparsers(dest="verb", metavar="VERB", required=True)
        module.add_verbs(verbs)
    return parser


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    # Line-buffered as ros2cli makes it: a pipe reader (a script, a test) sees each message when
    # it is printed, not when a block fills.
    sys.stdout.reconfigure(line_buffering=True)
    try:
        return args.run(args) or 0
    except UsageError as error:
        usage_exit(str(error))
    except CommandError as error:
        sys.stderr.write("%s\n" % error)
        return EXIT_FAILED
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
