"""What the three command lines (``xrce-agent``, ``xrce-client``, ``xrce-ros``) share: argparse with
a one-line error report, and the argument types they all take.

CPython only, standard library only: ``xrce-agent --version`` and ``--help`` import this and nothing
of the agent or the tools (tests/agent/test_agent_cli.py). A package of its own beside xrce.agent,
xrce.client and xrce.tools, which all use it, and not among what xrce.tools.mpy ships to boards.
"""

import argparse
import os
import sys

EXIT_USAGE = 2  # argparse's own exit code for a bad argument


def usage_exit(command, message):
    """End ``command`` as argparse ends it on a bad argument, in one line: scripts and tests read
    stderr, not a usage dump."""
    sys.stderr.write("%s: error: %s\n" % (command, message))
    sys.stderr.flush()
    raise SystemExit(EXIT_USAGE)


def help_formatter(prog):
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


class OneLineErrorParser(argparse.ArgumentParser):
    """argparse whose errors are one ``COMMAND: error: ...`` line and exit code 2. COMMAND is the
    first word of the top-level parser's ``prog`` (a subcommand's parser is ``prog`` followed by
    its name), so build the top-level parser with ``prog=`` the command's name."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", help_formatter)
        super().__init__(*args, **kwargs)

    def error(self, message):
        usage_exit(self.prog.split()[0], message)


def domain_id(text):
    """A ROS domain id, as ROS_DOMAIN_ID or --domain gives it."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid domain id: %r" % text)
    if not 0 <= value <= 232:  # the largest id whose RTPS ports still fit in 16 bits
        raise argparse.ArgumentTypeError("domain id %d is not in 0..232" % value)
    return value
