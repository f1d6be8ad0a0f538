"""The agent's transport subcommands (udp4/udp6, tcp4/tcp6, serial, multiserial,
pseudoterminal): the options each takes, those every agent takes, and the links each opens.

Only the chosen subcommand's options are built (xrce.agent.cli.subcommands), and the TCP and
serial link modules are imported only by the subcommands that serve them.
"""

from __future__ import annotations

import argparse
import socket
import sys

from xrce.agent import links
from xrce.agent.cli.arguments import (allow_list, baudrate, milliseconds, port, positive,
                                      positive_seconds, seconds, verbosity)
from xrce.command_line import domain_id

IP_SUBCOMMANDS = ("udp4", "udp6", "tcp4", "tcp6")


# ----------------------------------------------------------------------------- options every agent takes

def _add_session_options(parser):
    from xrce.agent.engine import limits  # no rclpy behind it; the defaults are documented there

    group = parser.add_argument_group("client liveliness and per-client quotas")
    group.add_argument("--client-dead-time", type=milliseconds, metavar="MS",
                       default=int(limits.CLIENT_DEAD_TIME * 1000),
                       help="a client silent this long is dead: no more HEARTBEATs to it, entities "
                            "kept, any message revives it (default %(default)s, as eProsima); a "
                            "dead client certainly gone is deleted (retired): its TCP connection "
                            "or serial port closed, or a newer client from its address created "
                            "its participant. A new key on a session's address and port (or "
                            "serial device) replaces it at once")
    group.add_argument("--client-expire-time", type=milliseconds, metavar="MS",
                       default=int(limits.CLIENT_EXPIRE_TIME * 1000),
                       help="a client silent this long (since its last message, whatever the "
                            "dead time) is deleted with all its ROS entities; 0 = never: a board "
                            "asleep keeps its session (default, as eProsima without uxr_hl)")
    group.add_argument("--max-clients", type=positive, metavar="N", default=limits.MAX_CLIENTS,
                       help="sessions at once; a new one evicts the longest-dead client or is "
                            "refused with ERR_RESOURCES (default %(default)s)")
    group.add_argument("--max-objects", type=positive, metavar="N",
                       default=limits.MAX_OBJECTS_PER_CLIENT,
                       help="XRCE objects per client; beyond, CREATE gets ERR_RESOURCES "
                            "(default %(default)s)")
    group.add_argument("--max-reassembly", type=positive, metavar="BYTES",
                       default=limits.MAX_REASSEMBLY,
                       help="largest fragmented message per client and stream (default %(default)s)")
    group.add_argument("--max-output-queue", type=positive, metavar="BYTES",
                       default=limits.MAX_OUTPUT_QUEUE_BYTES,
                       help="sample bytes queued towards one client; the oldest are dropped "
                            "beyond (default %(default)s)")
    group.add_argument("--max-client-memory", type=positive, metavar="BYTES",
                       default=limits.MAX_CLIENT_BYTES,
                       help="bytes one client's buffers may hold (out-of-order input, reassembly, "
                            "parked messages, output queues and windows); beyond, its reliable "
                            "input waits unacknowledged and its output is dropped "
                            "(default %(default)s)")
    group.add_argument("--max-memory", type=positive, metavar="BYTES",
                       default=limits.MAX_TOTAL_BYTES,
                       help="the same, all clients together (default %(default)s)")


def _add_admission_options(parser):
    from xrce.agent import allow_lists

    group = parser.add_argument_group("admission (XRCE has no authentication: see README)")
    group.add_argument("--allow-keys", type=allow_list(allow_lists.parse_keys),
                       metavar="KEY[,KEY...]",
                       help="open sessions only for these client keys (hex, e.g. 0xAABBCCDD); "
                            "others get ERR_DENIED and a (rate-limited) log line")
    group.add_argument("--allow-from", type=allow_list(allow_lists.parse_networks),
                       metavar="CIDR[,CIDR...]",
                       help="open sessions only for clients from these addresses/networks "
                            "(udp4/udp6/tcp4/tcp6)")


