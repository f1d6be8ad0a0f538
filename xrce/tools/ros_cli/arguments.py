"""What every ``xrce-ros`` verb shares from the command line: the error kinds and their exit codes,
argument types, and the discovery and QoS options of ros2cli (the verbs
import this; ``cli`` imports the verbs)."""

from __future__ import annotations

import argparse
import signal

from xrce import command_line

PROG = "xrce-ros"
EXIT_FAILED = 1
# ros2cli's main returns the signal's number: 2 after Ctrl-C (a bad argument's code too), 15 after
# SIGTERM.
EXIT_INTERRUPTED = int(signal.SIGINT)
EXIT_TERMINATED = int(signal.SIGTERM)
DEFAULT_SPIN_TIME_S = 0.5  # ros2cli's discovery wait without a daemon


class UsageError(Exception):
    """An argument argparse accepted but the command cannot use (a type name, a YAML value)."""


class CommandError(Exception):
    """The command ran and failed; the text is ros2cli's sentence for the same case."""


def usage_exit(message):
    command_line.usage_exit(PROG, message)


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
