"""``xrce-client``: poke an XRCE agent from a shell, without a board (CPython only).

    xrce-client ping udp4 [--agent 127.0.0.1] -p 8888 [--timeout-ms 1000] [--attempts 3]
    xrce-client pub udp4 -p 8888 --topic chatter --type std_msgs/msg/String --data hello
                [--count N] [--rate HZ] [--reliable] [--node NAME] [--domain N] [--key HEX]
    xrce-client sub udp4 -p 8888 --topic cmd_vel --type geometry_msgs/msg/Twist
                [--count N] [--timeout-ms T] [--reliable | --best-effort]
    xrce-client build-mpy OUTDIR

Transports (the agent's words): ``udp4``/``udp6``/``tcp4``/``tcp6`` with ``--agent HOST -p PORT``
(host defaults to 127.0.0.1, or ::1 for the v6 ones), ``serial --dev DEV [-b BAUD] [--crc arc|ccitt]``.

stdout carries the results (one line per pong, published or received message) so that scripts can
read them; progress and errors go to stderr. Exit codes: 0 success (also after Ctrl-C or SIGTERM,
which delete the session first), 1 the agent did not answer or refused, 2 bad arguments (one
``xrce-client: error: ...`` line on stderr).
"""

import argparse
import signal
import socket
import sys
import time

from xrce import constants as C, names as wire_names

PROG = "xrce-client"
EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2

IP_TRANSPORTS = {
    "udp4": ("udp", socket.AF_INET, "127.0.0.1"),
    "udp6": ("udp", socket.AF_INET6, "::1"),
    "tcp4": ("tcp", socket.AF_INET, "127.0.0.1"),
    "tcp6": ("tcp", socket.AF_INET6, "::1"),
}
TRANSPORTS = tuple(IP_TRANSPORTS) + ("serial",)

# A bounded wait for each step that needs the agent's answer: a CLI must never hang on a dead agent.
CREATE_ATTEMPTS = 5
CREATE_TIMEOUT_MS = 500
STATUS_TIMEOUT_MS = 3000
DELIVERY_TIMEOUT_MS = 1000
DELETE_ATTEMPTS = 3
DELETE_TIMEOUT_MS = 300
SPIN_SLICE_MS = 100


class UsageError(Exception):
    """An argument that argparse accepted but that makes no sense (reported like argparse's)."""


class AgentError(Exception):
    """The agent did not answer or refused; reported as one line, exit code 1."""


class ArgumentParser(argparse.ArgumentParser):
    """argparse with a one-line error report: scripts and tests read stderr, not a usage dump."""

    def error(self, message):
        _usage_exit(message)


def _usage_exit(message):
    sys.stderr.write("%s: error: %s\n" % (PROG, message))
    sys.stderr.flush()
    raise SystemExit(EXIT_USAGE)


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


