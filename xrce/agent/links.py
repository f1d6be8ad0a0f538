"""What every agent link shares: its traffic counters and the guarded hand-off to the engine.

Every link has a ``name``, a ``stats`` (``LinkStats``) and ``send(endpoint, data) -> bool``, and hands
each complete XRCE message it receives to ``receiver.receive(link, endpoint, data)`` (the protocol
engine). What an endpoint is depends on the link:

- UDP: the datagram's source address tuple (``xrce.agent.udp_links``);
- TCP: the ``TcpConnection`` object of the stream (``xrce.agent.tcp_links``);
- serial / multiserial / pseudoterminal: ``(port_name, remote_serial_address)``
  (``xrce.agent.serial_links``).

A malformed datagram or frame, or an exception raised by the receiver, is logged and counted as a
drop; nothing raises into the event loop. The byte framers themselves live in
``xrce.transports.framing`` (shared with the client).

If the receiver has an ``endpoint_closed(link, endpoint)`` method, it is called when a TCP
connection or a serial port goes away, so the engine can forget the sessions mapped to it.
"""

from __future__ import annotations

import logging

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


class Link:
    """Common part of every server: counters and the guarded hand-off to the receiver."""

    name = "link"
    # True when send() may be called from any thread (the engine then delivers a sample from the
    # middleware's thread without waking the loop); asyncio transports are loop-only.
    sends_from_any_thread = False

    def __init__(self, receiver):
        self.receiver = receiver
        self.stats = LinkStats()

    def describe(self):
        """A short human description for the start-up banner, valid once started."""
        return self.name

    def _deliver(self, endpoint, message):
        self.stats.messages_in += 1
        try:
            self.receiver.receive(self, endpoint, message)
        except Exception:  # one bad message must not take the loop (and every other client) down
            self.stats.drops += 1
            log.exception("%s: receiver failed on a %d-byte message from %r",
                          self.name, len(message), endpoint)

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



__all__ = ["LinkStats", "Link", "MAX_MESSAGE_SIZE", "MAX_PENDING_OUTPUT"]
