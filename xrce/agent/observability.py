"""What a running agent is doing: counters, a live stats view, /diagnostics and capture files.

- ``Observer`` turns the engine's counters (``AgentStats``, the per-client fields of
  ``ClientProxy``, per-entity sample counts, each link's ``LinkStats`` and frame decoders) into a
  JSON-able snapshot with per-client and per-topic rates. Rates are differences between two
  ``update_rates()`` calls, made once a second by ``Observability``.
- ``StatsServer``: ``--stats-port PORT`` serves that snapshot as one JSON document to every TCP
  connection on 127.0.0.1 (TCP, not UDP: a thousand clients do not fit in one datagram).
  ``xrce-agent stats -p PORT`` polls it and redraws a terminal table (plain ANSI, no dependency).
- At ``-v 5`` the agent logs a one-line summary (and one line per active client) periodically.
- With ``-m dds`` and ``diagnostic_msgs`` importable, a ``diagnostic_msgs/DiagnosticArray`` goes out
  on ``/diagnostics`` once a second in every ROS domain the agent has joined where some node
  subscribes to it: one status for the agent, one per client, named after the client key.
- ``--capture FILE`` writes every message in both directions, one text line each::

      <unix time, s> <in|out> <link> <endpoint> <message hex>

  ``read_capture`` parses it back and ``decode_capture`` runs each message through the wire
  decoder (``xrce.submessages.decode_message``), e.g. to replay a bug report.

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
import socket
import sys
import time

from xrce import constants as C
from xrce.cdr import CdrWriter
from xrce.agent.timeline import format_timeline

log = logging.getLogger("xrce.agent.observability")

DEFAULT_SUMMARY_PERIOD_S = 5.0
DIAGNOSTICS_PERIOD_S = 1.0
RATE_PERIOD_S = 1.0
STALE_AFTER_S = 5.0  # a client silent this long is reported WARN on /diagnostics
_TOPIC_KINDS = {C.OBJK_DATAWRITER: "to_ros", C.OBJK_DATAREADER: "from_ros"}
_RATE_FIELDS = ("messages_in", "messages_out", "bytes_in", "bytes_out")


def endpoint_text(endpoint) -> str:
    """A link endpoint as one word (capture files split on spaces)."""
    if isinstance(endpoint, tuple) and len(endpoint) >= 2:
        return "%s:%s" % (endpoint[0], endpoint[1])
    return str(endpoint).replace(" ", "")


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

    def snapshot(self) -> dict:
        now = self.clock()
        agent = self.agent
        clients = []
        for client in list(agent.clients.values()):
            rates = self._rates.get(("client", client.key), (0.0, 0.0, 0.0, 0.0))
            clients.append({
                "key": client.key.hex(),
                "session_id": client.session_id,
                "link": client.link.name,
                "endpoint": endpoint_text(client.endpoint),
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
                "topic": name, "type": type_name, "direction": direction, "endpoints": endpoints,
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
                "agent": agent.stats.as_dict(), "links": links, "clients": clients,
                "topics": topics,
                "recoveries": timelines.snapshot() if timelines is not None else []}


# ------------------------------------------------------------------------------------ rendering

def _number(value) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return "%.1f" % value if value < 1000 else "%.0f" % value
    return str(value)


def _table(headers, rows) -> list:
    widths = [len(h) for h in headers]
    text_rows = [[_number(v) for v in row] for row in rows]
    for row in text_rows:
        widths = [max(w, len(cell)) for w, cell in zip(widths, row)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(headers, widths))]
    lines.append("  ".join("-" * w for w in widths))
    for row in text_rows:
        lines.append("  ".join(cell.rjust(w) if i else cell.ljust(w)
                               for i, (cell, w) in enumerate(zip(row, widths))))
    return lines


def format_snapshot(snapshot: dict, max_clients: int = 40, max_recoveries: int = 5) -> str:
    """The stats view: links, clients (busiest first) and topics as plain-text tables."""
    agent = snapshot["agent"]
    lines = ["xrce-agent up %.0f s: %d clients, in %d msg / %d B, out %d msg / %d B, "
             "dropped %d (decode %d), retransmissions %d" % (
                 snapshot["uptime_s"], len(snapshot["clients"]), agent["messages_in"],
                 agent["bytes_in"], agent["messages_out"], agent["bytes_out"], agent["dropped"],
                 agent["decode_errors"], agent["retransmissions"]), ""]
    lines += _table(("link", "msg in", "msg out", "bytes in", "bytes out", "drops", "crc"),
                    [(l["name"], l["messages_in"], l["messages_out"], l["bytes_in"],
                      l["bytes_out"], l["drops"], l["crc_errors"]) for l in snapshot["links"]])
    clients = sorted(snapshot["clients"], key=lambda c: -(c["messages_in_per_s"]
                                                          + c["messages_out_per_s"]))
    lines.append("")
    lines += _table(("client", "link", "msg/s in", "msg/s out", "msg in", "msg out", "B/s in",
                     "B/s out", "decode", "dup", "retx", "rtt ms", "skew ms", "seen s"),
                    [(c["key"], c["link"], c["messages_in_per_s"], c["messages_out_per_s"],
                      c["messages_in"], c["messages_out"], c["bytes_in_per_s"],
                      c["bytes_out_per_s"], c["decode_errors"], c["duplicates"],
                      c["retransmissions"], c["rtt_ms"], c["timestamp_skew_ms"],
                      c["last_seen_s"]) for c in clients[:max_clients]])
    if len(clients) > max_clients:
        lines.append("... %d more clients" % (len(clients) - max_clients))
    lines.append("")
    lines += _table(("topic", "direction", "type", "endpoints", "samples", "samples/s", "B/s"),
                    [(t["topic"], t["direction"], t["type"], t["endpoints"], t["samples"],
                      t["samples_per_s"], t["bytes_per_s"]) for t in snapshot["topics"]])
    recoveries = snapshot.get("recoveries") or []
    if recoveries:
        lines += ["", "recoveries (latest last):"]
        lines += ["  " + format_timeline(t) for t in recoveries[-max_recoveries:]]
    return "\n".join(lines)


def summary_lines(snapshot: dict) -> list:
    """The ``-v 5`` periodic summary: one line for the agent, one per client that moved."""
    agent = snapshot["agent"]
    lines = ["summary: %d clients; in %d msg %d B, out %d msg %d B; dropped %d, decode errors %d, "
             "retransmissions %d, crc errors %d" % (
                 len(snapshot["clients"]), agent["messages_in"], agent["bytes_in"],
                 agent["messages_out"], agent["bytes_out"], agent["dropped"],
                 agent["decode_errors"], agent["retransmissions"],
                 sum(l["crc_errors"] for l in snapshot["links"]))]
    for c in snapshot["clients"]:
        if c["messages_in_per_s"] or c["messages_out_per_s"]:
            lines.append("client %s on %s: %.1f msg/s in, %.1f msg/s out, retx %d, rtt %s ms, "
                         "seen %.1f s ago" % (c["key"], c["link"], c["messages_in_per_s"],
                                              c["messages_out_per_s"], c["retransmissions"],
                                              _number(c["rtt_ms"]), c["last_seen_s"]))
    for t in snapshot["topics"]:
        if t["samples_per_s"]:
            lines.append("topic %s %s: %.1f samples/s, %.0f B/s" % (
                t["topic"], t["direction"], t["samples_per_s"], t["bytes_per_s"]))
    return lines


# ------------------------------------------------------------------------------------ live view

class StatsServer:
    """Every TCP connection on ``host:port`` gets the current snapshot as JSON, then EOF."""

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
            writer.write(json.dumps(self.observer.snapshot()).encode() + b"\n")
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


def fetch_stats(port: int, host: str = "127.0.0.1", timeout_s: float = 2.0) -> dict:
    """One snapshot from a running agent's ``--stats-port``."""
    with socket.create_connection((host, port), timeout=timeout_s) as sock:
        chunks = []
        while True:
            chunk = sock.recv(65536)
            if not chunk:
                break
            chunks.append(chunk)
    return json.loads(b"".join(chunks))


