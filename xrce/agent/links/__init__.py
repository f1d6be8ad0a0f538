"""What every agent link shares: its traffic counters and the guarded hand-off to the engine.

Every link has a ``name``, a ``stats`` (``LinkStats``) and ``send(endpoint, data) -> bool``, and hands
each complete XRCE message it receives to ``receiver.receive(link, endpoint, data)`` (the protocol
engine). What an endpoint is depends on the link:

- UDP: the datagram's source address tuple (``xrce.agent.links.udp``);
- TCP: the ``TcpConnection`` object of the stream (``xrce.agent.links.tcp``);
- serial / multiserial / pseudoterminal: ``(port_name, remote_serial_address)``
  (``xrce.agent.links.serial``).

A malformed datagram or frame, or an exception raised by the receiver, is logged and counted as a
drop; nothing raises into the event loop. The byte framers themselves live in
``xrce.transports.framing`` (shared with the client).

A link that hears only what it cannot decode (frames failing their CRC at the wrong baud rate,
datagrams that are not XRCE) says so once at the default verbosity, rate-limited
(``UndecodableHint``): otherwise a wrong setting looks exactly like a board that is not there.

If the receiver has an ``endpoint_closed(link, endpoint)`` method, it is called when a TCP
connection or a serial port goes away, so the engine can forget the sessions mapped to it; a UDP
link asks a receiver with an ``attach_compiled_path(link, sock)`` method (the agent's engine) for
the compiled receive path that reads its socket (``fastpath``, None when Python reads it).
"""

from __future__ import annotations

import logging
import time

# Every link module logs here, under the name these links have always logged under, so that
# existing log filters keep matching.
log = logging.getLogger("xrce.agent.servers")

# Like eProsima's SERVER_BUFFER_SIZE: the largest message any link accepts.
MAX_MESSAGE_SIZE = 65535
# Bytes queued towards one slow TCP peer or serial port before further replies are dropped: the
# reliable streams resend what matters, and memory stays bounded whatever the peer does.
MAX_PENDING_OUTPUT = 256 * 1024
# The command line's defaults, here so that parsing it does not import the serial and TCP links
# (with crcmod, termios and the framers) into a UDP agent.
DEFAULT_BAUDRATE = 115200
DEFAULT_TCP_MAX_CONNECTIONS = 100


class LinkStats:
    """Traffic counters of one link. ``drops`` counts messages or frames thrown away for any reason
    (malformed, oversize, unreachable peer, receiver error, output queue full)."""

    __slots__ = ("bytes_in", "bytes_out", "messages_in", "messages_out", "drops")

    def __init__(self):
        self.bytes_in = 0
        self.bytes_out = 0
        self.messages_in = 0
        self.messages_out = 0
        self.drops = 0

    def as_dict(self):
        return {name: getattr(self, name) for name in self.__slots__}

    def __repr__(self):
        return "LinkStats(%s)" % ", ".join("%s=%d" % item for item in self.as_dict().items())


class UndecodableHint:
    """One WARNING when ``THRESHOLD`` undecodable messages or frames arrive in a row with nothing
    decodable between them, then at most one every ``PERIOD_S`` while it goes on. Anything
    decodable starts the count again."""

    THRESHOLD = 10
    PERIOD_S = 60.0

    __slots__ = ("link", "in_a_row", "next_allowed")

    def __init__(self, link):
        self.link = link
        self.in_a_row = 0
        self.next_allowed = 0.0

    def bad(self, count=1, where=None):
        self.in_a_row += count
        if self.in_a_row < self.THRESHOLD:
            return
        now = time.monotonic()
        if now < self.next_allowed:
            return
        self.next_allowed = now + self.PERIOD_S
        link = self.link
        log.warning("%s: %d %s in a row%s and nothing decodable: %s (said at most once a minute)",
                    link.name, self.in_a_row, link.undecodable_what,
                    " from %s" % (where,) if where is not None else "", link.undecodable_advice())

    def good(self):
        self.in_a_row = 0


class Link:
    """Common part of every server: counters and the guarded hand-off to the receiver."""

    name = "link"
    # True when send() may be called from any thread (the engine then delivers a sample from the
    # middleware's thread without waking the loop); asyncio transports are loop-only.
    sends_from_any_thread = False
    # The compiled receive path reading this link's socket (UDP's, where it is built), and the
    # locators the engine's INFO names: what ``xrce.agent.engine.link.Link`` declares.
    fastpath = None
    info_locators = ()

    undecodable_what = "messages that are not XRCE"

    def __init__(self, receiver):
        self.receiver = receiver
        self.stats = LinkStats()
        self.undecodable = UndecodableHint(self)
        # The engine counts what it cannot decode; a receiver without counters gives no hint.
        self._receiver_stats = getattr(receiver, "stats", None)
        if not hasattr(self._receiver_stats, "decode_errors"):
            self._receiver_stats = None

    def describe(self):
        """A short human description for the start-up banner, valid once started."""
        return self.name

    def undecodable_advice(self):
        """What to check when only undecodable input arrives (UndecodableHint)."""
        return ("is something other than an XRCE client (micro-ROS, xrce) sending to this %s, "
                "or a client of another protocol version?" % self.describe())

    def _deliver(self, endpoint, message):
        self.stats.messages_in += 1
        counters = self._receiver_stats
        errors_before = counters.decode_errors if counters is not None else 0
        try:
            self.receiver.receive(self, endpoint, message)
        except Exception:  # one bad message must not take the loop (and every other client) down
            self.stats.drops += 1
            log.exception("%s: receiver failed on a %d-byte message from %r",
                          self.name, len(message), endpoint)
        if counters is not None:
            if counters.decode_errors != errors_before:
                self.undecodable.bad(where=endpoint)
            elif self.undecodable.in_a_row:
                self.undecodable.good()

    def _endpoint_closed(self, endpoint):
        hook = getattr(self.receiver, "endpoint_closed", None)
        if hook is None:
            return
        try:
            hook(self, endpoint)
        except Exception:
            log.exception("%s: receiver failed to forget endpoint %r", self.name, endpoint)

    async def start(self):
        raise NotImplementedError

    async def close(self):
        raise NotImplementedError



__all__ = ["LinkStats", "Link", "UndecodableHint", "MAX_MESSAGE_SIZE", "MAX_PENDING_OUTPUT"]
