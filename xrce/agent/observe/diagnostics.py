"""``/diagnostics``: with ``-m dds`` and ``diagnostic_msgs`` importable, a
``diagnostic_msgs/DiagnosticArray`` goes out once a second in every ROS domain the agent has joined
where some node subscribes to it: one status for the agent, one per client, named after the
client's tag (``names.client_tag``: the key itself is a credential, and the whole domain reads
this), with its address, its nodes and domains and its topics and types as ROS names. Its
content is an ``Observer`` snapshot (xrce.agent.observe.observability). A board the agent names
otherwise (a namespace, remaps, another domain, a fleet rule: issue 53) has the board's own names
beside the ROS ones in ``nodes`` and ``endpoints``, and ``rule``, ``namespace``, ``domain`` and
``remaps`` say what was applied.

The agent joins a ROS domain only with a client participant there (and stays for the linger after
the last, ``xrce.agent.middleware.ros.membership``), so an agent without clients publishes no
``/diagnostics``: publishing it would take the DDS participant the agent does not keep at rest,
and with no client there is nothing to report but that the agent runs, which the stats port
(``xrce-agent stats``) and SIGUSR1 still tell.
"""

from __future__ import annotations

import logging
import time

from xrce.wire.cdr import CdrWriter
from xrce.agent.observe.entities import client_naming, endpoints_text, nodes_text

# One logger for everything observability does (xrce.agent.observe.observability wires this module in).
log = logging.getLogger("xrce.agent.observability")

STALE_AFTER_S = 5.0  # a client silent this long is reported WARN on /diagnostics
DIAGNOSTIC_ARRAY_TYPE = "diagnostic_msgs::msg::dds_::DiagnosticArray_"
DIAGNOSTIC_OK = 0  # diagnostic_msgs/DiagnosticStatus levels
DIAGNOSTIC_WARN = 1
# The whole ROS domain reads /diagnostics: a client is named by its tag, never its key (the
# snapshot it is made from has none: Observer.snapshot without show_keys); nested rows as text.
# ``rule`` goes with the rest of the board's naming (entities.client_naming).
_NOT_VALUES = frozenset(("key", "tag", "participants", "endpoints", "rule"))


def diagnostic_array_type(raw_message_type):
    """The raw type handle of DiagnosticArray, or None when diagnostic_msgs is not installed.
    ``raw_message_type`` is the ROS middleware's lookup of a type by its DDS name, handed down by
    the command line: observe is a floor below the middleware and imports none of it."""
    try:
        return raw_message_type(DIAGNOSTIC_ARRAY_TYPE)
    except Exception as exc:  # no rclpy or no diagnostic_msgs: the agent runs without
        log.debug("no /diagnostics: %s", exc)
        return None


def diagnostic_array(snapshot: dict, stamp_ns: int) -> bytes:
    """A DiagnosticArray, one status for the agent and one per client (``xrce_agent: client
    TAG``), as its CDR body (XCDR1 little-endian, no encapsulation header).

    Encoded here rather than through the generated Python classes: building ~20 message objects
    a second cost more CPU than a TurtleBot3's whole sensor traffic, and importing the classes
    pulls in rosidl's code generator (lark, empy: +5 MB resident)."""
    statuses = [(DIAGNOSTIC_OK, "xrce_agent", "%d clients" % len(snapshot["clients"]),
                 "xrce_agent", [(k, str(v)) for k, v in snapshot["agent"].items()])]
    for client in snapshot["clients"]:
        stale = client["last_seen_s"] >= STALE_AFTER_S
        values = [(k, "" if v is None else str(v)) for k, v in client.items()
                  if k not in _NOT_VALUES]
        values += [("nodes", nodes_text(client)), ("endpoints", endpoints_text(client))]
        values += client_naming(client)
        statuses.append((
            DIAGNOSTIC_WARN if stale else DIAGNOSTIC_OK,
            "xrce_agent: client %s" % client["tag"],
            "silent for %.1f s" % client["last_seen_s"] if stale
            else "session 0x%02X on %s" % (client["session_id"], client["address"]),
            client["tag"], values))
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
    ROS node subscribes to /diagnostics there (nobody listening: no snapshot is built).
    ``observer`` is observability's ``Observer``, which wires this module in: named, not imported."""

    def __init__(self, observer, middleware, message_type):
        self.observer = observer
        self.middleware = middleware
        self.message_type = message_type
        self.published = 0

    def publisher(self, domain_id: int, on_matched=None):
        """The /diagnostics publisher of ``domain_id`` (made on first use, with ``on_matched``
        called as subscriptions come and go); None if the agent has not joined it."""
        return self.middleware.agent_publisher(domain_id, self.message_type, "/diagnostics",
                                               on_matched=on_matched)

    def publish(self) -> None:
        body = None
        for domain_id in self.middleware.domain_ids():
            publisher = self.publisher(domain_id)
            if publisher is None or not publisher.subscriber_count():
                continue
            if body is None:
                body = diagnostic_array(self.observer.snapshot(), time.time_ns())
            publisher.write(body)
            self.published += 1


__all__ = [
    "DIAGNOSTIC_ARRAY_TYPE", "DiagnosticsPublisher", "diagnostic_array", "diagnostic_array_type",
]
