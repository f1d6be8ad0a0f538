"""The types the command line's options parse, shared by every subcommand (the parser class and
``domain_id`` are the three command lines' own: ``xrce.command_line``).

Standard library only: ``xrce-agent --version`` and ``--help`` import this and nothing of the agent.
"""

from __future__ import annotations

import argparse
import logging

from xrce.agent.log_levels import TRACE

PROG = "xrce-agent"
VERBOSITY_LEVELS = {
    0: logging.CRITICAL + 10,  # nothing
    1: logging.CRITICAL,
    2: logging.ERROR,
    3: logging.WARNING,
    4: logging.INFO,
    5: logging.DEBUG,
    6: TRACE,
}


class CliError(Exception):
    """A problem found after parsing (unreadable refs file, ...) reported like a bad argument."""


# ----------------------------------------------------------------------------- argument types

def port(text):
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid port: %r" % text)
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError("port %d is not in 0..65535" % value)
    return value


def seconds(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid number of seconds: %r" % text)
    if not 0 <= value < float("inf"):
        raise argparse.ArgumentTypeError("must be 0 or more seconds, not %s" % text)
    return value


def positive_seconds(text):
    value = seconds(text)
    if value == 0:
        raise argparse.ArgumentTypeError("must be more than 0 seconds, not %s" % text)
    return value


def baudrate(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid baud rate: %r" % text)
    if value <= 0:
        raise argparse.ArgumentTypeError("baud rate must be positive, not %d" % value)
    return value


def verbosity(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid verbosity: %r (0..6)" % text)
    if value not in VERBOSITY_LEVELS:
        raise argparse.ArgumentTypeError("verbosity %d is not in 0..6" % value)
    return value


def milliseconds(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid time in ms: %r" % text)
    if value < 0:
        raise argparse.ArgumentTypeError("time must be >= 0 ms, not %d" % value)
    return value


def positive(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid number: %r" % text)
    if value <= 0:
        raise argparse.ArgumentTypeError("must be positive, not %d" % value)
    return value


def allow_list(parse):
    """An option type from a parser raising ValueError (the admission lists)."""
    def parse_option(text):
        try:
            return parse(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc))
    return parse_option