def add_stats_options(parser) -> None:
    parser.add_argument("-p", "--port", type=int, required=True,
                        help="the agent's --stats-port")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("-i", "--interval", type=float, default=1.0, metavar="S",
                        help="seconds between refreshes (default 1)")
    parser.add_argument("--once", action="store_true", help="print one table and exit")
    parser.add_argument("--json", action="store_true", help="print the raw JSON snapshot")


def run_stats(args) -> int:
    """``xrce-agent stats``: poll a running agent and redraw its tables until Ctrl-C."""
    clear = "\x1b[H\x1b[2J" if sys.stdout.isatty() and not args.once else ""
    try:
        while True:
            try:
                snapshot = fetch_stats(args.port, args.host)
            except (OSError, ValueError) as exc:
                sys.stderr.write("xrce-agent: error: cannot read stats from %s:%d: %s\n"
                                 % (args.host, args.port, exc))
                return 1
            text = json.dumps(snapshot) if args.json else format_snapshot(snapshot)
            sys.stdout.write(clear + text + "\n")
            sys.stdout.flush()
            if args.once:
                return 0
            time.sleep(args.interval)
    except KeyboardInterrupt:
        return 0


# ------------------------------------------------------------------------------------ capture

class CaptureWriter:
    """The engine's tap: one line per message (see the module docstring for the format)."""

    def __init__(self, path: str):
        self.path = path
        self.file = open(path, "w", encoding="ascii")
        self.file.write("# xrce-agent capture: time direction link endpoint hex\n")
        self.records = 0

    def __call__(self, direction: str, link, endpoint, data) -> None:
        self.file.write("%.6f %s %s %s %s\n" % (time.time(), direction,
                                                getattr(link, "name", "link"),
                                                endpoint_text(endpoint), bytes(data).hex()))
        self.records += 1

    def flush(self) -> None:
        if not self.file.closed:
            self.file.flush()

    def close(self) -> None:
        if not self.file.closed:
            self.file.close()


