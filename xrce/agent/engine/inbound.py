"""The engine's receive path: the message header, stream admission, submessage dispatch and the
parking of clients whose CREATE waits for a type build (XRCE-WIRE.md §1, §2, §5, §7).

``Inbound.receive`` takes every whole message the agent is handed (``Agent.receive``): a message
of a session the agent does not know gets the one answer it may, a session-less one opens or
describes a session, a client's goes through its input stream, best-effort or reliable, then
submessage by submessage to the part that handles it: ``Sessions``, ``ObjectRegistry``,
``DataPath``, ``Acknowledgments`` and ``Liveliness``. Nothing raises out of ``receive``.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from typing import Callable, Deque, Hashable

from xrce import DecodeError
from xrce.wire import constants as C
from xrce.wire.message import decode_header, header_size, iter_submessages
from xrce.wire.streams import InputBestEffortStream, InputReliableStream, is_reliable, seq_sub
from xrce.wire.submessages import (
    Heartbeat, TimestampReply, decode_payload, encode_message, sample_ids, Status,
)
from xrce.agent.engine.client import ClientProxy, ResumingStream
from xrce.agent.engine.limits import STREAM_WINDOW
from xrce.agent.engine.link import Link
from xrce.agent.engine.objects import Parked
from xrce.agent.engine.output import trace
from xrce.agent.engine.timeline import Timeline
from xrce.agent.log_levels import TRACE

log = logging.getLogger("xrce.agent")

# Messages a parked client may queue while its type builds. Beyond, its reliable streams stop
# advancing (the client retransmits: nothing acknowledged is lost); best-effort ones are dropped.
MAX_PARKED_MESSAGES = 512

_HANDLED = frozenset((C.CREATE, C.DELETE, C.READ_DATA, C.ACKNACK, C.HEARTBEAT, C.GET_INFO,
                      C.TIMESTAMP, C.RESET))


class Inbound:
    """Every message in, to the part that handles each of its submessages.

    Collaborators: ``table`` (clients by key and by endpoint), ``output``, ``budget`` (what parked
    and out-of-order messages hold), ``scheduler`` (the loop a parked client resumes on, when
    timed work is due), ``timelines``, ``stats``, ``lock`` (the engine's, taken to resume parked clients
    from the loop); then, given to ``connect``, the parts that call back into this one.
    ``admission``, ``tap`` and ``state`` are set by the agent (its properties of those names).
    """

    def __init__(self, table, output, budget, scheduler, timelines, stats, lock,
                 clock: Callable[[], float]):
        self.clients = table.clients
        self.endpoints = table.endpoints
        self.output = output
        self.budget = budget
        self._charge = budget.charge
        self.scheduler = scheduler
        self.timelines = timelines
        self.stats = stats
        self.lock = lock
        self.clock = clock
        self.admission = None
        self.tap = None
        self.state = None
        self._resumable: Deque[ClientProxy] = deque()  # parked clients whose build finished
        # A CREATE was handled in this turn of the loop: the client's next submessage waits for
        # the next turn (see process_message).
        self._yield_due = False

    def connect(self, datapath, acks, objects, sessions, liveliness) -> None:
        """The parts built after this one, as they are built with its bound methods: ``DataPath``
        with ``process_message`` (a message put together from FRAGMENTs), ``Acknowledgments``
        with ``process_reliable_message`` (the messages a HEARTBEAT lets a stream hand out)."""
        self.datapath = datapath
        self._fast_write = datapath.fast_write
        self._write_data = datapath.write_data
        self.acks = acks
        self.objects = objects
        self.sessions = sessions
        self.liveliness = liveliness

    def receive(self, link: Link, endpoint: Hashable, data) -> None:
        """Handle one whole XRCE message from ``endpoint`` on ``link``. Never raises."""
        data = bytes(data)
        stats = self.stats
        with self.lock:
            self._yield_due = False
            stats.messages_in += 1
            stats.bytes_in += len(data)
            admission = self.admission
            if admission is not None and not admission.admits_datagram(link, endpoint, data):
                stats.sources_refused += 1  # outside --allow-from: no session is looked up
                stats.dropped += 1
                return
            if self.tap is not None:
                self.tap("in", link, endpoint, data)
            try:
                # At -v 6 every message goes the general way, which traces it.
                if log.isEnabledFor(TRACE) or not self._fast_write(link, endpoint, data):
                    self._receive(link, endpoint, data)
            except DecodeError as exc:
                self.stats.decode_errors += 1
                self.stats.dropped += 1
                log.debug("dropped malformed message from %s %r (%s): %s", link.name, endpoint,
                          exc, data.hex())
            except Exception as exc:  # a bug or a middleware surprise must not take the agent down
                self.stats.handler_errors += 1
                self.stats.dropped += 1
                log.debug("dropped message from %s %r after %s: %s", link.name, endpoint,
                          exc.__class__.__name__, data.hex(), exc_info=True)

    def _receive(self, link: Link, endpoint: Hashable, data: bytes) -> None:
        header = decode_header(data)
        if log.isEnabledFor(TRACE):
            trace("in", link, endpoint, data, header.size)
        session_id = header.session_id
        if session_id in (C.SESSION_ID_NONE_WITH_KEY, C.SESSION_ID_NONE_WITHOUT_KEY):
            self._receive_sessionless(link, endpoint, data, header)
            return
        if session_id < C.SESSION_ID_WITHOUT_KEY_MASK:
            client = self.clients.get(header.key)
        else:
            key = self.endpoints.get((link, endpoint))
            client = self.clients.get(key) if key is not None else None
        if client is None:
            self._receive_unknown_client(link, endpoint, data, header)
            return
        if client.restored and not client.spoken:
            self._restored_spoke(client, link, endpoint)
        client.last_seen = self.clock()
        client.probes = 0
        if client.dead:
            client.dead = False
            self.stats.clients_revived += 1
            log.info("client %s is alive again", client.key.hex())
            self.scheduler.wake_at(client.last_seen + self.sessions.quiet_limit(client))
        client.messages_in += 1
        client.bytes_in += len(data)
        stream_id = header.stream_id
        if stream_id == C.STREAM_NONE:
            self.process_message(client, data, header.size, stream_id)
        elif is_reliable(stream_id):
            self._receive_reliable(client, stream_id, header.seq, data)
        else:
            stream = client.in_best_effort.get(stream_id)
            if stream is None:
                stream = client.in_best_effort[stream_id] = InputBestEffortStream(stream_id)
                if client.resume_inputs:  # restored: the board's numbers go on from where they are
                    stream.last_handled = (header.seq - 1) & 0xFFFF
            if stream.accept(header.seq):
                self.process_message(client, data, header.size, stream_id)
            else:
                self.stats.dropped += 1

    def _receive_reliable(self, client: ClientProxy, stream_id: int, seq: int, data: bytes) -> None:
        stream = client.in_reliable.get(stream_id)
        if stream is None:
            stream = client.in_reliable[stream_id] = InputReliableStream(stream_id, STREAM_WINDOW)
            if client.resume_inputs:
                # Restored: this process never saw the board's earlier numbers, and an ACKNACK
                # behind what the board has had acknowledged would make it count the whole
                # sequence space as acknowledged. Its first message here is the next one.
                stream.last_handled = stream.last_announced = (seq - 1) & 0xFFFF
        if self._hold_back(client, stream, seq, data):
            # Not accepted, so not acknowledged: the client sends it again after its next
            # HEARTBEAT, and nothing the agent acknowledged is ever dropped. No ACKNACK now: one
            # per refused message would make the client resend its window at once, in a loop.
            self.stats.budget_refused += 1
            return
        duplicates = stream.duplicates
        stored = stream.stored_bytes
        answered = client.messages_out
        try:
            for message in stream.receive(seq, data):
                self.process_reliable_message(client, stream_id, message)
        finally:
            self._charge(client, stream.stored_bytes - stored)
            self.stats.duplicates += stream.duplicates - duplicates
            client.duplicates += stream.duplicates - duplicates
            if client.alive:  # every reliable message is acknowledged, duplicates included
                # (a reassembled sample may have handed the stream to the compiled path)
                self.acks.acknack_soon(client, client.in_reliable.get(stream_id, stream))
                if client.messages_out != answered:
                    # It was answered (a STATUS): the client may react at once, so its ACKNACK
                    # follows the answer now, as eProsima's agent sends it, not at the batch's end.
                    self.acks.settle(client)

    def _hold_back(self, client: ClientProxy, stream: InputReliableStream, seq: int,
                   data: bytes) -> bool:
        """True if the message, new and in the window, would have to wait in a buffer (out of
        order, behind a parked CREATE, or a fragment) that the client's budget has no room for,
        or its parked client already holds MAX_PARKED_MESSAGES."""
        distance = seq_sub(seq, stream.last_handled)
        if distance == 0 or distance > stream.window or seq in stream.stored:
            return False  # a duplicate or out of the window: receive() counts and drops it
        if distance == 1 and client.parked is None and not _is_fragment(data):
            return False  # handled at once, kept nowhere
        if client.parked is not None and len(client.parked) >= MAX_PARKED_MESSAGES:
            return True
        return self.budget.over(client, len(data))

    def process_reliable_message(self, client: ClientProxy, stream_id: int, message: bytes) -> None:
        """One message of a batch the stream handed out: whatever goes wrong with it, the ones
        behind it (already taken from the stream and acknowledged) are still processed."""
        size = header_size(message[0])
        try:
            self.process_message(client, message, size, stream_id)
        except DecodeError:
            self.stats.decode_errors += 1
            client.decode_errors += 1
            log.debug("malformed reliable message from client %s: %s", client.key.hex(), message.hex())
        except Exception:
            self.stats.handler_errors += 1
            log.debug("reliable message of client %s failed", client.key.hex(), exc_info=True)

    def _receive_sessionless(self, link: Link, endpoint: Hashable, data: bytes, header) -> None:
        for sub_id, flags, start, end in iter_submessages(data, header.size):
            payload = decode_payload(sub_id, flags, data, start, end)
            if sub_id == C.CREATE_CLIENT:
                self.sessions.create_client(link, endpoint, header, payload,
                                            (flags, data, start, end))
            elif sub_id == C.GET_INFO:
                key = self.endpoints.get((link, endpoint))
                established = key is not None and key in self.clients and \
                    self.clients[key].session_id > C.SESSION_ID_WITHOUT_KEY_MASK
                self.sessions.reply_info(link, endpoint, header, payload, 1 if established else 0)
            else:
                self.stats.dropped += 1
            return  # only the first submessage of a session-less message counts

    def _receive_unknown_client(self, link: Link, endpoint: Hashable, data: bytes, header) -> None:
        """A message for a session the agent does not know: only its first submessage counts
        (as eProsima), and only two kinds get an answer, one at most per datagram: UDP sources
        are spoofable, and answering each of a datagram's submessages made the agent a
        reflector (5000 replies, 2-4x the bytes, for one 60 KB datagram)."""
        self.sessions.unknown_session(link, endpoint, header)
        for sub_id, flags, start, end in iter_submessages(data, header.size):
            if sub_id == C.DELETE:
                payload = decode_payload(sub_id, flags, data, start, end)
                if payload.object_id == C.OBJECTID_CLIENT:
                    self.output.send_raw(link, endpoint, encode_message(
                        header.session_id, header.stream_id, header.seq, header.key,
                        [Status(payload.request_id, payload.object_id)]))
                    return
            elif sub_id == C.GET_INFO:
                payload = decode_payload(sub_id, flags, data, start, end)
                self.sessions.reply_info(link, endpoint, header, payload, 0)
                return
            break
        self.stats.dropped += 1

    def process_message(self, client: ClientProxy, data: bytes, start: int, stream_id: int) -> None:
        """Submessages in order; the first failing one stops the rest of the message."""
        if client.parked is not None and stream_id != C.STREAM_NONE:
            if not is_reliable(stream_id) and (len(client.parked) >= MAX_PARKED_MESSAGES or
                                               self.budget.over(client, len(data))):
                self.stats.dropped += 1  # best effort; reliable ones were held back before
            else:
                client.parked.append((data, start, stream_id))
                self._charge(client, len(data))
            return
        try:
            for sub_id, flags, sub_start, sub_end in iter_submessages(data, start):
                if not client.alive:
                    return
                if self._yield_due and stream_id != C.STREAM_NONE:
                    # Creating an entity can take milliseconds: after one, the loop serves the
                    # other clients' datagrams before this client's next submessage.
                    self._park(client, data, sub_start - 4, stream_id)
                    self._resumable.append(client)
                    self.scheduler.loop.call_soon(self._resume_from_loop)
                    return
                try:
                    handled = self._handle_submessage(client, stream_id, data, sub_id, flags,
                                                      sub_start, sub_end)
                except Parked as parked:
                    # Resume at this CREATE's submessage header once the build is done.
                    self._park(client, data, sub_start - 4, stream_id)
                    parked.future.add_done_callback(lambda _, c=client: self._build_finished(c))
                    return
                if not handled:
                    return
                if sub_id == C.CREATE and self.scheduler.loop is not None and \
                        self.scheduler.on_loop_thread():
                    self._yield_due = True
        except DecodeError as exc:
            self.stats.decode_errors += 1
            client.decode_errors += 1
            log.debug("client %s: malformed submessage (%s) in %s", client.key.hex(), exc, data.hex())

    def _handle_submessage(self, client: ClientProxy, stream_id: int, data: bytes, sub_id: int,
                           flags: int, start: int, end: int) -> bool:
        if sub_id == C.WRITE_DATA:
            if flags & C.FLAG_FORMAT_MASK != C.FORMAT_DATA:
                return False
            if start == end:
                # Length 0: the sample runs to the end of the message, as the C client writes a
                # sample longer than 64 KiB (in FRAGMENTs); eProsima's agent reads it so too.
                end = len(data)
                request_id, object_id = sample_ids(data, start, end)
                self._write_data(client, request_id, object_id, data[start + 4:end])
                return False  # nothing follows it
            request_id, object_id = sample_ids(data, start, end)
            return self._write_data(client, request_id, object_id, data[start + 4:end])
        if sub_id == C.FRAGMENT:
            return self.datapath.fragment(client, stream_id, data, flags, start, end)
        if sub_id not in _HANDLED:
            return False  # CREATE_CLIENT in session, STATUS, INFO, DATA, … stop the message
        payload = decode_payload(sub_id, flags, data, start, end)
        if sub_id == C.CREATE or sub_id == C.DELETE:
            queued = client.queued_bytes  # a REPLACE or DELETE of a reader drops its queue
            if sub_id == C.CREATE:
                self.objects.create(client, payload, stream_id)
            elif payload.object_id == C.OBJECTID_CLIENT:
                self._delete_session(client, payload)
            else:
                self.objects.delete(client, payload, stream_id)
            self.budget.queued_total -= queued - client.queued_bytes
            if self.state is not None and client.alive:
                self.state.objects_changed(client, sub_id, flags, data, start, end, payload)
        elif sub_id == C.READ_DATA:
            self.datapath.read_data(client, payload)
            if self.state is not None:
                self.state.read_data(client, flags, data, start, end, payload)
        elif sub_id == C.ACKNACK:
            if client.resuming:
                client.resume_output(payload)
            self.liveliness.on_acknack(client, payload)
        elif sub_id == C.HEARTBEAT:
            if client.resume_inputs and is_reliable(payload.stream_id) and \
                    payload.stream_id not in client.in_reliable:
                # Restored: what the board still holds unacknowledged starts at first_unacked
                # (see _receive_reliable for why the stream cannot start anywhere else).
                stream = client.in_reliable[payload.stream_id] = InputReliableStream(
                    payload.stream_id, STREAM_WINDOW)
                stream.last_handled = stream.last_announced = (payload.first_unacked - 1) & 0xFFFF
            self.acks.on_heartbeat(client, payload)
        elif sub_id == C.GET_INFO:
            self.output.send_client(client, self.sessions.info_message(
                None, client.session_id, C.STREAM_NONE, 0, client.header_key, payload, 1))
        elif sub_id == C.TIMESTAMP:
            receive_ns = time.time_ns()
            client.timestamp_skew_ns = receive_ns - payload.ns()
            self.output.send_stream0(client, TimestampReply(time.time_ns(), receive_ns,
                                                            payload.ns()))
        elif sub_id == C.RESET:
            self.sessions.reset_streams(client)
        return True

    def _delete_session(self, client: ClientProxy, request) -> None:
        """DELETE of the client itself: the session and everything it created go; the STATUS
        goes out on stream none (the client's streams are gone with it)."""
        self.sessions.delete_client(client)
        self.output.send_raw(client.link, client.endpoint, encode_message(
            client.session_id, C.STREAM_NONE, 0, client.header_key,
            [Status(request.request_id, request.object_id)]))

    # ------------------------------------------------------------------ parked clients --

    def _park(self, client: ClientProxy, data: bytes, start: int, stream_id: int) -> None:
        if client.parked is None:
            client.parked = []
        client.parked.insert(0, (data, start, stream_id))  # before anything queued meanwhile
        self._charge(client, len(data))

    def _build_finished(self, client: ClientProxy) -> None:
        """Called from the build's thread: hand the client back to the loop."""
        self._resumable.append(client)
        loop = self.scheduler.loop
        if loop is not None:
            loop.call_soon_threadsafe(self._resume_from_loop)
        # Without a loop (synchronous tests), tick() resumes it.

    def _resume_from_loop(self) -> None:
        with self.lock:
            self.resume_parked()

    def resume_parked(self) -> None:
        """The parked clients whose build finished (``tick`` calls it, holding the lock)."""
        # Only the clients waiting now: one that parks again (the next CREATE of a storm) waits
        # for a later turn of the loop, after the other clients' datagrams.
        for _ in range(len(self._resumable)):
            client = self._resumable.popleft()
            pending, client.parked = client.parked, None
            if not client.alive or pending is None:
                continue
            self._charge(client, -sum(len(entry[0]) for entry in pending))
            self._yield_due = False
            for index, (data, start, stream_id) in enumerate(pending):
                try:
                    self.process_message(client, data, start, stream_id)
                except Exception:
                    self.stats.handler_errors += 1
                    log.debug("resumed message of client %s failed", client.key.hex(), exc_info=True)
                if client.parked is not None:  # parked again by another CREATE
                    rest = pending[index + 1:]
                    client.parked.extend(rest)
                    self._charge(client, sum(len(entry[0]) for entry in rest))
                    break

    # ------------------------------------------------------------------ restored sessions --

    def _restored_spoke(self, client: ClientProxy, link: Link, endpoint: Hashable) -> None:
        """The first message of a client restored from the state store: its session carries
        on. A session with its key in its headers may speak from another port now."""
        client.spoken = True
        if client.header_key is not None and (link, endpoint) != (client.link, client.endpoint):
            client.link, client.endpoint = link, endpoint
            if self.state is not None:
                self.state.client_moved(client)
        now = self.clock()
        log.info("client %s (restored from the store) spoke on %s %r: its session carries on "
                 "without a CREATE_CLIENT", client.key.hex(), link.name, endpoint)
        self.timelines.pending[client.key] = Timeline(client.key, "restored from the store",
                                                      now, now)
        for stream in list(client.out_reliable.values()):
            if stream.__class__ is ResumingStream:  # ask now rather than at the next tick
                span = stream.heartbeat()
                self.stats.heartbeats_out += 1
                self.output.send_stream0(client, Heartbeat(span[0], span[1], stream.stream_id))
        resync = client.input_resync
        if resync is not None:
            # Its own reliable streams may never say where they are (xrce.agent.engine.resync).
            due = resync.start(client, now, self.liveliness.resync_sender(client),
                               self.scheduler.heartbeat_period)
            if due is None:
                client.input_resync = None
            else:
                self.scheduler.wake_at(due)
        self.scheduler.wake_at(now + self.scheduler.heartbeat_period)


def _is_fragment(message: bytes) -> bool:
    head = header_size(message[0])
    return len(message) > head and message[head] == C.FRAGMENT
