"""What a running agent is doing: counters, a live stats view, /diagnostics and capture files.

- ``Observer`` turns the engine's counters (``AgentStats``, the per-client fields of
  ``ClientProxy``, per-entity sample counts, each link's ``LinkStats`` and frame decoders) into a
  JSON-able snapshot with per-client and per-topic rates. Rates are differences between two
  ``update_rates()`` calls, made once a second by ``Observability`` while anything shows them.
- ``StatsServer``: ``--stats-port PORT`` serves that snapshot as one JSON document to every TCP
  connection on 127.0.0.1 (TCP, not UDP: a thousand clients do not fit in one datagram).
  ``xrce-agent stats -p PORT`` polls it and redraws a terminal table (xrce.agent.observe.stats_view).
- At ``-v 5`` the agent logs a one-line summary (and one line per active client) periodically.
- With ``-m dds``, ``/diagnostics`` carries the snapshot into ROS (xrce.agent.observe.diagnostics).
- ``--capture FILE`` writes every message in both directions to a text file that
  ``read_capture``/``decode_capture`` read back (xrce.agent.observe.capture).

``Observability`` attaches the ones the command line asks for to one agent; each lives in the
module named above, readable alone.

Honest limits: the agent cannot know a client's clock offset. It reports ``rtt_ms``, the time from
its latest HEARTBEAT to the client's next ACKNACK (only while reliable output is unacknowledged),
and ``timestamp_skew_ms``, its receive time minus the transmit time in the client's last
TIMESTAMP (clock offset plus one-way delay). CRC failures are counted per link: a frame with a bad
CRC cannot be trusted to name its sender.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import socket
import struct
import time

from xrce.wire import constants as C
from xrce.agent.observe.diagnostics import DiagnosticsPublisher, diagnostic_array_type
from xrce.agent.observe.entities import DIRECTIONS, client_rule, describe
# In this module's __all__ too, as before they had a module of their own.
from xrce.agent.observe.names import (  # noqa: F401
    address_text, client_pseudonym, client_tag, endpoint_text, ros_topic_name, ros_type_name,
)
# The `xrce-agent stats` subcommand is registered (xrce/agent/cli/subcommands.py) through this module.

log = logging.getLogger("xrce.agent.observability")

DEFAULT_SUMMARY_PERIOD_S = 5.0
RATE_PERIOD_S = 1.0
_TOPIC_KINDS = {C.OBJK_DATAWRITER: "to_ros", C.OBJK_DATAREADER: "from_ros"}
_DESCRIBED = frozenset(DIRECTIONS) | {C.OBJK_PARTICIPANT}


def _link_crc_errors(link) -> int:
    ports = getattr(link, "ports", None)
    if not ports:
        return 0
    return sum(port.decoder.crc_errors for port in ports.values())


def _ms(seconds):
    return None if seconds is None else round(seconds * 1000.0, 3)


class Observer:
    """Snapshots of an ``Agent`` and its links, with rates between ``update_rates`` calls."""

    def __init__(self, agent, links=(), clock=time.monotonic):
        self.agent = agent
        self.links = list(links)
        self.clock = clock
        self.started = clock()
        self._previous = {}  # ("client", key) / ("topic", name, direction) -> (time, counters)
        self._rates = {}

    # -- collection ---------------------------------------------------------------------------

    def _client_counters(self, client):
        return (client.messages_in, client.messages_out, client.bytes_in, client.bytes_out)

    def _topic_totals(self):
        """{(topic, direction): [type, endpoints, samples, bytes]} over every client."""
        totals = {}
        for client in list(self.agent.clients.values()):
            for entry in list(client.objects.values()):
                direction = _TOPIC_KINDS.get(entry.kind)
                if direction is None or entry.topic_spec is None:
                    continue
                key = (entry.topic_spec.name, direction)
                row = totals.get(key)
                if row is None:
                    row = totals[key] = [entry.topic_spec.type_name, 0, 0, 0]
                row[1] += 1
                row[2] += entry.samples
                row[3] += entry.sample_bytes
        return totals

    def update_rates(self) -> None:
        """Per-second rates since the previous call (the first call only sets the baseline)."""
        now = self.clock()
        current = {}
        for client in list(self.agent.clients.values()):
            current[("client", client.key)] = self._client_counters(client)
        for (name, direction), row in self._topic_totals().items():
            current[("topic", name, direction)] = (row[2], row[3])
        rates = {}
        for key, counters in current.items():
            previous = self._previous.get(key)
            if previous is None:
                continue
            elapsed = now - previous[0]
            if elapsed <= 0:
                continue
            rates[key] = tuple(max(0, c - p) / elapsed for c, p in zip(counters, previous[1]))
        self._previous = {key: (now, counters) for key, counters in current.items()}
        self._rates = rates

    def restart_rates(self) -> None:
        """Forget the last counters: the next ``update_rates`` starts a new baseline (after a
        pause in the rounds, a rate over the whole pause would mislead)."""
        self._previous = {}
        self._rates = {}

    def snapshot(self, show_keys: bool = False) -> dict:
        """Everything the stats show. Each client by its ``tag`` (names.client_tag); its
        ``key`` as the client sent it only with ``show_keys`` (the reader may know it: see
        ``StatsServer``), None otherwise."""
        now = self.clock()
        agent = self.agent
        fold = getattr(agent, "fold_compiled", None)
        if fold is not None:
            fold()
        clients = []
        for client in list(agent.clients.values()):
            rates = self._rates.get(("client", client.key), (0.0, 0.0, 0.0, 0.0))
            entities = [describe(client, entry) for entry in list(client.objects.values())
                        if entry.kind in _DESCRIBED]
            participants = [e for e in entities if e["kind"] == "participant"]
            clients.append({
                "key": client.key.hex() if show_keys else None,
                "tag": client_tag(client.key),
                "session_id": client.session_id,
                # Restored from the state store (issue 51): "silent" until the board's first
                # message after the restart, then "spoke"; None for a client created in this run.
                "restored": ("spoke" if client.spoken else "silent") if client.restored else None,
                "link": client.link.name,
                "endpoint": endpoint_text(client.endpoint),
                "address": address_text(client.link.name, client.endpoint),
                "participants": participants,
                "endpoints": [e for e in entities if e["kind"] != "participant"],
                # The fleet rule that named the board (issue 53), None: the command line's naming
                # (its participants say what that gave them).
                "rule": client_rule({"participants": participants}),
                "objects": len(client.objects),
                "messages_in": client.messages_in,
                "messages_out": client.messages_out,
                "bytes_in": client.bytes_in,
                "bytes_out": client.bytes_out,
                "messages_in_per_s": round(rates[0], 1),
                "messages_out_per_s": round(rates[1], 1),
                "bytes_in_per_s": round(rates[2], 1),
                "bytes_out_per_s": round(rates[3], 1),
                "decode_errors": client.decode_errors,
                "duplicates": client.duplicates,
                "retransmissions": client.retransmissions,
                "rtt_ms": _ms(client.rtt_s),
                "timestamp_skew_ms": None if client.timestamp_skew_ns is None
                else round(client.timestamp_skew_ns / 1e6, 3),
                "last_seen_s": round(now - client.last_seen, 3),
                "age_s": round(now - client.created_at, 3),
            })
        topics = []
        for (name, direction), (type_name, endpoints, samples, size) in \
                sorted(self._topic_totals().items()):
            rates = self._rates.get(("topic", name, direction), (0.0, 0.0))
            topics.append({
                "topic": ros_topic_name(name), "type": ros_type_name(type_name),
                "dds_topic": name, "dds_type": type_name, "direction": direction,
                "endpoints": endpoints,
                "samples": samples, "bytes": size, "samples_per_s": round(rates[0], 1),
                "bytes_per_s": round(rates[1], 1),
            })
        links = []
        for link in self.links:
            row = {"name": link.name}
            row.update(link.stats.as_dict())
            row["crc_errors"] = _link_crc_errors(link)
            links.append(row)
        timelines = getattr(agent, "timelines", None)
        return {"time": time.time(), "uptime_s": round(now - self.started, 3),
                "keys_shown": show_keys, "agent": agent.stats.as_dict(), "links": links,
                "clients": clients, "topics": topics,
                "recoveries": [dict(t, key=t["key"] if show_keys else None,
                                    tag=client_tag(bytes.fromhex(t["key"])))
                               for t in timelines.snapshot()] if timelines is not None else []}


# ------------------------------------------------------------------------------------ live view

def _proc_net_address(host: str, port: int) -> str:
    """An address as /proc/net/tcp{,6} prints it: the address's 32-bit words in host order, hex."""
    if ":" in host:
        words = struct.unpack("=4I", socket.inet_pton(socket.AF_INET6, host))
    else:
        words = struct.unpack("=I", socket.inet_aton(host))
    return "%s:%04X" % ("".join("%08X" % word for word in words), port)


