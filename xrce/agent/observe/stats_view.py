"""Text views of an ``Observer`` snapshot (xrce.agent.observe.observability).

- ``xrce-agent stats -p PORT`` reads a running agent's ``--stats-port`` (one JSON document per TCP
  connection) and redraws its links, clients and topics as terminal tables (plain ANSI, no
  dependency).
- ``summary_lines``: the periodic one-line summaries the agent logs at ``-v 5``.
"""

from __future__ import annotations

import json
import socket
import sys
import time

from xrce.agent.observe.timeline_text import format_timeline
from xrce.agent.observe.entities import endpoint_name_text, nodes_text, rule_text


def _number(value) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return "%.1f" % value if value < 1000 else "%.0f" % value
    return str(value)


def _table(headers, rows, words: bool = False) -> list:
    """Columns of numbers right-aligned after the first; with ``words``, all left-aligned."""
    widths = [len(h) for h in headers]
    text_rows = [[_number(v) for v in row] for row in rows]
    for row in text_rows:
        widths = [max(w, len(cell)) for w, cell in zip(widths, row)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(headers, widths)).rstrip()]
    lines.append("  ".join("-" * w for w in widths))
    for row in text_rows:
        lines.append("  ".join(cell.rjust(w) if i and not words else cell.ljust(w)
                               for i, (cell, w) in enumerate(zip(row, widths))).rstrip())
    return lines


def client_name(row: dict) -> str:
    """A client as the stats name it: the key it sent, or its tag where keys are hidden."""
    return row.get("key") or row["tag"]


def _restored_text(restored) -> str:
    """Whether a client came back from the state store, and whether it has spoken since."""
    return {"spoke": "yes, spoke", "silent": "yes, silent"}.get(restored, "-")


def _naming_cell(row: dict) -> str:
    """What named a client's board: ``rule robot1``, ``command line``, or ``-`` (its own names)."""
    if not any("namespace" in p for p in row.get("participants", ())):
        return "-"
    return rule_text(row.get("rule"))


