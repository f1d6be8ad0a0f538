"""Reliability control and liveliness: ACKNACK/HEARTBEAT in both directions, dead, retired and expired clients (XRCE-WIRE.md §9, §10).

Two parts of ``xrce.agent.engine.agent.Agent``:

- ``Acknowledgments``, the input side: an ACKNACK for each client's reliable stream after a
  batch of its messages or before anything else is sent to it, whichever comes first, and in
  answer to its HEARTBEAT; a batch's repeated while the client stays silent on that stream
  (``ACKNACK_REPEATS_S``);
- ``Liveliness``, the output side and the timed work per client: it retransmits what a client's
  ACKNACK asks for, sends HEARTBEATs while reliable output is unacknowledged, probes
  hard-liveliness clients, finds dead, retired and expired clients (the rule: "Recovery and
  liveliness" in docs/ARCHITECTURE.md) and paces READ_DATA delivery.

Nothing is polled: that work runs from one loop timer (``xrce.agent.engine.scheduler``) set for
the earliest time something is due, HEARTBEATs ``heartbeat_period`` after unacknowledged output,
a client's dead time after it was last heard, a READ_DATA's deadline. With no client, or clients
whose output is all acknowledged, the agent wakes at most once per dead time per client (and
every 0.5 s for a minute after a new client appears beside dead ones on their host:
``Sessions.retirement``).
"""

from __future__ import annotations

import logging
from typing import Dict, Tuple

from xrce.wire import constants as C
from xrce.agent.engine.scheduler import NEVER
from xrce.agent.engine.client import ClientProxy
from xrce.agent.engine.limits import STREAM_WINDOW
from xrce.wire.streams import InputReliableStream, OutputReliableStream, is_reliable
from xrce.wire.submessages import AckNack, GetInfo, Heartbeat

log = logging.getLogger("xrce.agent")

HARD_LIVELINESS_PROBES = 3

# When one ACKNACK answered several messages and the client then says nothing more on that
# stream, it is sent again after these delays (seconds since the first), at most one repeat per
# message it answered beyond the first: eProsima's agent sends one per message, so a client whose
# ACKNACK was lost learns from the next one; one per batch lost would leave a client whose
# history is full waiting for its own HEARTBEAT, which eProsima's client library sends only after
# 100 ms without polling (a board spinning every 10 ms never does). Repeats stop at the first
# newer ACKNACK or message on the stream, so the count stays at or below one per message.
ACKNACK_REPEATS_S = (0.02, 0.06, 0.15, 0.4)


