"""The subcommand table and the parser built from it.

Each ``Subcommand`` row adds its options to a subparser and either returns the links to serve
(``make_links``: the transports of xrce.agent.cli.transports) or runs on its own (``run``), so
tools such as ``build-interfaces`` or ``stats`` are registered here without touching the agent's
start-up (xrce.agent.cli.startup).

``build_parser(argv)`` fills in only the options of the subcommand ``argv`` names: their defaults
come from the engine, the observability and the links, which ``--version``, ``--help`` and the
other subcommands then never import. The tools' own modules load only when they run.
"""

from __future__ import annotations

import argparse
import sys

from xrce.agent.cli import transports
from xrce.agent.cli.arguments import PROG, CliError, seconds
from xrce.command_line import OneLineErrorParser, domain_id


class Subcommand:
    """One row of the subcommand table. An agent transport gives ``make_links(args, agent)``; any
    other tool gives ``run(args) -> exit code``."""

    def __init__(self, name, help, add_options, make_links=None, run=None):
        self.name = name
        self.help = help
        self.add_options = add_options
        self.make_links = make_links
        self.run = run


SUBCOMMANDS = {}


def register(subcommand):
    SUBCOMMANDS[subcommand.name] = subcommand
    return subcommand


# ----------------------------------------------------------------------------- the tools

def _add_stats_options(parser):
    from xrce.agent.observe import observability
    observability.add_stats_options(parser)


def _run_stats(args):
    from xrce.agent.observe import observability
    return observability.run_stats(args)


def _add_build_options(parser):
    from xrce.agent import interfaces
    interfaces.add_build_options(parser)


def _run_build(args):
    from xrce.agent import interfaces
    return interfaces.run_build_command(args)


def _add_demo_options(parser):
    parser.add_argument("--serial", action="store_true",
                        help="robot on the agent's pseudoterminal at 115200 baud (default UDP)")
    parser.add_argument("--duration", type=seconds, default=0.0, metavar="S",
                        help="stop after S seconds (default 0: until Ctrl-C)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--domain", type=domain_id, metavar="N",
                       help="publish in ROS domain N with the usual discovery range, so other "
                            "machines see it (default: a private domain on this machine only)")
    where.add_argument("--lan", action="store_true",
                       help="publish in $ROS_DOMAIN_ID (else 0) with the usual discovery range, so "
                            "a robot on the LAN in that domain would obey its /cmd_vel")


def _run_demo(args):
    from xrce.agent import demo
    return demo.run(args)


for _name, _help, _add_options, _make_links in transports.TRANSPORTS:
    register(Subcommand(_name, _help, _add_options, _make_links))
register(Subcommand("stats", "show a running agent's counters live (see --stats-port)",
                    _add_stats_options, run=_run_stats))
register(Subcommand("build-interfaces", "build ROS interface packages (.msg/.srv) for rclpy",
                    _add_build_options, run=_run_build))
register(Subcommand("demo", "run the agent, a simulated TurtleBot3 and a ROS node driving it",
                    _add_demo_options, run=_run_demo))


# ----------------------------------------------------------------------------- the parser

class _VersionAction(argparse.Action):
    """``--version``: this xrce, and the ROS 2 and RMW the agent would join, found without
    importing rclpy (so it answers at once, and also where no rclpy can be had)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        import platform

        import xrce
        from xrce.agent.interfaces import ros_install as rosenv

        from xrce.agent.cli.event_loop import event_loop

        try:
            loop = event_loop()[0]
        except CliError as exc:
            loop = str(exc)
        sys.stdout.write("%s %s (DDS-XRCE 1.0, Python %s, %s)\n%s\n" % (
            PROG, xrce.__version__, platform.python_version(), loop, rosenv.would_use()))
        sys.stdout.flush()
        parser.exit(0)


def _named_subcommand(argv):
    # The top-level parser has no option taking a value, so the subcommand is the first word
    # that is not an option (after "--" too, as argparse reads it).
    for word in argv:
        if not word.startswith("-"):
            return word
    return None


def build_parser(argv=None):
    """The parser for ``argv`` (default ``sys.argv[1:]``): every subcommand listed, the options of
    the one ``argv`` names added (a subparser without its options is never the one that parses)."""
    chosen = _named_subcommand(sys.argv[1:] if argv is None else argv)
    parser = OneLineErrorParser(prog=PROG, description="Micro XRCE-DDS agent (MicroXRCEAgent-compatible)")
    parser.add_argument("--version", action=_VersionAction,
                        help="print xrce's version and the ROS 2 and RMW the agent would use")
    sub = parser.add_subparsers(dest="subcommand", metavar="SUBCOMMAND", required=True)
    for row in SUBCOMMANDS.values():
        child = sub.add_parser(row.name, help=row.help, description=row.help)
        if row.name != chosen:
            continue
        row.add_options(child)
        if row.make_links is not None:
            transports.add_common_options(child)
    return parser
