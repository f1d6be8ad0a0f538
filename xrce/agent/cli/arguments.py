"""The command line's parser class and the types its options parse, shared by every subcommand.

Standard library only: ``xrce-agent --version`` and ``--help`` import this and nothing of the agent.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys

PROG = "xrce-agent"
TRACE = 5  # -v 6: every message decoded, logged by the engine on logger "xrce.agent"
logging.addLevelName(TRACE, "TRACE")
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


def _help_formatter(prog):
    """argparse's formatter, told the terminal width as ``shutil.get_terminal_size`` would find
    it: argparse asks shutil otherwise, and shutil (with the bz2 and lzma it imports) is 0.5 MB of
    the agent's resident memory, used for nothing else."""
    try:
        width = int(os.environ.get("COLUMNS", 0))
    except ValueError:
        width = 0
    if width <= 0:
        try:
            width = os.get_terminal_size(sys.__stdout__.fileno()).columns
        except (AttributeError, ValueError, OSError):
            width = 0
    return argparse.HelpFormatter(prog, width=(width or 80) - 2)


class ArgumentParser(argparse.ArgumentParser):
    """argparse with a one-line error report: scripts and tests read stderr, not a usage dump."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _help_formatter)
        super().__init__(*args, **kwargs)

    def error(self, message):
        sys.stderr.write("%s: error: %s\n" % (PROG, message))
        sys.stderr.flush()
        raise SystemExit(2)


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


def domain_id(text):
    """A ROS domain id (--domain). xrce.tools.cli_types has the tools' twin; the agent's
    options import no tool module."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid domain id: %r" % text)
    if not 0 <= value <= 232:  # the largest id whose RTPS ports still fit in 16 bits
        raise argparse.ArgumentTypeError("domain id %d is not in 0..232" % value)
    return value


def allow_list(parse):
    """An option type from a parser raising ValueError (the admission lists)."""
    def parse_option(text):
        try:
            return parse(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc))
    return parse_option
