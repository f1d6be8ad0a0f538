"""Reliability control and liveliness: ACKNACK/HEARTBEAT in both directions, dead, retired and expired clients (XRCE-WIRE.md §9, §10).

``Liveliness`` is the part of ``xrce.agent.engine.dispatch.Agent`` that answers a client's HEARTBEAT with
an ACKNACK, retransmits what a client's ACKNACK asks for, and does the timed work per client:
HEARTBEATs while reliable output is unacknowledged, hard-liveliness probes, dead, retired and
expired clients (the rule: "Recovery and liveliness" in docs/ARCHITECTURE.md) and paced READ_DATA
delivery.

Nothing is polled: that work runs from one loop timer (``loop.call_at``) set for the earliest time
something is due, HEARTBEATs ``heartbeat_period`` after unacknowledged output, a client's dead time
after it was last heard, a READ_DATA's deadline. With no client, or clients whose output is all
acknowledged, the agent wakes at most once per dead time per client (and every 0.5 s for a minute
after a new client appears beside dead ones on their host: ``_retirement``).
"""

from __future__ import annotations

import logging
import threading

import math
from typing import Tuple

from xrce import constants as C
from xrce.agent.engine.session import STREAM_WINDOW, ClientProxy
from xrce.streams import InputReliableStream, OutputReliableStream, is_reliable
from xrce.submessages import AckNack, GetInfo, Heartbeat

log = logging.getLogger("xrce.agent")

HARD_LIVELINESS_PROBES = 3
NEVER = math.inf
# After a new client appears on a host, how long (s) its dead neighbours are checked, and how
# often, for the participant that would show it to be one of them started over.
SUCCESSOR_WATCH_S = 60.0
SUCCESSOR_CHECK_S = 0.5