class CapturedMessage:
    __slots__ = ("time", "direction", "link", "endpoint", "data")

    def __init__(self, time_s, direction, link, endpoint, data):
        self.time = time_s
        self.direction = direction
        self.link = link
        self.endpoint = endpoint
        self.data = data

    def __repr__(self):
        return "CapturedMessage(%.6f, %r, %r, %r, %s)" % (self.time, self.direction, self.link,
                                                        self.endpoint, self.data.hex())


def read_capture(path: str):
    """Every message of a capture file, in order; ValueError on a line that is not a record."""
    with open(path, encoding="ascii") as lines:
        for number, line in enumerate(lines, 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            parts = line.split(" ")
            if len(parts) != 5 or parts[1] not in ("in", "out"):
                raise ValueError("%s:%d: not a capture record" % (path, number))
            yield CapturedMessage(float(parts[0]), parts[1], parts[2], parts[3],
                                  bytes.fromhex(parts[4]))


def decode_capture(path: str):
    """``(CapturedMessage, header, payloads)`` per record, decoded by the wire core; a message
    that does not decode gives ``(record, None, DecodeError)`` so a bug report still reads."""
    from xrce.errors import DecodeError
    from xrce.submessages import decode_message

    for record in read_capture(path):
        try:
            header, payloads = decode_message(record.data)
        except DecodeError as exc:
            yield record, None, exc
        else:
            yield record, header, payloads


# ------------------------------------------------------------------------------------ /diagnostics

DIAGNOSTIC_ARRAY_TYPE = "diagnostic_msgs::msg::dds_::DiagnosticArray_"
DIAGNOSTIC_OK = 0  # diagnostic_msgs/DiagnosticStatus levels
DIAGNOSTIC_WARN = 1


def _diagnostic_type():
    """The raw type handle of DiagnosticArray, or None when diagnostic_msgs is not installed."""
    try:
        from xrce.agent.rostypes import raw_message_type
        return raw_message_type(DIAGNOSTIC_ARRAY_TYPE)
    except Exception as exc:  # no rclpy or no diagnostic_msgs: the agent runs without
        log.debug("no /diagnostics: %s", exc)
        return None


def diagnostic_array(snapshot: dict, stamp_ns: int) -> bytes:
    """A DiagnosticArray, one status for the agent and one per client (``xrce_agent: client
    KEY``), as its CDR body (XCDR1 little-endian, no encapsulation header).

    Encoded here rather than through the generated Python classes: building ~20 message objects
    a second cost more CPU than a TurtleBot3's whole sensor traffic, and importing the classes
    pulls in rosidl's code generator (lark, empy: +5 MB resident)."""
    statuses = [(DIAGNOSTIC_OK, "xrce_agent", "%d clients" % len(snapshot["clients"]),
                 "xrce_agent", [(k, str(v)) for k, v in snapshot["agent"].items()])]
    for client in snapshot["clients"]:
        stale = client["last_seen_s"] >= STALE_AFTER_S
        statuses.append((
            DIAGNOSTIC_WARN if stale else DIAGNOSTIC_OK,
            "xrce_agent: client %s" % client["key"],
            "silent for %.1f s" % client["last_seen_s"] if stale
            else "session 0x%02X on %s" % (client["session_id"], client["link"]),
            client["key"],
            [(k, "" if v is None else str(v)) for k, v in client.items() if k != "key"]))
    writer = CdrWriter(bytearray(512))
    writer.i32(stamp_ns // 1000000000)  # header.stamp
    writer.u32(stamp_ns % 1000000000)
    writer.string("")  # header.frame_id
    writer.u32(len(statuses))
    for level, name, message, hardware_id, values in statuses:
        writer.u8(level)
        writer.string(name)
        writer.string(message)
        writer.string(hardware_id)
        writer.u32(len(values))
        for key, value in values:
            writer.string(key)
            writer.string(value)
    return writer.getvalue()


class DiagnosticsPublisher:
    """Publishes ``diagnostic_array`` in every domain a ``RosMiddleware`` has joined, while some
    ROS node subscribes to /diagnostics there (nobody listening: no snapshot is built)."""

    def __init__(self, observer: Observer, middleware, message_type):
        self.observer = observer
        self.middleware = middleware
        self.message_type = message_type
        self.published = 0

    def publish(self) -> None:
        body = None
        for domain_id in self.middleware.domain_ids():
            publisher = self.middleware.agent_publisher(domain_id, self.message_type,
                                                        "/diagnostics")
            if publisher is None or not publisher.subscriber_count():
                continue
            if body is None:
                body = diagnostic_array(self.observer.snapshot(), time.time_ns())
            publisher.write(body)
            self.published += 1


# ------------------------------------------------------------------------------------ wiring

def add_agent_options(parser) -> None:
    """Options every agent transport subcommand gets."""
    parser.add_argument("--stats-port", type=int, metavar="PORT",
                        help="serve live counters as JSON on 127.0.0.1:PORT (0: any free port, "
                             "shown in the banner) for `xrce-agent stats -p PORT`")
    parser.add_argument("--capture", metavar="FILE",
                        help="record every message in both directions, with timestamps, to FILE")
    parser.add_argument("--summary-period", type=float, default=DEFAULT_SUMMARY_PERIOD_S,
                        metavar="S", help="seconds between -v 5 summaries (default 5)")
    parser.add_argument("--no-diagnostics", action="store_true",
                        help="do not publish /diagnostics (-m dds)")


class Observability:
    """Everything above, attached to one agent according to its command-line options."""

    def __init__(self, agent, links, *, stats_port=None, capture=None, summary_period=None,
                 middleware=None, diagnostics=True):
        self.agent = agent
        self.observer = Observer(agent, links)
        self.stats_server = StatsServer(self.observer, stats_port) if stats_port is not None \
            else None
        self.capture = CaptureWriter(capture) if capture else None
        self.summary_period = summary_period
        self.diagnostics = None
        if diagnostics and middleware is not None and hasattr(middleware, "agent_publisher"):
            message_type = _diagnostic_type()
            if message_type is not None:
                self.diagnostics = DiagnosticsPublisher(self.observer, middleware, message_type)
        self._task = None

    @classmethod
    def from_args(cls, args, agent, links, middleware):
        summary = args.summary_period if log.getEffectiveLevel() <= logging.DEBUG else None
        return cls(agent, links, stats_port=getattr(args, "stats_port", None),
                   capture=getattr(args, "capture", None), summary_period=summary,
                   middleware=middleware, diagnostics=not getattr(args, "no_diagnostics", False))

    async def start(self) -> None:
        if self.capture is not None:
            self.agent.tap = self.capture
        if self.stats_server is not None:
            await self.stats_server.start()
        self._task = asyncio.ensure_future(self._run())

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
                    for line in summary_lines(self.observer.snapshot()):
                        log.debug("%s", line)
            except Exception:  # observability must never stop the agent
                log.warning("observability round failed", exc_info=True)

    async def close(self) -> None:
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


__all__ = [
    "Observer", "Observability", "StatsServer", "CaptureWriter", "CapturedMessage",
    "DiagnosticsPublisher", "add_agent_options", "add_stats_options", "decode_capture",
    "diagnostic_array", "endpoint_text", "fetch_stats", "format_snapshot", "read_capture",
    "run_stats", "summary_lines",
]