def connection_uid(peer, local):
    """The user id owning the other end of a loopback TCP connection (``peer`` connected to our
    ``local``), read from the kernel's socket table as ``ss -e`` does; None where unknown (not
    Linux, or the peer already gone)."""
    try:
        ours = _proc_net_address(local[0], local[1])
        theirs = _proc_net_address(peer[0], peer[1])
        with open("/proc/net/tcp6" if ":" in peer[0] else "/proc/net/tcp") as table:
            for line in table:
                fields = line.split()
                if len(fields) > 7 and fields[1] == theirs and fields[2] == ours:
                    return int(fields[7])
    except (OSError, ValueError, TypeError, IndexError, struct.error):
        pass
    return None


class StatsServer:
    """Every TCP connection on ``host:port`` gets the current snapshot as JSON, then EOF.

    Client keys are credentials (names.py): the snapshot names each client by the key it sent
    only to a reader who could read that key from the agent anyway, a process of the agent's own
    user or root (``connection_uid``); any other local user gets tags only, as before."""

    def __init__(self, observer: Observer, port: int, host: str = "127.0.0.1"):
        self.observer = observer
        self.host = host
        self.requested_port = port
        self.port = None
        self._server = None

    async def start(self) -> None:
        self._server = await asyncio.start_server(self._serve, self.host, self.requested_port,
                                                  reuse_address=True)
        self.port = self._server.sockets[0].getsockname()[1]

    def describe(self) -> str:
        return "stats on %s:%d" % (self.host, self.port)

    async def _serve(self, reader, writer) -> None:
        try:
            uid = connection_uid(writer.get_extra_info("peername"),
                                 writer.get_extra_info("sockname"))
            show_keys = uid is not None and uid in (0, os.geteuid())
            writer.write(json.dumps(self.observer.snapshot(show_keys)).encode() + b"\n")
            await writer.drain()
        except (ConnectionError, OSError):
            pass
        finally:
            writer.close()

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
            self._server = None