class Liveliness:
    """Mixin of ``Agent``. Uses the agent's ``stats``, ``clock``, ``heartbeat_period``,
    ``client_dead_time`` and ``client_expire_time``; ``_send_client``/``_send_stream0`` and
    ``_pump`` (data path), ``_process_reliable_message`` (dispatcher), ``_delete_client``."""

    # ------------------------------------------------------------------ timer --

    def _wake_at(self, due: float) -> None:
        """Run ``tick()`` at ``due`` (agent clock) unless it is already set to run sooner."""
        if due >= self._timer_due or self.loop is None:
            return
        if threading.get_ident() != self._loop_thread:
            # Output sent from the middleware's thread (datapath): the loop owns its timers.
            self.loop.call_soon_threadsafe(self._wake_at, due)
            return
        if self._timer is not None:
            self._timer.cancel()
        self._timer_due = due
        delay = due - self.clock()
        self._timer = self.loop.call_at(self.loop.time() + (delay if delay > 0 else 0.0),
                                        self._on_timer)

    def _heartbeat_soon(self) -> None:
        """Reliable output went out: its HEARTBEAT round is due one period from now."""
        due = self.clock() + self.heartbeat_period
        if due < self._timer_due:
            self._wake_at(due)

    def _on_timer(self) -> None:
        self._timer = None
        self._timer_due = NEVER
        self.tick()

    def _cancel_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self._timer = None
        self._timer_due = NEVER

    def _on_acknack(self, client: ClientProxy, acknack: AckNack) -> None:
        stream = client.out_reliable.get(acknack.stream_id)
        if stream is None:
            return
        now = self.clock()
        if client.heartbeat_sent_at is not None:
            client.rtt_s = now - client.heartbeat_sent_at
            client.heartbeat_sent_at = None
            if client.fast is not None:  # the compiled path may take ACKNACKs again
                client.fast.probing(False)
        now_ms = int(now * 1000)
        holdoff_ms = int(self.heartbeat_period * 1000) // 2
        stored = stream.stored_bytes
        resend = stream.on_acknack(acknack.first_unacked, acknack.nack_bitmap, now_ms, holdoff_ms)
        self._charge(client, stream.stored_bytes - stored)
        for message in resend:
            self.stats.retransmissions += 1
            client.retransmissions += 1
            self._send_client(client, message)
        if client.out_pending:
            self._send_pending(client, stream)
        if client.blocked_readers and stream.has_room():
            self._unblock(client)

    def _unblock(self, client: ClientProxy) -> None:
        blocked = list(client.blocked_readers)
        client.blocked_readers.clear()
        for object_id in blocked:
            entry = client.objects.get(object_id)
            if entry is not None and entry.reader is not None:
                self._pump(client, entry)

    def _on_heartbeat(self, client: ClientProxy, heartbeat: Heartbeat) -> None:
        stream_id = heartbeat.stream_id
        if not is_reliable(stream_id):
            return
        stream = client.in_reliable.get(stream_id)
        if stream is None:
            stream = client.in_reliable[stream_id] = InputReliableStream(stream_id, STREAM_WINDOW)
        stored = stream.stored_bytes
        try:
            for message in stream.on_heartbeat(heartbeat.first_unacked, heartbeat.last_unacked):
                self._process_reliable_message(client, stream_id, message)
        finally:
            self._charge(client, stream.stored_bytes - stored)
        if client.alive:
            self._send_acknack(client, stream)

    def _drop_out_of_order(self, client: ClientProxy) -> None:
        """Give back what a silent client's streams hold out of order: not acknowledged (the
        ACKNACK names them missing again), so nothing it sent is lost by it."""
        for stream in client.in_reliable.values():
            if stream.stored:
                self._charge(client, -stream.stored_bytes)
                stream.stored.clear()
                stream.stored_bytes = 0

    def _send_acknack(self, client: ClientProxy, stream: InputReliableStream) -> None:
        first, bitmap = stream.acknack()
        self.stats.acknacks_out += 1
        self._send_stream0(client, AckNack(first, bitmap, stream.stream_id))

    def _quiet_limit(self, client: ClientProxy) -> float:
        """Silence after which something happens to ``client``: its dead time, or its expiry if
        that comes first (the timer is set for it)."""
        dead_time = client.hard_liveliness or self.client_dead_time
        expire_time = self.client_expire_time
        return expire_time if expire_time and expire_time < dead_time else dead_time

    def _retirement(self, client: ClientProxy, now: float) -> Tuple[str, float]:
        """Why a dead client is certainly gone ("" while it may still be there, asleep), and
        when to look again. Gone: its TCP connection or serial port closed, or a client with
        another key, created from the same host after it last spoke, created the same
        participant (what a board does after a reboot or rmw's fini and init under a new
        ``rand()`` key). A board that sleeps is never retired for its silence alone; see
        "Recovery and liveliness" in docs/ARCHITECTURE.md for what a spoofed one can do."""
        if client.closed:
            return "its %s endpoint %r closed" % (client.link.name, client.endpoint), NEVER
        record = self.hosts.get(client.host)
        if record is None or record.born_at <= client.last_seen:
            return "", NEVER
        mine = None
        for other in record.members:
            if other is client or other.created_at <= client.last_seen:
                continue
            if mine is None:
                mine = _participants(client)
                if not mine:
                    return "", NEVER
            if any(signature in mine for signature in _participants(other)):
                return "client %s, created since from the same host %s, has its participant" % (
                    other.key.hex(), _host_text(client.host)), NEVER
        # A newer neighbour without that participant (yet): it may still be on its way there
        # (PX4 syncs its clock for ~6 s first). Look again for a while, then wait for the next.
        if now - record.born_at < SUCCESSOR_WATCH_S:
            return "", now + SUCCESSOR_CHECK_S
        return "", NEVER

    def _tick_client(self, client: ClientProxy, now: float) -> float:
        """The timed work for one client; returns when it next has some (``NEVER``: only when
        the client speaks again)."""
        dead_time = client.hard_liveliness or self.client_dead_time
        silent = now - client.last_seen
        expire_time = self.client_expire_time
        if expire_time and silent >= expire_time:
            # What --client-expire-time says: counted from its last message, whatever the dead
            # time (the dead time used to gate it: 30 s before a 3 s expiry was applied).
            self.stats.clients_expired += 1
            log.info("client %s silent for %d ms: expired, deleting its %d objects",
                     client.key.hex(), int(silent * 1000), len(client.objects))
            self._delete_client(client)
            return NEVER
        if silent >= dead_time:
            if not client.dead:
                client.dead = True
                self.stats.clients_dead += 1
                if _still_reading(client):
                    # A receive-only client (a best-effort subscriber) has nothing to say while its
                    # data arrives: eProsima's dead time applies all the same, but "dead" would
                    # alarm someone watching samples reach it.
                    log.info("client %s has sent nothing for %d ms but still reads: its samples "
                             "keep going out, HEARTBEATs pause until it speaks", client.key.hex(),
                             int(silent * 1000))
                else:
                    log.info("client %s silent for %d ms: dead (no more HEARTBEATs); its "
                             "entities are kept, any message revives it", client.key.hex(),
                             int(silent * 1000))
                self._drop_out_of_order(client)
            if not client.objects and not client.hard_liveliness:
                # Nothing to keep for it: a session that never created anything (a flood's, or
                # a board that went away before its first CREATE) gives its memory back. A board
                # that comes back finds no session and creates it again, as after a restart.
                self.stats.clients_expired += 1
                log.info("client %s silent for %d ms with no objects: expired", client.key.hex(),
                         int(silent * 1000))
                self._delete_client(client)
                return NEVER
            reason, recheck = self._retirement(client, now)
            if reason:
                self.stats.clients_retired += 1
                log.info("client %s silent for %d ms and %s: retired, deleting its %d objects",
                         client.key.hex(), int(silent * 1000), reason, len(client.objects))
                self._delete_client(client)
                return NEVER
            if client.hard_liveliness:
                if client.probes >= HARD_LIVELINESS_PROBES:
                    log.info("client %s missed %d liveliness probes", client.key.hex(), client.probes)
                    self._delete_client(client)
                    return NEVER
                client.probes += 1
                self._send_stream0(client, GetInfo(C.REQUEST_ID_INVALID, C.OBJECTID_CLIENT,
                                                   C.INFO_CONFIGURATION))
                return now + self.heartbeat_period
            # Dead clients get no HEARTBEATs; only their expiry (if set) is due.
            expiry = client.last_seen + expire_time if expire_time else NEVER
            return recheck if recheck < expiry else expiry
        due = client.last_seen + self._quiet_limit(client)
        soon = now + self.heartbeat_period
        for stream in list(client.out_reliable.values()):
            if stream.__class__ is not OutputReliableStream:
                self._release_acknowledged(client, stream)  # nothing may be sent for a while
            span = stream.heartbeat()
            if span is not None:
                self.stats.heartbeats_out += 1
                if client.heartbeat_sent_at is None and client.fast is not None:
                    client.fast.probing(True)  # this ACKNACK is Python's to time
                client.heartbeat_sent_at = now
                self._send_stream0(client, Heartbeat(span[0], span[1], stream.stream_id))
                due = soon
        for entry in list(client.objects.values()):
            reader = entry.reader
            if reader is not None and reader.active is not None:
                if reader.queue:
                    self._pump(client, entry)
                active = reader.active
                if active is None:
                    continue
                if reader.queue:
                    due = soon if soon < due else due
                elif active.deadline is not None:
                    if now >= active.deadline:
                        reader.active = None
                    elif active.deadline < due:
                        due = active.deadline
        return due


def _participants(client: ClientProxy) -> list:
    """The signatures (xrce.agent.engine.reuse) of the client's participants: equal for the same
    node created again, whatever the key or object ids."""
    return [entry.signature for entry in client.objects.values()
            if entry.kind == C.OBJK_PARTICIPANT]


def _host_text(host) -> str:
    if isinstance(host, tuple):  # (link name, serial device)
        return "%s %s" % host[:2]
    return str(host)


def _still_reading(client) -> bool:
    """True while a READ_DATA of the client is in force: the agent may be sending it samples."""
    return any(entry.reader is not None and entry.reader.active is not None
               for entry in client.objects.values())
