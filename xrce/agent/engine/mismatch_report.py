"""Board endpoints that cannot reach their peers, named: the part of the engine that turns what
the middleware and the data path find into one WARNING per pair and a count."""

from __future__ import annotations

import logging
from typing import Optional

from xrce.wire import constants as C
from xrce.agent.engine.client import ClientProxy, ObjectEntry
from xrce.agent.observe import entities as words
from xrce.agent.observe.names import address_text, object_id_text, ros_topic_name
from xrce.wire.message import header_size

log = logging.getLogger("xrce.agent")

MAX_MISMATCHES_KEPT = 8  # texts kept per endpoint for the stats; all are counted and logged


class MismatchReport:
    """Board endpoints that cannot reach their peers, named once per pair in one WARNING (the
    board by key and address, the topic, both sides and the fix) and counted in
    ``stats.mismatches``. The middleware finds QoS and type mismatches (``middleware_mismatch``,
    its ``on_mismatch``, from its own thread); the data path finds samples too large for a
    board's stream (``too_large_for_best_effort``); liveliness, ACKNACKs that show a board
    holding fragments it can never complete (``acknack_holds_fragments``).

    Collaborators: ``clients`` (the agent's table, key → ClientProxy, read only) and
    ``scheduler`` (the loop a report from another thread is handed to)."""

    def __init__(self, clients: dict, scheduler, stats, clock, heartbeat_period: float):
        self.clients = clients
        self.scheduler = scheduler
        self.stats = stats
        self.clock = clock
        self.heartbeat_period = heartbeat_period
        # (client key, stream id) → (first unacknowledged, fragments held, rounds, since)
        self._held_fragments: dict = {}

    def middleware_mismatch(self, entity, text: str) -> None:
        scheduler = self.scheduler
        if scheduler.loop is not None and not scheduler.on_loop_thread():
            try:
                scheduler.loop.call_soon_threadsafe(self.middleware_mismatch, entity, text)
            except RuntimeError:  # the loop has closed: the agent is going
                pass
            return
        client = self.clients.get((entity[0] & 0xFFFFFFFF).to_bytes(4, "big"))
        entry = client.objects.get(entity[1]) if client is not None else None
        self.report(client, entry, text)

    def report(self, client: Optional[ClientProxy], entry: Optional[ObjectEntry],
                  text: str) -> None:
        self.stats.mismatches += 1
        if client is None or entry is None:  # gone since: still worth the line
            log.warning("mismatch: %s", text)
            return
        kept = _info(entry).setdefault("mismatches", [])
        if len(kept) < MAX_MISMATCHES_KEPT:
            kept.append(text)
        log.warning("client %s at %s, %s %s: %s", client.key.hex(),
                    address_text(client.link.name, client.endpoint),
                    words.kind_name(entry.kind), object_id_text(entry.object_id), text)

    # -- samples from ROS a board's stream cannot carry ---------------------------------------

    def too_large_for_best_effort(self, client: ClientProxy, entry: ObjectEntry,
                                   size: int, message_size: int) -> None:
        """A reader's sample does not fit one best-effort message (those are never cut into
        FRAGMENTs): it is dropped, now and every time (``StreamOutput.send_on_stream`` counts
        it)."""
        info = _info(entry)
        if "too_large" in info:
            return
        info["too_large"] = True
        self.report(client, entry, (
            "%s: a %d-byte sample from ROS cannot reach the board: it reads on a best-effort "
            "stream, which carries one message of at most %d bytes (its MTU; this one is %d) "
            "and is never fragmented, so every such sample is dropped; fix: read it with a "
            "reliable subscription (samples are then fragmented), raise the board's MTU "
            "(RMW_UXRCE_MAX_TRANSPORT_MTU) or publish smaller samples"
            % (_topic(entry), size, client.mtu, message_size)))

    def acknack_holds_fragments(self, client: ClientProxy, stream, acknack) -> None:
        """An ACKNACK whose first unacknowledged message the board has (bit 0 clear) but has
        not handled: the first FRAGMENTs of a sample it holds until the last arrives. A board
        whose stream is shorter than the sample (eProsima's client holds one fragment per slot
        of its input stream's history) can never take the rest: the same ACKNACK then comes
        back for ever and the stream is stuck. The same, ``STUCK_ROUNDS`` heartbeat periods
        apart (the missing fragments resent in between), and nothing held past the first missing
        one: named."""
        first = acknack.first_unacked
        bitmap = acknack.nack_bitmap
        held = (bitmap & -bitmap).bit_length() - 1  # fragments the board holds, from ``first``
        missing = bitmap >> held
        state_key = (client.key, stream.stream_id)
        if missing & (missing + 1):  # it has some after a gap: a loss being repaired, not this
            self._held_fragments.pop(state_key, None)
            return
        now = self.clock()
        state = self._held_fragments.get(state_key)
        if state is None or state[:2] != (first, held):
            if len(self._held_fragments) >= MAX_WATCHED_STREAMS:
                self._held_fragments.clear()
            self._held_fragments[state_key] = (first, held, 1, now)
            return
        # One round per heartbeat period: the agent has resent the missing fragments since.
        if now - state[3] < self.heartbeat_period:
            return
        rounds = state[2] + 1
        self._held_fragments[state_key] = (first, held, rounds, now)
        if rounds != STUCK_ROUNDS:
            return
        message = stream.slots[first & (stream.history - 1)]
        entry = None
        if message is not None:
            head = header_size(message[0])
            # FRAGMENT, then the fragmented message's first submessage: DATA + request and
            # object ids (XRCE-WIRE.md: the BaseObjectRequest).
            if len(message) >= head + 12 and message[head] == C.FRAGMENT and \
                    message[head + 4] == C.DATA:
                entry = client.objects.get(int.from_bytes(message[head + 10:head + 12], "big"))
        if entry is None or entry.reader is None:
            return
        info = _info(entry)
        if "stuck" in info:
            return
        info["stuck"] = True
        size = info.get("fragmented")
        chunk = client.mtu - head - 4
        self.report(client, entry, (
            "%s: a %ssample from ROS cannot reach the board: its reliable stream holds %d "
            "fragments of at most %d bytes (about %d bytes with its MTU %d) and the sample needs "
            "more, so the board never completes it and that stream is stuck until the session "
            "restarts; fix: raise the board's stream history or MTU (RMW_UXRCE_STREAM_HISTORY, "
            "RMW_UXRCE_MAX_TRANSPORT_MTU) or publish smaller samples" % (
                _topic(entry), "%d-byte " % size if size else "", held, chunk, held * chunk,
                client.mtu)))


STUCK_ROUNDS = 4  # heartbeat periods with the same fragments held: the board cannot take more
MAX_WATCHED_STREAMS = 4096


def _info(entry: ObjectEntry) -> dict:
    if entry.info is None:
        entry.info = {}
    return entry.info


def _topic(entry: ObjectEntry) -> str:
    service = (entry.info or {}).get("service")
    if service is not None:
        return service["name"]
    return ros_topic_name(entry.topic_spec.name) if entry.topic_spec is not None else "?"