# ------------------------------------------------------------------------------------ wiring

CAPTURE_MAX_BYTES = 16 * 1024 * 1024  # xrce.agent.observe.capture: a flood fills 4 x 16 MiB at most
CAPTURE_FILES = 4
_MIN_CAPTURE_BYTES = 4096


def _capture_size(text):
    import argparse

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid size: %r" % text)
    if value < _MIN_CAPTURE_BYTES:
        raise argparse.ArgumentTypeError("capture files need at least %d bytes, not %d"
                                         % (_MIN_CAPTURE_BYTES, value))
    return value


def _capture_files(text):
    import argparse

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid number: %r" % text)
    if value < 1:
        raise argparse.ArgumentTypeError("must be at least 1, not %d" % value)
    return value


def add_agent_options(parser) -> None:
    """Options every agent transport subcommand gets."""
    parser.add_argument("--stats-port", type=int, metavar="PORT",
                        help="serve live counters as JSON on 127.0.0.1:PORT (0: any free port, "
                             "shown in the banner) for `xrce-agent stats -p PORT`")
    parser.add_argument("--capture", metavar="FILE",
                        help="record every message in both directions, with timestamps, to FILE "
                             "(mode 0600; client keys replaced by their tags)")
    parser.add_argument("--capture-max-bytes", type=_capture_size, metavar="BYTES",
                        default=CAPTURE_MAX_BYTES,
                        help="rotate the capture file past this size (default %(default)s)")
    parser.add_argument("--capture-files", type=_capture_files, metavar="N", default=CAPTURE_FILES,
                        help="capture files kept: FILE, FILE.1 .. FILE.N-1 (default %(default)s)")
    parser.add_argument("--summary-period", type=float, default=DEFAULT_SUMMARY_PERIOD_S,
                        metavar="S", help="seconds between -v 5 summaries (default 5)")
    parser.add_argument("--no-diagnostics", action="store_true",
                        help="do not publish /diagnostics (-m dds)")


