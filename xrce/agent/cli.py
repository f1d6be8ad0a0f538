"""``xrce-agent``: a command line compatible with eProsima's MicroXRCEAgent.

    xrce-agent udp4 -p 8888 [-d [PORT]] [-m dds|ced] [-r refs.xml] [-v 0..6]
    xrce-agent tcp6 -p 8888
    xrce-agent serial -D /dev/ttyUSB0 [-b 115200] [--crc arc|ccitt]
    xrce-agent multiserial --devs "/dev/ttyUSB0 /dev/ttyUSB1"
    xrce-agent pseudoterminal [-D /tmp/xrce_pty]

Subcommands live in the ``SUBCOMMANDS`` table: each entry adds its options to a subparser and
either returns the links to serve (``make_links``) or runs on its own (``run``), so tools such as
``build-interfaces`` or ``stats`` can be registered without touching the agent start-up.

Once every link is open, one banner line goes to stdout (flushed) — tests wait for it. Errors in the
arguments (a path that cannot be used included) give one ``xrce-agent: error: ...`` line on stderr
naming the flag, and exit code 2; a port that cannot be opened gives one line naming it and exit
code 1; SIGINT/SIGTERM close the agent cleanly and exit 0 (as eProsima's agent).
"""

from __future__ import annotations

import argparse
import asyncio
import errno
import logging
import os
import signal
import socket
import sys

from xrce.agent import interfaces, links
from xrce.agent.links import udp
from xrce.agent.observe import observability
from xrce.tools.cli_types import domain_id