class Acknowledgments:
    """ACKNACKs for the clients' reliable input streams.

    Collaborators: ``clients`` (the agent's table, read only: a client replaced meanwhile gets
    no ACKNACK), ``output``, ``budget`` (what a stream holds out of order), ``scheduler`` (the
    loop a batch's ACKNACKs wait for) and ``process_reliable_message`` (the dispatcher, for the
    messages a HEARTBEAT lets a stream hand out). ``lock``: the engine's, held to send a
    batch's ACKNACKs from the loop."""

    def __init__(self, clients: dict, output, budget, scheduler, lock, stats,
                 process_reliable_message):
        self.clients = clients
        self.lock = lock
        self.output = output
        self.budget = budget
        self.scheduler = scheduler
        self.stats = stats
        self._process_reliable_message = process_reliable_message
        # client key -> (client, {stream id: stream}) of the ACKNACKs owed; shared with the
        # output, which settles a client's before anything else goes to it.
        self._due: Dict[bytes, Tuple[ClientProxy, Dict[int, InputReliableStream]]] = {}
        output.owed = self._due
        output.settle = self.settle

    def acknack_soon(self, client: ClientProxy, stream: InputReliableStream) -> None:
        """ACKNACK a stream's messages no later than the first of: the end of the read batch,
        or anything else the agent sends that client. The ACKNACK is cumulative, so one sent
        then says what one per message would have said last; and as a client can only react to
        what it receives, it never waits a round trip for it (a client answering each STATUS at
        once with its next CREATE kept one batch open across round trips, and its history of 8
        filled before any ACKNACK came). So at most one per reliable message, as eProsima's agent
        sends. Without a loop (synchronous use, tests, golden replays) it goes out at once."""
        loop = self.scheduler.loop
        if loop is None:
            self.send_acknack(client, stream)
            return
        due = self._due
        if not due:
            loop.call_soon(self.flush)
        owed = due.get(client.key)
        if owed is None or owed[0] is not client:
            due[client.key] = (client, {stream.stream_id: stream})
        else:
            owed[1][stream.stream_id] = stream

    def flush(self) -> None:
        """Every owed ACKNACK, now (the end of a read batch, or of a hand-over's round)."""
        with self.lock:
            for key in list(self._due):
                owed = self._due.get(key)
                if owed is not None:
                    self.settle(owed[0])

    def settle(self, client: ClientProxy) -> None:
        """The ACKNACKs ``client`` is owed, now (the output calls it first for such a client)."""
        owed = self._due.pop(client.key, None)
        if owed is None:
            return
        client = owed[0]
        if not client.alive or self.clients.get(client.key) is not client:
            return
        for stream_id, stream in owed[1].items():
            if client.in_reliable.get(stream_id) is stream:
                try:
                    self.send_acknack(client, stream)
                except Exception:
                    self.stats.handler_errors += 1
                    log.debug("ACKNACK to client %s failed", client.key.hex(), exc_info=True)

    def send_acknack(self, client: ClientProxy, stream: InputReliableStream) -> None:
        first, bitmap = stream.acknack()
        self.stats.acknacks_out += 1
        self.output.send_stream0(client, AckNack(first, bitmap, stream.stream_id))
        sent = client.acknacks_sent
        last = sent.get(stream.stream_id)
        held, duplicates = len(stream.stored), stream.duplicates
        # The messages received since the last ACKNACK, each of which eProsima's agent would
        # have answered with one: those the stream handed out since, the change in those it holds
        # out of order, and repeats of ones it had (a client's retransmissions after a lost
        # ACKNACK are all duplicates but one).
        covered = 1 if last is None else (((first - last[0]) & 0xFFFF) + held - last[2]
                                          + duplicates - last[3])
        if last is not None and covered <= 0:
            return  # nothing new (a HEARTBEAT's answer): the repeats already set stand
        record = sent[stream.stream_id] = [first, min(covered - 1, len(ACKNACK_REPEATS_S)), held,
                                           duplicates]
        loop = self.scheduler.loop
        if record[1] > 0 and loop is not None:
            loop.call_later(ACKNACK_REPEATS_S[0], self._repeat, client, stream, record, 0)

    def _repeat(self, client: ClientProxy, stream: InputReliableStream, record: list,
                index: int) -> None:
        """The ACKNACK ``record`` names, once more, unless the stream moved on (a newer one was
        sent: ``record`` is no longer the stream's) or the client went."""
        with self.lock:
            if (not client.alive or self.clients.get(client.key) is not client
                    or client.in_reliable.get(stream.stream_id) is not stream
                    or client.acknacks_sent.get(stream.stream_id) is not record
                    or stream.acknack()[0] != record[0] or len(stream.stored) != record[2]
                    or record[1] <= 0):
                return
            record[1] -= 1
            first, bitmap = stream.acknack()
            self.stats.acknacks_out += 1
            try:
                self.output.send_stream0(client, AckNack(first, bitmap, stream.stream_id))
            except Exception:
                self.stats.handler_errors += 1
                log.debug("ACKNACK repeat to client %s failed", client.key.hex(), exc_info=True)
                return
            if record[1] > 0 and index + 1 < len(ACKNACK_REPEATS_S):
                self.scheduler.loop.call_later(
                    ACKNACK_REPEATS_S[index + 1] - ACKNACK_REPEATS_S[index], self._repeat,
                    client, stream, record, index + 1)

    def on_heartbeat(self, client: ClientProxy, heartbeat: Heartbeat) -> None:
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
            self.budget.charge(client, stream.stored_bytes - stored)
        if client.alive:
            self.send_acknack(client, stream)