def _domain(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid domain id: %r" % text)
    if not 0 <= value <= 232:  # the largest id whose RTPS ports still fit in 16 bits
        raise argparse.ArgumentTypeError("domain id %d is not in 0..232" % value)
    return value


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
    parser.add_argument("-b", "--baudrate", type=_positive_int, default=115200, help="serial baud rate")
    parser.add_argument("--crc", choices=("arc", "ccitt"), default="arc",
                        help="serial frame checksum: CRC-16/ARC (default, as eProsima) or CRC-16/X.25")


def _add_entity_arguments(parser):
    parser.add_argument("--topic", required=True, help="ROS topic name (chatter or /chatter)")
    parser.add_argument("--type", dest="type_name", required=True, metavar="TYPE",
                        help="ROS message type, e.g. std_msgs/msg/String")
    parser.add_argument("--node", default="xrce_client", help="participant (ROS node) name")
    parser.add_argument("--domain", type=_domain, default=0, help="ROS domain id (default 0)")
    parser.add_argument("--key", type=_client_key, help="client key, 8 hex digits (default random)")
    parser.add_argument("--count", type=_count, help="messages to publish/receive (0: until Ctrl-C)")


def build_parser():
    parser = ArgumentParser(prog=PROG, description="Talk to a Micro XRCE-DDS agent from a shell.")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND")
    commands.required = True

    ping = commands.add_parser("ping", help="check that an agent answers (session-less GET_INFO)")
    _add_transport_arguments(ping)
    ping.add_argument("--timeout-ms", type=_positive_int, default=1000, help="wait per attempt")
    ping.add_argument("--attempts", type=_positive_int, default=3, help="GET_INFO requests to send")

    pub = commands.add_parser("pub", help="publish messages on a topic")
    _add_transport_arguments(pub)
    _add_entity_arguments(pub)
    pub.add_argument("--data", help="the message: a plain value for one-field types, else YAML")
    pub.add_argument("--rate", type=_rate, default=10.0, help="messages per second (default 10)")
    pub.add_argument("--reliable", action="store_true",
                     help="reliable stream and QoS; wait for the agent to confirm each message")

    sub = commands.add_parser("sub", help="print the messages of a topic, one per line")
    _add_transport_arguments(sub)
    _add_entity_arguments(sub)
    sub.add_argument("--timeout-ms", type=_positive_int,
                     help="give up (exit 1) if --count messages have not arrived by then")
    # Best effort by default: a best-effort reader matches both kinds of writer, a reliable one
    # only reliable writers, so the default sees every publisher.
    qos = sub.add_mutually_exclusive_group()
    qos.add_argument("--reliable", dest="reliable", action="store_true", default=False,
                     help="reliable QoS and stream")
    qos.add_argument("--best-effort", dest="reliable", action="store_false",
                     help="best-effort QoS and stream (default)")

    build = commands.add_parser("build-mpy", help="compile the client for MicroPython (.mpy files)")
    build.add_argument("outdir", metavar="OUTDIR")
    return parser


# ----------------------------------------------------------------------------- transports

def agent_address(args):
    """How to name the agent in messages: HOST:PORT ([HOST]:PORT for IPv6) or the device."""
    if args.transport == "serial":
        return args.dev
    host = args.host
    if ":" in host:
        return "[%s]:%d" % (host, args.port)
    return "%s:%d" % (host, args.port)


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


def open_transport(args):
    """The client transport the arguments describe; TransportError if it cannot be opened."""
    if args.transport == "serial":
        from xrce.transports.serial import SerialTransport

        return SerialTransport(args.dev, args.baudrate, crc=args.crc)
    kind, family, _ = IP_TRANSPORTS[args.transport]
    if kind == "udp":
        from xrce.transports.udp import UdpTransport

        return UdpTransport(args.host, args.port, family=family)
    from xrce.transports.tcp import TcpTransport

    return TcpTransport(args.host, args.port, family=family)


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
    from xrce.errors import EncodeError

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
    from xrce.errors import EncodeError

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


def _say(line, stream=None):
    stream = sys.stdout if stream is None else stream
    stream.write(line + "\n")
    stream.flush()


# ----------------------------------------------------------------------------- commands

def run_ping(args):
    from xrce.client.session import ping_agent

    transport = open_transport(args)
    try:
        rtt_us = ping_agent(transport, args.timeout_ms, args.attempts)
    finally:
        transport.close()
    where = agent_address(args)
    if rtt_us is None:
        raise AgentError("no agent answered at %s after %d attempt%s" % (
            where, args.attempts, "" if args.attempts == 1 else "s"))
    _say("pong from %s in %.2f ms" % (where, rtt_us / 1000.0))
    return EXIT_OK


class _Connection:
    """A created session that is deleted (logout) and closed however the command ends."""

    def __init__(self, args):
        from xrce.client.session import Session

        self.where = agent_address(args)
        self.transport = open_transport(args)
        self.session = Session(self.transport, key=args.key)

    def __enter__(self):
        session = self.session
        try:
            if not session.create(CREATE_ATTEMPTS, CREATE_TIMEOUT_MS):
                if session.create_status is None:
                    raise AgentError("no agent answered CREATE_CLIENT at %s" % self.where)
                raise AgentError("agent at %s refused the session (status %s)" % (
                    self.where, _status_name(session.create_status)))
        except BaseException:
            self.transport.close()
            raise
        return session

    def __exit__(self, exc_type, exc, tb):
        try:
            if self.session.connected:
                self.session.delete(DELETE_ATTEMPTS, DELETE_TIMEOUT_MS)
        except Exception:  # the link may be what failed; closing is all that is left to do
            pass
        finally:
            self.transport.close()
        return False




def _status_name(status):
    return wire_names.STATUS_NAMES.get(status, "0x%02X" % status)


def _require_statuses(session, what):
    if not session.run_until_all_status(STATUS_TIMEOUT_MS):
        failed = [_status_name(s) for s in session.last_statuses.values()
                  if s not in (C.STATUS_OK, C.STATUS_OK_MATCHED)]
        raise AgentError("agent did not create the %s (status %s)" % (what, ", ".join(failed)))


def _qos_name(reliable):
    return "reliable" if reliable else "best-effort"


def run_pub(args):
    msg_class = resolve_type(args.type_name)
    message = parse_data(msg_class, args.data)
    line = format_message(message)
    count = 1 if args.count is None else args.count
    period = 1.0 / args.rate
    with _Connection(args) as session:
        node = session.create_participant(domain_id=args.domain, name=args.node)
        writer = session.create_writer(node, args.topic, msg_class, reliable=args.reliable)
        _require_statuses(session, "writer for %s" % args.topic)
        stream_id = session.reliable if args.reliable else session.best_effort
        unconfirmed = 0
        sent = 0
        next_due = time.monotonic()
        while count == 0 or sent < count:
            wait_ms = int((next_due - time.monotonic()) * 1000)
            if wait_ms > 0:
                session.run_until_timeout(wait_ms)  # keeps answering heartbeats and acknacks
            lost = session.link_state == "lost"  # the session drops writes until it is back
            written = session.write(writer, message, stream_id)
            sent += 1
            note = ""
            if lost:
                note = " (not sent: agent lost, re-creating the session)"
            elif not written:
                raise AgentError("the agent at %s did not free the reliable window" % agent_address(args))
            elif args.reliable:
                if session.run_until_confirm_delivery(DELIVERY_TIMEOUT_MS):
                    note = " (confirmed)"
                else:
                    unconfirmed += 1
                    note = " (not confirmed within %d ms)" % DELIVERY_TIMEOUT_MS
            else:
                session.flush()
            if count:
                _say("published %d/%d on %s: %s%s" % (sent, count, args.topic, line, note))
            else:
                _say("published %d on %s: %s%s" % (sent, args.topic, line, note))
            next_due += period
    if unconfirmed:
        raise AgentError("%d of %d messages were not confirmed by the agent" % (unconfirmed, sent))
    return EXIT_OK


def run_sub(args):
    msg_class = resolve_type(args.type_name)
    count = 0 if args.count is None else args.count
    received = [0]

    def on_message(message):
        if count and received[0] >= count:
            return  # several samples can share one message; print exactly --count
        received[0] += 1
        _say(format_message(message))

    with _Connection(args) as session:
        node = session.create_participant(domain_id=args.domain, name=args.node)
        session.create_reader(node, args.topic, msg_class, on_message, reliable=args.reliable)
        _require_statuses(session, "reader for %s" % args.topic)
        _say("subscribed to %s (%s, %s)" % (args.topic, msg_class.ROS_TYPE, _qos_name(args.reliable)),
             sys.stderr)
        deadline = None if args.timeout_ms is None else time.monotonic() + args.timeout_ms / 1000.0
        while count == 0 or received[0] < count:
            slice_ms = SPIN_SLICE_MS
            if deadline is not None:
                left_ms = int((deadline - time.monotonic()) * 1000)
                if left_ms <= 0:
                    raise AgentError("timed out after %d ms with %d of %s messages on %s" % (
                        args.timeout_ms, received[0], count or "unlimited", args.topic))
                slice_ms = min(slice_ms, left_ms)
            session.spin_once(slice_ms)
    return EXIT_OK


def run_build_mpy(args):
    from xrce.tools import mpy  # CPython-only tooling, imported only for this command

    return mpy.main(["build-mpy", args.outdir])


COMMANDS = {
    "ping": run_ping,
    "pub": run_pub,
    "sub": run_sub,
    "build-mpy": run_build_mpy,
}


def _stop_on_sigterm():
    """SIGTERM ends the command like Ctrl-C, so that the session is deleted before exiting."""

    def raise_interrupt(signum, frame):
        raise KeyboardInterrupt

    try:
        signal.signal(signal.SIGTERM, raise_interrupt)
    except (ValueError, OSError):  # not the main thread: leave the default behaviour
        pass


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    from xrce.errors import XrceError

    try:
        if args.command != "build-mpy":
            check_transport_arguments(args)
        _stop_on_sigterm()
        return COMMANDS[args.command](args)
    except UsageError as error:
        _usage_exit(str(error))
    except KeyboardInterrupt:
        return EXIT_OK  # the session was deleted on the way out (_Connection.__exit__)
    except AgentError as error:
        _say("%s: %s" % (PROG, error), sys.stderr)
        return EXIT_FAILURE
    except (XrceError, OSError) as error:  # TransportError and socket failures: one line, not a trace
        _say("%s: %s" % (PROG, error), sys.stderr)
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