PROG = "xrce-agent"
TRACE = 5  # -v 6: every message decoded, logged by the engine on logger "xrce.agent"
logging.addLevelName(TRACE, "TRACE")
_VERBOSITY_LEVELS = {
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

def _port(text):
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid port: %r" % text)
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError("port %d is not in 0..65535" % value)
    return value


def _seconds(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid number of seconds: %r" % text)
    if not 0 <= value < float("inf"):
        raise argparse.ArgumentTypeError("must be 0 or more seconds, not %s" % text)
    return value


def _baudrate(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid baud rate: %r" % text)
    if value <= 0:
        raise argparse.ArgumentTypeError("baud rate must be positive, not %d" % value)
    return value


def _verbosity(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid verbosity: %r (0..6)" % text)
    if value not in _VERBOSITY_LEVELS:
        raise argparse.ArgumentTypeError("verbosity %d is not in 0..6" % value)
    return value


# ----------------------------------------------------------------------------- option groups

def _milliseconds(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid time in ms: %r" % text)
    if value < 0:
        raise argparse.ArgumentTypeError("time must be >= 0 ms, not %d" % value)
    return value


def _positive(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid number: %r" % text)
    if value <= 0:
        raise argparse.ArgumentTypeError("must be positive, not %d" % value)
    return value


def _add_session_options(parser):
    from xrce.agent.engine import dispatch  # no rclpy behind it; the defaults are documented there

    group = parser.add_argument_group("client liveliness and per-client quotas")
    group.add_argument("--client-dead-time", type=_milliseconds, metavar="MS",
                       default=int(dispatch.CLIENT_DEAD_TIME * 1000),
                       help="a client silent this long is dead: no more HEARTBEATs to it, entities "
                            "kept, any message revives it (default %(default)s, as eProsima)")
    group.add_argument("--client-expire-time", type=_milliseconds, metavar="MS",
                       default=int(dispatch.CLIENT_EXPIRE_TIME * 1000),
                       help="a client silent this long (since its last message) is deleted with "
                            "all its ROS entities; 0 = never (default, as eProsima without uxr_hl)")
    group.add_argument("--max-clients", type=_positive, metavar="N", default=dispatch.MAX_CLIENTS,
                       help="sessions at once; a new one evicts the longest-dead client or is "
                            "refused with ERR_RESOURCES (default %(default)s)")
    group.add_argument("--max-objects", type=_positive, metavar="N",
                       default=dispatch.MAX_OBJECTS_PER_CLIENT,
                       help="XRCE objects per client; beyond, CREATE gets ERR_RESOURCES "
                            "(default %(default)s)")
    group.add_argument("--max-reassembly", type=_positive, metavar="BYTES",
                       default=dispatch.MAX_REASSEMBLY,
                       help="largest fragmented message per client and stream (default %(default)s)")
    group.add_argument("--max-output-queue", type=_positive, metavar="BYTES",
                       default=dispatch.MAX_OUTPUT_QUEUE_BYTES,
                       help="sample bytes queued towards one client; the oldest are dropped "
                            "beyond (default %(default)s)")
    group.add_argument("--max-client-memory", type=_positive, metavar="BYTES",
                       default=dispatch.MAX_CLIENT_BYTES,
                       help="bytes one client's buffers may hold (out-of-order input, reassembly, "
                            "parked messages, output queues and windows); beyond, its reliable "
                            "input waits unacknowledged and its output is dropped "
                            "(default %(default)s)")
    group.add_argument("--max-memory", type=_positive, metavar="BYTES",
                       default=dispatch.MAX_TOTAL_BYTES,
                       help="the same, all clients together (default %(default)s)")


def _allow_list(parse):
    def parse_option(text):
        try:
            return parse(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc))
    return parse_option


def _add_admission_options(parser):
    from xrce.agent.engine import admission

    group = parser.add_argument_group("admission (XRCE has no authentication: see README)")
    group.add_argument("--allow-keys", type=_allow_list(admission.parse_keys),
                       metavar="KEY[,KEY...]",
                       help="open sessions only for these client keys (hex, e.g. 0xAABBCCDD); "
                            "others get ERR_DENIED and a (rate-limited) log line")
    group.add_argument("--allow-from", type=_allow_list(admission.parse_networks),
                       metavar="CIDR[,CIDR...]",
                       help="open sessions only for clients from these addresses/networks "
                            "(udp4/udp6/tcp4/tcp6)")


def _add_common_options(parser):
    parser.add_argument("-v", "--verbose", type=_verbosity, default=4, metavar="LEVEL",
                        help="log level 0 (off) .. 4 (info, default) .. 5 (debug) .. 6 (trace)")
    _add_session_options(parser)
    _add_admission_options(parser)
    parser.add_argument("-m", "--middleware", choices=("dds", "ced"), default="dds",
                        help="dds: ROS 2 through rclpy (default); ced: route between clients only")
    parser.add_argument("-r", "--refs", metavar="FILE",
                        help="Fast DDS XML profiles file for objects created by reference")
    parser.add_argument("--interfaces", action="append", default=[], metavar="DIR",
                        help="also look here for interface packages to build when a client names "
                             "a type that is not installed (repeatable; the packages shipped with "
                             "xrce are always searched)")
    observability.add_agent_options(parser)


def _add_ip_options(parser):
    parser.add_argument("-p", "--port", type=_port, required=True,
                        help="UDP/TCP port to serve (0: any free port, shown in the banner)")
    parser.add_argument("-d", "--discovery", type=_port, nargs="?", const=udp.DISCOVERY_PORT,
                        metavar="PORT", help="answer discovery requests on PORT (default 7400)")


def _add_tcp_options(parser):
    _add_ip_options(parser)
    parser.add_argument("--max-connections", type=int,
                        default=links.DEFAULT_TCP_MAX_CONNECTIONS, metavar="N",
                        help="simultaneous TCP connections (default 100)")


def _add_crc_option(parser):
    parser.add_argument("--crc", choices=("arc", "ccitt"), default="arc",
                        help="frame checksum: CRC-16/ARC (default, as eProsima) or CRC-16/X.25")


def _add_baudrate_option(parser):
    parser.add_argument("-b", "--baudrate", type=_baudrate, default=links.DEFAULT_BAUDRATE,
                        metavar="BAUD", help="line speed; the board must use the same "
                                             "(default %(default)s, as eProsima)")


def _add_serial_options(parser):
    parser.add_argument("-D", "--dev", required=True, metavar="DEVICE",
                        help="serial device or glob (waited for until it appears; reopened when "
                             "it comes back after vanishing)")
    _add_baudrate_option(parser)
    _add_crc_option(parser)


def _add_multiserial_options(parser):
    parser.add_argument("--devs", required=True, metavar='"DEV1 DEV2 ..."',
                        help="space-separated serial devices")
    _add_baudrate_option(parser)
    _add_crc_option(parser)


def _add_pty_options(parser):
    parser.add_argument("-D", "--dev", metavar="PATH",
                        help="also make PATH a symbolic link to the pseudoterminal")
    _add_crc_option(parser)


# ----------------------------------------------------------------------------- link factories

# The TCP and serial link modules are imported only by the subcommands that serve them.

def _udp_links(family):
    def make_links(args, agent):
        return [udp.UdpServer(agent, args.port, family=family)]
    return make_links


def _tcp_links(family):
    def make_links(args, agent):
        from xrce.agent.links import tcp
        return [tcp.TcpServer(agent, args.port, family=family,
                                    max_connections=args.max_connections)]
    return make_links


def _serial_links(args, agent):
    from xrce.agent.links import serial
    return [serial.SerialServer(agent, [args.dev], baudrate=args.baudrate, crc=args.crc)]


def _multiserial_links(args, agent):
    from xrce.agent.links import serial
    devices = args.devs.split()
    return [serial.SerialServer(agent, devices, baudrate=args.baudrate, crc=args.crc)]


def _pty_links(args, agent):
    from xrce.agent.links import serial
    return [serial.PseudoterminalServer(agent, symlink=args.dev, crc=args.crc)]


# The demo's options are defined here and its module imported only when it runs: every agent
# process builds the whole parser, and xrce.agent.demo is none of its business.

def _add_demo_options(parser):
    parser.add_argument("--serial", action="store_true",
                        help="robot on the agent's pseudoterminal at 115200 baud (default UDP)")
    parser.add_argument("--duration", type=_seconds, default=0.0, metavar="S",
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


for _row in (
    Subcommand("udp4", "serve UDP over IPv4", _add_ip_options,
               _udp_links(socket.AF_INET)),
    Subcommand("udp6", "serve UDP over IPv6", _add_ip_options,
               _udp_links(socket.AF_INET6)),
    Subcommand("tcp4", "serve TCP over IPv4", _add_tcp_options,
               _tcp_links(socket.AF_INET)),
    Subcommand("tcp6", "serve TCP over IPv6", _add_tcp_options,
               _tcp_links(socket.AF_INET6)),
    Subcommand("serial", "serve one serial device", _add_serial_options, _serial_links),
    Subcommand("multiserial", "serve several serial devices", _add_multiserial_options,
               _multiserial_links),
    Subcommand("pseudoterminal", "create a pseudoterminal and serve it", _add_pty_options,
               _pty_links),
):
    register(_row)
register(Subcommand("stats", "show a running agent's counters live (see --stats-port)",
                    observability.add_stats_options, run=observability.run_stats))
register(Subcommand("build-interfaces", "build ROS interface packages (.msg/.srv) for rclpy",
                    interfaces.add_build_options, run=interfaces.run_build_command))
register(Subcommand("demo", "run the agent, a simulated TurtleBot3 and a ROS node driving it",
                    _add_demo_options, run=_run_demo))


_IP_SUBCOMMANDS = ("udp4", "udp6", "tcp4", "tcp6")


class _VersionAction(argparse.Action):
    """``--version``: this xrce, and the ROS 2 and RMW the agent would join, found without
    importing rclpy (so it answers at once, and also where no rclpy can be had)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        import platform

        import xrce
        from xrce.agent.middleware.ros import env as rosenv

        sys.stdout.write("%s %s (DDS-XRCE 1.0, Python %s)\n%s\n" % (
            PROG, xrce.__version__, platform.python_version(), rosenv.would_use()))
        sys.stdout.flush()
        parser.exit(0)


def build_parser():
    parser = ArgumentParser(prog=PROG, description="Micro XRCE-DDS agent (MicroXRCEAgent-compatible)")
    parser.add_argument("--version", action=_VersionAction,
                        help="print xrce's version and the ROS 2 and RMW the agent would use")
    sub = parser.add_subparsers(dest="subcommand", metavar="SUBCOMMAND", required=True)
    for row in SUBCOMMANDS.values():
        child = sub.add_parser(row.name, help=row.help, description=row.help)
        row.add_options(child)
        if row.make_links is not None:
            _add_common_options(child)
    return parser


# ----------------------------------------------------------------------------- refs and middleware

def _local_name(tag):
    return tag.rsplit("}", 1)[-1]


def _strip_namespaces(element):
    for node in element.iter():
        if isinstance(node.tag, str):
            node.tag = _local_name(node.tag)


def load_refs(path):
    """``{profile_name: xml}`` for every element carrying a ``profile_name`` in a Fast DDS XML
    profiles file; the XML of each is that element alone, namespaces removed."""
    import xml.etree.ElementTree as ElementTree  # only with -r: see xrce.agent.engine.xmlrep._parse

    try:
        tree = ElementTree.parse(path)
    except OSError as exc:
        raise CliError("cannot read refs file %s: %s" % (path, exc.strerror or exc))
    except ElementTree.ParseError as exc:
        raise CliError("refs file %s is not valid XML: %s" % (path, exc))
    root = tree.getroot()
    _strip_namespaces(root)
    refs = {}
    for element in root.iter():
        name = element.get("profile_name")
        if name:
            element.tail = None
            refs[name] = ElementTree.tostring(element, encoding="unicode")
    return refs


def check_paths(args):
    """Paths named on the command line, checked before anything starts, so a typo is one line
    naming the flag (exit 2) rather than an errno once the agent is half up, or silence."""
    for directory in getattr(args, "interfaces", ()):
        if not os.path.isdir(directory):
            what = "does not exist" if not os.path.exists(directory) else "is not a directory"
            raise CliError("argument --interfaces: %s %s (give a directory holding interface "
                           "packages, each with its package.xml)" % (directory, what))
    capture = getattr(args, "capture", None)
    if capture:
        parent = os.path.dirname(os.path.abspath(capture))
        if os.path.isdir(capture):
            raise CliError("argument --capture: %s is a directory (give a file name)" % capture)
        if not os.path.isdir(parent):
            raise CliError("argument --capture: directory %s does not exist (create it or "
                           "write the capture elsewhere)" % parent)
        if not os.access(parent, os.W_OK) or (os.path.exists(capture)
                                              and not os.access(capture, os.W_OK)):
            raise CliError("argument --capture: %s is not writable (write the capture "
                           "elsewhere)" % capture)
    stats_port = getattr(args, "stats_port", None)
    if stats_port is not None and not 0 <= stats_port <= 65535:
        raise CliError("argument --stats-port: port %d is not in 0..65535" % stats_port)


def make_middleware(name):
    # Imported lazily: "ced" must work on machines without ROS, and rclpy is slow to import.
    if name == "ced":
        from xrce.agent.middleware.ced import CedMiddleware
        return CedMiddleware()
    from xrce.agent.middleware.ros.entities import RosMiddleware
    return RosMiddleware(park_creation=True)


def configure_logging(verbosity):
    level = _VERBOSITY_LEVELS[verbosity]
    logging.basicConfig(level=level, stream=sys.stderr,
                        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s")
    logging.getLogger().setLevel(level)


# ----------------------------------------------------------------------------- running

async def serve(args, refs):
    """Run the agent on the links of ``args.subcommand`` until SIGINT/SIGTERM; the exit code."""
    from xrce.agent.engine.dispatch import Agent

    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop.set)

    middleware = make_middleware(args.middleware)
    agent = Agent(middleware, refs=refs, loop=loop,
                  client_dead_time=args.client_dead_time / 1000.0,
                  client_expire_time=args.client_expire_time / 1000.0,
                  max_clients=args.max_clients, max_objects_per_client=args.max_objects,
                  max_reassembly_bytes=args.max_reassembly,
                  max_output_queue_bytes=args.max_output_queue,
                  max_client_bytes=args.max_client_memory, max_total_bytes=args.max_memory)
    from xrce.agent.engine.admission import AdmissionPolicy
    agent.admission = AdmissionPolicy.from_args(args)
    if agent.admission is not None:
        logging.getLogger("xrce.agent.admission").info("admission: %s", agent.admission.describe())
    links = SUBCOMMANDS[args.subcommand].make_links(args, agent)
    started = []
    run_task = None
    observe = None
    try:
        # The middleware starts (the default ROS domain joined, the agent's node in it) before
        # any link opens: no client is answered while rclpy builds, and a restarted agent's DDS
        # participant is already being discovered when its clients come back.
        await agent.start()
        run_task = asyncio.ensure_future(agent.run())
        try:
            for link in links:
                await link.start()
                started.append(link)
            if getattr(args, "discovery", None) is not None:
                discovery = udp.DiscoveryServer(links[0].port, args.discovery)
                await discovery.start()
                started.append(discovery)
            observe = observability.Observability.from_args(args, agent, started, middleware)
            await observe.start()
        except OSError as exc:
            sys.stderr.write("%s: error: %s\n" % (PROG, _open_error(args, links, started, exc)))
            sys.stderr.flush()
            return 1
        banner = "; ".join(link.describe() for link in started)
        if observe.describe():
            banner += "; " + observe.describe()
        sys.stdout.write("%s: %s (middleware %s)\n" % (PROG, banner, args.middleware))
        sys.stdout.flush()
        loop.add_signal_handler(signal.SIGUSR1, _print_stats, agent, started)
        stopped = asyncio.ensure_future(stop.wait())
        done, _ = await asyncio.wait({run_task, stopped}, return_when=asyncio.FIRST_COMPLETED)
        if run_task in done and run_task.exception() is not None:
            logging.getLogger("xrce.agent").error("agent stopped: %r", run_task.exception())
            stopped.cancel()
            return 1
        stopped.cancel()
        return 0
    finally:
        if run_task is not None and not run_task.done():
            run_task.cancel()
            try:
                await run_task
            except asyncio.CancelledError:
                pass
        # The engine first, so DELETE-time replies can still go out through the open links.
        await agent.close()
        if observe is not None:  # after the engine, so a capture ends with the DELETE replies
            await observe.close()
        for link in reversed(started):
            await link.close()
        for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGUSR1):
            loop.remove_signal_handler(signum)


def _open_error(args, links, started, exc):
    """What could not be opened, by flag and port: the errno alone does not say which."""
    # asyncio's servers wrap the errno in their own sentence; the errno's own words are enough.
    reason = os.strerror(exc.errno) if exc.errno else (exc.strerror or str(exc))
    if getattr(exc, "filename", None):  # a file, not a socket
        return "cannot open %s: %s" % (exc.filename, reason)
    pending = [link for link in links if link not in started]
    if pending:
        link = pending[0]
        port = getattr(link, "requested_port", None)
        if port is not None:
            hint = " (another agent there? choose another -p)" if exc.errno == errno.EADDRINUSE else ""
            return "cannot open %s port %d (-p): %s%s" % (link.name, port, reason, hint)
        return "cannot open %s: %s" % (link.describe(), reason)
    if getattr(args, "discovery", None) is not None and not any(
            isinstance(link, udp.DiscoveryServer) for link in started):
        return "cannot open discovery port %d (-d): %s" % (args.discovery, reason)
    if getattr(args, "stats_port", None) is not None:
        return "cannot open stats port %d (--stats-port): %s" % (args.stats_port, reason)
    return reason


def _print_stats(agent, links):
    """SIGUSR1: one ``xrce-agent: stats {json}`` line on stdout with the engine's and every link's
    counters, for scripts and tests watching a running agent."""
    import json

    report = {"engine": agent.stats.as_dict(), "clients": len(agent.clients),
              "links": {link.name: link.stats.as_dict() for link in links}}
    sys.stdout.write("%s: stats %s\n" % (PROG, json.dumps(report, sort_keys=True)))
    sys.stdout.flush()


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    row = SUBCOMMANDS[args.subcommand]
    if row.run is not None:
        return row.run(args)
    if getattr(args, "allow_from", None) and args.subcommand not in _IP_SUBCOMMANDS:
        parser.error("--allow-from needs an IP link (udp4, udp6, tcp4, tcp6), not %s"
                     % args.subcommand)
    try:
        check_paths(args)
        refs = load_refs(args.refs) if args.refs else None
    except CliError as exc:
        parser.error(str(exc))
    del parser  # the agent runs for days: not with every subcommand's options kept alive
    configure_logging(args.verbose)
    if args.interfaces:  # the build code loads only when there is something to tell it
        interfaces.add_search_dirs(args.interfaces)
    if args.middleware == "dds":
        from xrce.agent.middleware.ros import env as rosenv
        try:  # the one line saying which ROS 2, rclpy and RMW this agent joins
            rosenv.log_ros_in_use(logging.getLogger("xrce.agent.rosenv"))
        except rosenv.RosUnavailable as exc:
            sys.stderr.write("%s: error: %s\n" % (PROG, exc))
            sys.stderr.flush()
            return 1
        from xrce.agent.middleware.ros import fastdds_profile, rclpy_services
        rclpy_services.defer_unused()  # before anything imports rclpy.node
        profile = fastdds_profile.install()  # before any participant: Fast DDS reads it once
        if profile:
            logging.getLogger("xrce.agent.rosenv").debug("Fast DDS participant profile: %s", profile)
    try:
        return asyncio.run(serve(args, refs))
    except KeyboardInterrupt:  # a second Ctrl-C during shutdown
        return 130


if __name__ == "__main__":
    sys.exit(main())