def _add_state_options(parser):
    group = parser.add_argument_group("state that outlives the agent (docs/RECOVERY.md)")
    choice = group.add_mutually_exclusive_group()
    choice.add_argument("--state", metavar="FILE",
                        help="keep what clients told the agent (sessions, entities, standing "
                             "READ_DATAs) in this SQLite file, so that a restarted agent resumes "
                             "boards that never re-create their session (default: "
                             "$XDG_STATE_HOME/xrce/TRANSPORT-PORT.sqlite3, one per transport and "
                             "port or device; none for -p 0 or a pseudoterminal)")
    choice.add_argument("--no-state", action="store_true",
                        help="keep nothing: a restarted agent knows no session")


class _MiddlewareAction(argparse.Action):
    """``-m rtps`` is served as ``-m dds``, with one line saying so. eProsima's agent puts a
    client's entities on Fast DDS's RTPS layer for rtps and on its DDS layer for dds; peers on
    the network see the same RTPS writers and readers either way, and this agent has one Fast
    DDS path (the ROS 2 one, and plain DDS topics beside it)."""

    def __call__(self, parser, namespace, values, option_string=None):
        if values == "rtps":
            sys.stderr.write("%s: -m rtps is served as -m dds (the same DDS entities on the "
                             "network as eProsima's RTPS-layer middleware)\n" % parser.prog)
            values = "dds"
        setattr(namespace, self.dest, values)


def _add_naming_options(parser):
    """What the agent names every board's entities (issue 53; xrce.agent.middleware.ros.naming):
    one firmware image for a whole fleet. ``--ros-args -r`` is taken out of the command line
    before argparse (``cli.main``): outside it, ``-r`` is ``--refs``."""
    group = parser.add_argument_group(
        "names given to the boards (-m dds; also --ros-args -r __ns:=/NS -r FROM:=TO [--])")
    group.add_argument("--namespace", metavar="NS",
                       help="put every board's ROS names and nodes under NS, as -r __ns:=/NS; "
                            "global topics stay as they are")
    group.add_argument("--domain", type=domain_id, metavar="N",
                       help="put every board's participant in ROS domain N, whatever domain it "
                            "asks for")
    group.add_argument("--global-topics", metavar="NAMES", default="/tf,/tf_static,/clock",
                       help="comma-separated absolute names kept out of the namespace "
                            "(default %(default)s)")
    group.add_argument("--fleet", metavar="FILE",
                       help="a TOML file of [[board]] rules giving boards, by client key, "
                            "source address or serial device, their own namespace, remaps and "
                            "domain over the options above (first match wins; SIGHUP reads it "
                            "again for boards created afterwards; docs/ARCHITECTURE.md)")


def add_common_options(parser):
    from xrce.agent.observe import observability

    parser.add_argument("-v", "--verbose", type=verbosity, default=4, metavar="LEVEL",
                        help="log level 0 (off) .. 4 (info, default) .. 5 (debug) .. 6 (trace)")
    _add_session_options(parser)
    _add_admission_options(parser)
    _add_state_options(parser)
    parser.add_argument("-m", "--middleware", choices=("dds", "rtps", "ced"), default="dds",
                        action=_MiddlewareAction,
                        help="dds: ROS 2 through rclpy, other types as plain DDS topics "
                             "(default); rtps: the same as dds; ced: route between clients only")
    from xrce.agent.middleware.ros import DOMAIN_LINGER_S, REQUEST_TIMEOUT_S  # no rclpy behind

    parser.add_argument("--domain-linger", type=seconds, metavar="S", default=DOMAIN_LINGER_S,
                        help="-m dds: a ROS domain is joined with its first client participant "
                             "and left this long after its last one is deleted (default "
                             "%(default)s; 0: at once)")
    parser.add_argument("--request-timeout", type=positive_seconds, metavar="S",
                        default=REQUEST_TIMEOUT_S,
                        help="-m dds: a service request waits this long for its reply (from a "
                             "board's replier, or from ROS for a board's requester) before it is "
                             "forgotten (default %(default)s; an action's get_result waits for "
                             "its goal however long)")
    _add_naming_options(parser)
    parser.add_argument("-r", "--refs", metavar="FILE",
                        help="Fast DDS XML profiles file for objects created by reference")
    parser.add_argument("--interfaces", action="append", default=[], metavar="DIR",
                        help="also look here for interface packages to build when a client names "
                             "a type that is not installed (repeatable; the packages shipped with "
                             "xrce are always searched)")
    observability.add_agent_options(parser)


# ----------------------------------------------------------------------------- per transport