class Liveliness:
    """Retransmission on ACKNACK and the timed work per client (``tick_client``).

    Collaborators: ``sessions`` (dead time, retirement, deletion of a client), ``datapath``
    (paced delivery), ``stream_output`` (pending output, windows the compiled path
    acknowledged), ``output``, ``budget``, ``mismatches`` (a board that holds fragments it can
    never complete)."""

    def __init__(self, sessions, datapath, stream_output, output, budget, mismatches, stats,
                 clock, *, heartbeat_period: float, client_expire_time: float):
        self.sessions = sessions
        self.datapath = datapath
        self.stream_output = stream_output
        self.output = output
        self.budget = budget
        self.mismatches = mismatches
        self.stats = stats
        self.clock = clock
        self.heartbeat_period = heartbeat_period
        self.client_expire_time = client_expire_time

    def resync_sender(self, client: ClientProxy):
        """How ``InputResync`` sends its ACKNACKs to ``client``."""
        def send(acknack: AckNack) -> None:
            self.stats.acknacks_out += 1
            self.output.send_stream0(client, acknack)
        return send

    def on_acknack(self, client: ClientProxy, acknack: AckNack) -> None:
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
        if acknack.nack_bitmap and not acknack.nack_bitmap & 1:  # fragments held: mismatch_report.py
            self.mismatches.acknack_holds_fragments(client, stream, acknack)
        self.budget.charge(client, stream.stored_bytes - stored)
        for message in resend:
            self.stats.retransmissions += 1
            client.retransmissions += 1
            self.output.send_client(client, message)
        if client.out_pending:
            self.stream_output.send_pending(client, stream)
        if client.blocked_readers and stream.has_room():
            self._unblock(client)

    def _unblock(self, client: ClientProxy) -> None:
        blocked = list(client.blocked_readers)
        client.blocked_readers.clear()
        for object_id in blocked:
            entry = client.objects.get(object_id)
            if entry is not None and entry.reader is not None:
                self.datapath.pump(client, entry)

    def _drop_out_of_order(self, client: ClientProxy) -> None:
        """Give back what a silent client's streams hold out of order: not acknowledged (the
        ACKNACK names them missing again), so nothing it sent is lost by it."""
        for stream in client.in_reliable.values():
            if stream.stored:
                self.budget.charge(client, -stream.stored_bytes)
                stream.stored.clear()
                stream.stored_bytes = 0

    def tick_client(self, client: ClientProxy, now: float) -> float:
        """The timed work for one client; returns when it next has some (``NEVER``: only when
        the client speaks again)."""
        dead_time = self.sessions.dead_time(client)
        silent = now - client.last_seen
        expire_time = self.client_expire_time
        if expire_time and silent >= expire_time:
            # What --client-expire-time says: counted from its last message, whatever the dead
            # time (the dead time used to gate it: 30 s before a 3 s expiry was applied).
            self.stats.clients_expired += 1
            log.info("client %s silent for %d ms: expired, deleting its %d objects",
                     client.key.hex(), int(silent * 1000), len(client.objects))
            self.sessions.delete_client(client)
            return NEVER
        if silent >= dead_time:
            return self._tick_dead(client, now, silent)
        return self._tick_live(client, now)

    def _tick_dead(self, client: ClientProxy, now: float, silent: float) -> float:
        """The timed work for a client silent for its dead time: mark it dead, then expire,
        retire or probe it (hard liveliness); returns when it next has some."""
        expire_time = self.client_expire_time
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
            self.sessions.delete_client(client)
            return NEVER
        reason, recheck = self.sessions.retirement(client, now)
        if reason:
            self.stats.clients_retired += 1
            log.info("client %s silent for %d ms and %s: retired, deleting its %d objects",
                     client.key.hex(), int(silent * 1000), reason, len(client.objects))
            self.sessions.delete_client(client)
            return NEVER
        if client.hard_liveliness:
            if client.probes >= HARD_LIVELINESS_PROBES:
                log.info("client %s missed %d liveliness probes", client.key.hex(), client.probes)
                self.sessions.delete_client(client)
                return NEVER
            client.probes += 1
            self.output.send_stream0(client, GetInfo(C.REQUEST_ID_INVALID, C.OBJECTID_CLIENT,
                                               C.INFO_CONFIGURATION))
            return now + self.heartbeat_period
        # Dead clients get no HEARTBEATs; only their expiry (if set) is due.
        expiry = client.last_seen + expire_time if expire_time else NEVER
        return recheck if recheck < expiry else expiry

    def _tick_live(self, client: ClientProxy, now: float) -> float:
        """The timed work for a client that spoke within its dead time: its input streams set
        going again (a restored session), HEARTBEATs for its reliable output, its readers' paced
        delivery and deadlines; returns when it next has some."""
        due = client.last_seen + self.sessions.quiet_limit(client)
        soon = now + self.heartbeat_period
        resync = client.input_resync
        if resync is not None and client.spoken:
            again = resync.run(client, now, self.resync_sender(client), self.heartbeat_period)
            if again is None:
                client.input_resync = None
            elif again < due:
                due = again
        for stream in list(client.out_reliable.values()):
            if stream.__class__ is not OutputReliableStream:
                self.stream_output.release_acknowledged(client, stream)  # nothing may be sent for a while
            span = stream.heartbeat()
            if span is not None:
                self.stats.heartbeats_out += 1
                if client.heartbeat_sent_at is None and client.fast is not None:
                    client.fast.probing(True)  # this ACKNACK is Python's to time
                client.heartbeat_sent_at = now
                self.output.send_stream0(client, Heartbeat(span[0], span[1], stream.stream_id))
                due = soon
        for entry in list(client.objects.values()):
            reader = entry.reader
            if reader is not None and reader.active is not None:
                if reader.queue:
                    self.datapath.pump(client, entry)
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



def _still_reading(client) -> bool:
    """True while a READ_DATA of the client is in force: the agent may be sending it samples."""
    return any(entry.reader is not None and entry.reader.active is not None
               for entry in client.objects.values())