def format_snapshot(snapshot: dict, max_clients: int = 40, max_recoveries: int = 5,
                    max_endpoints: int = 60) -> str:
    """The stats view: links, clients (busiest first) with their addresses and nodes, their
    endpoints and the topics as plain-text tables."""
    agent = snapshot["agent"]
    lines = ["xrce-agent up %.0f s: %d clients, in %d msg / %d B, out %d msg / %d B, "
             "dropped %d (decode %d), not published %d, retransmissions %d, mismatches %d" % (
                 snapshot["uptime_s"], len(snapshot["clients"]), agent["messages_in"],
                 agent["bytes_in"], agent["messages_out"], agent["bytes_out"], agent["dropped"],
                 agent["decode_errors"], agent.get("publish_errors", 0),
                 agent["retransmissions"], agent.get("mismatches", 0))]
    if snapshot["clients"] and not snapshot.get("keys_shown"):
        lines.append("client keys hidden (this reader is not the agent's user): clients named "
                     "by tag, as on /diagnostics")
    lines.append("")
    lines += _table(("link", "msg in", "msg out", "bytes in", "bytes out", "drops", "crc"),
                    [(l["name"], l["messages_in"], l["messages_out"], l["bytes_in"],
                      l["bytes_out"], l["drops"], l["crc_errors"]) for l in snapshot["links"]])
    clients = sorted(snapshot["clients"], key=lambda c: -(c["messages_in_per_s"]
                                                          + c["messages_out_per_s"]))
    shown = clients[:max_clients]
    lines.append("")
    # The naming column only where the agent names some board otherwise than it asked (issue 53).
    named = any("namespace" in p for c in shown for p in c.get("participants", ()))
    lines += _table(("client", "tag", "address", "session", "restored", "nodes (ROS domain)")
                    + (("naming",) if named else ()),
                    [(client_name(c), c["tag"], c["address"], "0x%02X" % c["session_id"],
                      _restored_text(c.get("restored")), nodes_text(c) or "-")
                     + ((_naming_cell(c),) if named else ()) for c in shown],
                    words=True)
    lines.append("")
    lines += _table(("client", "msg/s in", "msg/s out", "msg in", "msg out", "B/s in",
                     "B/s out", "decode", "dup", "retx", "rtt ms", "skew ms", "seen s"),
                    [(client_name(c), c["messages_in_per_s"], c["messages_out_per_s"],
                      c["messages_in"], c["messages_out"], c["bytes_in_per_s"],
                      c["bytes_out_per_s"], c["decode_errors"], c["duplicates"],
                      c["retransmissions"], c["rtt_ms"], c["timestamp_skew_ms"],
                      c["last_seen_s"]) for c in shown])
    if len(clients) > max_clients:
        lines.append("... %d more clients" % (len(clients) - max_clients))
    endpoints = [(client_name(c), e) for c in shown for e in c.get("endpoints", ())]
    if endpoints:
        lines.append("")
        lines += _table(("client", "endpoint", "topic / service", "type", "QoS", "samples",
                         "mismatch"),
                        [(name, "%s %s" % (e["kind"], e["object_id"]),
                          endpoint_name_text(e), e.get("type"), e.get("qos", "-"),
                          e["samples"], "yes" if e.get("mismatches") else "-")
                         for name, e in endpoints[:max_endpoints]], words=True)
        if len(endpoints) > max_endpoints:
            lines.append("... %d more endpoints" % (len(endpoints) - max_endpoints))
    lines.append("")
    lines += _table(("topic", "direction", "type", "endpoints", "samples", "samples/s", "B/s"),
                    [(t["topic"], t["direction"], t["type"], t["endpoints"], t["samples"],
                      t["samples_per_s"], t["bytes_per_s"]) for t in snapshot["topics"]])
    recoveries = snapshot.get("recoveries") or []
    if recoveries:
        lines += ["", "recoveries (latest last):"]
        lines += ["  " + format_timeline(dict(t, key=t.get("key") or t["tag"]))
                  for t in recoveries[-max_recoveries:]]
    mismatches = [(client_name(c), text) for c in shown for e in c.get("endpoints", ())
                  for text in e.get("mismatches", ())]
    if mismatches:
        lines += ["", "mismatches:"]
        lines += ["  client %s: %s" % pair for pair in mismatches]
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
                         "seen %.1f s ago" % (client_name(c), c["address"], c["messages_in_per_s"],
                                              c["messages_out_per_s"], c["retransmissions"],
                                              _number(c["rtt_ms"]), c["last_seen_s"]))
    for t in snapshot["topics"]:
        if t["samples_per_s"]:
            lines.append("topic %s %s: %.1f samples/s, %.0f B/s" % (
                t["topic"], t["direction"], t["samples_per_s"], t["bytes_per_s"]))
    return lines


# ------------------------------------------------------------------------------------ stats command

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


def run_stats(args) -> int:
    """``xrce-agent stats``: poll a running agent and redraw its tables until Ctrl-C (exit 130);
    ``--once`` and ``--json`` print one snapshot and exit 0. A reader that goes away (``| head``)
    ends it quietly."""
    import os

    if not 0 < args.port <= 65535:
        sys.stderr.write("xrce-agent: error: argument -p/--port: port %d is not in 1..65535\n"
                         % args.port)
        return 2
    if not args.interval > 0:
        sys.stderr.write("xrce-agent: error: argument -i/--interval: must be more than 0 s\n")
        return 2
    once = args.once or args.json
    clear = "\x1b[H\x1b[2J" if sys.stdout.isatty() and not once else ""
    try:
        while True:
            try:
                snapshot = fetch_stats(args.port, args.host)
            except (OSError, ValueError) as exc:
                sys.stderr.write("xrce-agent: error: cannot read stats from %s:%d: %s (is an "
                                 "agent running with --stats-port %d?)\n"
                                 % (args.host, args.port, getattr(exc, "strerror", None) or exc,
                                    args.port))
                return 1
            text = json.dumps(snapshot) if args.json else format_snapshot(snapshot)
            sys.stdout.write(clear + text + "\n")
            sys.stdout.flush()
            if once:
                return 0
            time.sleep(args.interval)
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # Nobody reads any more; point stdout at /dev/null so the interpreter's own flush at
        # exit does not report the same broken pipe again.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        return 0


__all__ = ["fetch_stats", "format_snapshot", "run_stats", "summary_lines"]