def add_ip_options(parser):
    from xrce.agent.links import udp

    parser.add_argument("-p", "--port", type=port, required=True,
                        help="UDP/TCP port to serve (0: any free port, shown in the banner)")
    parser.add_argument("-d", "--discovery", type=port, nargs="?", const=udp.DISCOVERY_PORT,
                        metavar="PORT", help="answer discovery requests on PORT (default 7400)")


def add_tcp_options(parser):
    add_ip_options(parser)
    parser.add_argument("--max-connections", type=int,
                        default=links.DEFAULT_TCP_MAX_CONNECTIONS, metavar="N",
                        help="simultaneous TCP connections (default 100)")


def _add_crc_option(parser):
    parser.add_argument("--crc", choices=("arc", "ccitt"), default="arc",
                        help="frame checksum: CRC-16/ARC (default, as eProsima) or CRC-16/X.25")


def _add_baudrate_option(parser):
    parser.add_argument("-b", "--baudrate", type=baudrate, default=links.DEFAULT_BAUDRATE,
                        metavar="BAUD", help="line speed; the board must use the same "
                                             "(default %(default)s, as eProsima)")


def add_serial_options(parser):
    parser.add_argument("-D", "--dev", required=True, metavar="DEVICE",
                        help="serial device or glob (waited for until it appears; reopened when "
                             "it comes back after vanishing)")
    _add_baudrate_option(parser)
    _add_crc_option(parser)


def add_multiserial_options(parser):
    parser.add_argument("--devs", required=True, metavar='"DEV1 DEV2 ..."',
                        help="space-separated serial devices")
    _add_baudrate_option(parser)
    _add_crc_option(parser)


def add_pty_options(parser):
    parser.add_argument("-D", "--dev", metavar="PATH",
                        help="also make PATH a symbolic link to the pseudoterminal")
    _add_crc_option(parser)


# ----------------------------------------------------------------------------- link factories

def udp_links(family):
    def make_links(args, agent):
        from xrce.agent.links import udp
        return [udp.UdpServer(agent, args.port, family=family)]
    return make_links


def tcp_links(family):
    def make_links(args, agent):
        from xrce.agent.links import tcp
        return [tcp.TcpServer(agent, args.port, family=family,
                              max_connections=args.max_connections)]
    return make_links


def serial_links(args, agent):
    from xrce.agent.links import serial
    return [serial.SerialServer(agent, [args.dev], baudrate=args.baudrate, crc=args.crc)]


def multiserial_links(args, agent):
    from xrce.agent.links import serial
    devices = args.devs.split()
    return [serial.SerialServer(agent, devices, baudrate=args.baudrate, crc=args.crc)]


def pty_links(args, agent):
    from xrce.agent.links import serial
    return [serial.PseudoterminalServer(agent, symlink=args.dev, crc=args.crc)]


def state_path(args):
    """The state store's file for ``args``: --state, else the default for the transport and
    its port or device; None with --no-state, and where nothing lasts across a restart to key a
    default by (a free port, -p 0, or a pseudoterminal made anew at each start)."""
    if getattr(args, "no_state", False):
        return None
    if getattr(args, "state", None):
        return args.state
    from xrce.agent.state.store import default_directory, default_name
    import os

    subcommand = args.subcommand
    if subcommand in IP_SUBCOMMANDS:
        if not args.port:
            return None
        where = str(args.port)
    elif subcommand == "serial":
        where = args.dev
    elif subcommand == "multiserial":
        where = "+".join(args.devs.split())
    else:
        return None
    return os.path.join(default_directory(), default_name(subcommand, where))


# (name, help, add_options, make_links) of every transport, in the order --help lists them.
TRANSPORTS = (
    ("udp4", "serve UDP over IPv4", add_ip_options, udp_links(socket.AF_INET)),
    ("udp6", "serve UDP over IPv6", add_ip_options, udp_links(socket.AF_INET6)),
    ("tcp4", "serve TCP over IPv4", add_tcp_options, tcp_links(socket.AF_INET)),
    ("tcp6", "serve TCP over IPv6", add_tcp_options, tcp_links(socket.AF_INET6)),
    ("serial", "serve one serial device", add_serial_options, serial_links),
    ("multiserial", "serve several serial devices", add_multiserial_options, multiserial_links),
    ("pseudoterminal", "create a pseudoterminal and serve it", add_pty_options, pty_links),
)