class Observability:
    """The observer, stats server, capture file, /diagnostics and ``-v 5`` summaries, attached to
    one agent according to its command-line options."""

    def __init__(self, agent, links, *, stats_port=None, capture=None, summary_period=None,
                 middleware=None, diagnostics=True, capture_max_bytes=CAPTURE_MAX_BYTES,
                 capture_files=CAPTURE_FILES, raw_message_type=None):
        self.agent = agent
        self.observer = Observer(agent, links)
        self.stats_server = StatsServer(self.observer, stats_port) if stats_port is not None \
            else None
        self.capture = None
        if capture:
            from xrce.agent.observe.capture import CaptureWriter

            self.capture = CaptureWriter(capture, capture_max_bytes, capture_files)
        self.summary_period = summary_period
        self.diagnostics = None
        # raw_message_type: the ROS middleware's type lookup (diagnostic_array_type), None without.
        if (diagnostics and middleware is not None and raw_message_type is not None
                and hasattr(middleware, "agent_publisher")):
            message_type = diagnostic_array_type(raw_message_type)
            if message_type is not None:
                self.diagnostics = DiagnosticsPublisher(self.observer, middleware, message_type)
        # The once-a-second round (rates, capture flush, /diagnostics, summaries) runs only while
        # something shows its result: nothing polls in an agent nobody watches. /diagnostics
        # counts while some subscription matches the agent's publisher (its matched event), or
        # always where the RMW has no such event.
        self._always = stats_port is not None or capture is not None or bool(summary_period)
        self._diagnostics_publishers = []
        self._diagnostics_unmatched_events = False
        self._task = None
        self._closed = False

    @classmethod
    def from_args(cls, args, agent, links, middleware, raw_message_type=None):
        summary = args.summary_period if log.getEffectiveLevel() <= logging.DEBUG else None
        return cls(agent, links, stats_port=getattr(args, "stats_port", None),
                   capture=getattr(args, "capture", None), summary_period=summary,
                   middleware=middleware, diagnostics=not getattr(args, "no_diagnostics", False),
                   capture_max_bytes=getattr(args, "capture_max_bytes", CAPTURE_MAX_BYTES),
                   capture_files=getattr(args, "capture_files", CAPTURE_FILES),
                   raw_message_type=raw_message_type)

    async def start(self) -> None:
        if self.capture is not None:
            self.agent.tap = self.capture
        if self.stats_server is not None:
            await self.stats_server.start()
        if self.diagnostics is not None:
            self.diagnostics.middleware.add_domain_listener(self._watch_domain,
                                                            self._forget_domain)
        self._update_rounds()

    def _watch_domain(self, domain_id: int) -> None:
        publisher = self.diagnostics.publisher(domain_id, self._update_rounds)
        if publisher is None:
            return
        self._diagnostics_publishers.append((domain_id, publisher))
        self._update_rounds()

    def _forget_domain(self, domain_id: int) -> None:
        # A domain left takes its subscribers' matches with it, and no unmatched event comes
        # from a destroyed publisher: without this the round would go on waking the loop.
        self._diagnostics_publishers = [entry for entry in self._diagnostics_publishers
                                        if entry[0] != domain_id]
        self._update_rounds()

    def _rounds_needed(self) -> bool:
        # A publisher's matched_events is known once it is made (after the domain's first
        # client, whose node goes first), and it calls _update_rounds then.
        if any(not publisher.matched_events for _, publisher in self._diagnostics_publishers):
            self._diagnostics_unmatched_events = True
        if self._always:
            return True
        if self._diagnostics_unmatched_events:  # no matched events: a domain joined is enough
            return bool(self._diagnostics_publishers)
        for entry in list(self._diagnostics_publishers):
            try:
                if entry[1].subscriber_count():
                    return True
            except Exception:  # destroyed with its domain (the agent shutting down)
                self._diagnostics_publishers.remove(entry)
        return False

    def _update_rounds(self) -> None:
        """Start or stop the once-a-second round as its readers come and go (loop thread)."""
        if self._closed:
            return
        needed = self._rounds_needed()
        if needed and self._task is None:
            self.observer.restart_rates()
            self._task = asyncio.ensure_future(self._run())
        elif not needed and self._task is not None:
            self._task.cancel()
            self._task = None

    def describe(self):
        return self.stats_server.describe() if self.stats_server is not None else None

    async def _run(self) -> None:
        next_summary = None if not self.summary_period else time.monotonic() + self.summary_period
        while True:
            await asyncio.sleep(RATE_PERIOD_S)
            try:
                self.observer.update_rates()
                if self.capture is not None:
                    self.capture.flush()
                if self.diagnostics is not None:
                    self.diagnostics.publish()
                if next_summary is not None and time.monotonic() >= next_summary:
                    next_summary += self.summary_period
                    from xrce.agent.observe.stats_view import summary_lines

                    # The operator's own log, which names keys anyway.
                    for line in summary_lines(self.observer.snapshot(show_keys=True)):
                        log.debug("%s", line)
            except Exception:  # observability must never stop the agent
                log.warning("observability round failed", exc_info=True)

    async def close(self) -> None:
        self._closed = True
        if self._task is not None:
            self._task.cancel()
            try:
                await self._task
            except asyncio.CancelledError:
                pass
            self._task = None
        if self.stats_server is not None:
            await self.stats_server.close()
        if self.capture is not None:
            if self.agent.tap is self.capture:
                self.agent.tap = None
            self.capture.close()


# `xrce-agent stats`: its options are declared with every subcommand's, its code (xrce.agent.observe.stats_view)
# loads only when it runs; a serving agent never needs it.
def add_stats_options(parser) -> None:
    parser.add_argument("-p", "--port", type=int, required=True,
                        help="the agent's --stats-port")
    parser.add_argument("--host", default="127.0.0.1",
                        help="where that agent runs (default 127.0.0.1; the stats port listens "
                             "on loopback only, so another host needs a tunnel)")
    parser.add_argument("-i", "--interval", type=float, default=1.0, metavar="S",
                        help="seconds between refreshes (default 1)")
    parser.add_argument("--once", action="store_true", help="print one table and exit")
    parser.add_argument("--json", action="store_true",
                        help="print one raw JSON snapshot and exit (for scripts)")


def run_stats(args) -> int:
    from xrce.agent.observe.stats_view import run_stats as run

    return run(args)


__all__ = ["Observability", "Observer", "StatsServer", "add_agent_options", "add_stats_options",
           "client_pseudonym", "client_tag", "endpoint_text", "run_stats"]
