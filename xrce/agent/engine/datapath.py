"""The per-message data path: samples in (WRITE_DATA, FRAGMENT) and out (READ_DATA delivery, DATA) (XRCE-WIRE.md §6–§8).

Everything a sample touches between the dispatcher (``xrce.agent.engine.inbound``) and the middleware is
here, so this module is the one to read and profile for throughput:

- in: ``write_data`` hands a WRITE_DATA's bytes to ``middleware.write``; ``fragment`` reassembles
  FRAGMENTs of a reliable stream and feeds the whole message back to the dispatcher;
- out: the middleware's callbacks queue samples per reader (``from_middleware``, ``_enqueue``,
  bounded per client), on the middleware's own thread when the client's link allows it;
  ``pump`` sends them as DATA while the client's READ_DATA and the stream's window allow,
  through ``xrce.agent.engine.stream_output`` (numbering, the reliable window, FRAGMENTs).

With the optional compiled UDP path (``xrce.agent.engine.compiled.fastpath``), WRITE_DATA of writers this path
has handled once (best-effort, and reliable ones next in order) are published by the UDP link's read
before they reach Python; what ``fast_write`` hands it (``offer``) is how it learns which ones.
"""

from __future__ import annotations

import logging
import threading
from typing import Hashable, Optional

from xrce.wire import constants as C
from xrce.agent.engine.client import ClientProxy, ObjectEntry, ReadRequest
from xrce.agent.engine.limits import MAX_REASSEMBLY, DataLimits
from xrce.agent.engine.link import Link
from xrce.agent.engine.stream_output import data_message
from xrce.wire.message import header_size
from xrce.wire.streams import is_reliable
from xrce.wire.submessages import ReadData

log = logging.getLogger("xrce.agent")
C_WRITE_DATA = C.WRITE_DATA  # a module global: one attribute lookup less per sample
C_DATAWRITER = C.OBJK_DATAWRITER
C_REPLIER = C.OBJK_REPLIER
# How long a READ_DATA with max_samples 0 waits for its first sample: eProsima's reader thread's
# longest single read (see DataPath.read_data).
ZERO_SAMPLES_FIRST_READ_S = 0.1


class DataPath:
    """Sample input, per-reader queues and READ_DATA delivery.

    Collaborators: ``table`` (clients by key and by endpoint, looked up by ``fast_write``),
    ``middleware``, ``stream_output`` (DATA and STATUS out on a client's streams), ``budget``
    (the bytes reassembly and queues hold), ``scheduler`` (when timed work is due, which thread
    is the loop's), ``acks`` (ACKNACK after a reliable sample), ``mismatches`` (samples a board's
    stream cannot carry), ``timelines``, ``fastpaths`` (the compiled receive paths) and ``lock`` (held for samples
    from the middleware's thread). ``process_message``: the dispatcher, for a message put
    together from FRAGMENTs. ``limits``: what a client's reassembly and reader queues may hold.
    """

    def __init__(self, table, middleware, stream_output, budget, scheduler, acks, mismatches,
                 timelines, fastpaths: list, lock, stats, clock, process_message,
                 limits: DataLimits):
        # What the per-sample paths use, bound once: no hop through another part per sample.
        self.clients = table.clients
        self.endpoints = table.endpoints
        self.middleware = middleware
        self._send_on_stream = stream_output.send_on_stream
        self._send_status = stream_output.send_status
        self.budget = budget
        self.scheduler = scheduler
        self._wake_at = scheduler.wake_at
        self._acknack_soon = acks.acknack_soon
        self.mismatches = mismatches
        self.timelines = timelines
        self.fastpaths = fastpaths
        self.lock = lock
        self.stats = stats
        self.clock = clock
        self._process_message = process_message
        # Read per queued sample and per FRAGMENT: plain attributes (the agent's
        # ``max_reassembly_bytes`` setter changes the first).
        self.max_reassembly_bytes = limits.max_reassembly_bytes
        self.max_output_queue_bytes = limits.max_output_queue_bytes

    def fast_write(self, link: Link, endpoint: Hashable, data: bytes) -> bool:
        """The common case in one step: a message holding exactly one WRITE_DATA (FORMAT_DATA) of
        a live session, to a writer created earlier, on a best-effort stream or as the next
        message in order of a reliable one. Anything else (and each stream's first message)
        returns False untouched and takes the general path (``Inbound._receive``), which keeps
        exactly the same counters and checks; this one skips the header object, the submessage
        iterator and several layers of calls."""
        if len(data) < 12:
            return False  # too short to hold a WRITE_DATA
        session_id = data[0]
        if session_id & 0x7F == 0:
            return False  # session-less
        if session_id & 0x80:
            key = self.endpoints.get((link, endpoint))
            start = 4
        else:
            key = data[4:8]
            start = 8
        client = self.clients.get(key)
        stream_id = data[1]
        if client is None or client.dead or client.parked is not None or stream_id == 0 \
                or len(data) < start + 8:
            return False
        if self.timelines.pending and client.key in self.timelines.pending:
            return False  # a client coming back: write_data notes its first sample into ROS
        length = data[start + 2] | (data[start + 3] << 8)
        end = start + 4 + length
        # PX4's client pads every datagram to a multiple of 4 bytes: up to 3 bytes after the
        # submessage are its alignment padding, as iter_submessages reads them.
        if data[start] != C_WRITE_DATA or data[start + 1] & C.FLAG_FORMAT_MASK != C.FORMAT_DATA \
                or not end <= len(data) <= ((end + 3) & ~3) or length < 4:
            return False
        entry = client.objects.get((data[start + 6] << 8) | data[start + 7])
        if entry is None or entry.write is None:
            return False
        seq = data[2] | (data[3] << 8)
        if stream_id & 0x80:
            stream = client.in_reliable.get(stream_id)
            if stream is None or stream.stored or seq != (stream.last_handled + 1) & 0xFFFF:
                return False  # out of order, a gap to fill, or a duplicate: the general path
        else:
            stream = client.in_best_effort.get(stream_id)
            if stream is None:
                return False
        client.last_seen = self.clock()
        client.probes = 0
        client.messages_in += 1
        client.bytes_in += len(data)
        if stream_id & 0x80:
            stream.receive(seq, data)  # in order, nothing stored: hands back this one message
        elif not stream.accept(seq):
            self.stats.dropped += 1
            return True
        self.stats.samples_in += 1
        entry.samples += 1
        entry.sample_bytes += length - 4
        if not entry.write(data[start + 8:end]) and entry.kind == C_DATAWRITER:
            self.stats.publish_errors += 1
        if entry.kind == C_DATAWRITER or entry.kind == C_REPLIER:
            fastpath = link.fastpath
            if fastpath is not None:  # the next ones may not need Python (xrce.agent.engine.compiled.fastpath)
                fastpath.offer(client, stream_id, entry)
        if stream_id & 0x80 and client.alive:
            # offer() may have handed the stream's numbers to C: acknowledge the stream now held
            self._acknack_soon(client, client.in_reliable.get(stream_id, stream))
        return True

    def write_data(self, client: ClientProxy, request_id: int, object_id: int, data: bytes) -> bool:
        entry = client.objects.get(object_id)
        if entry is None:
            return False
        key = client.entity(entry.object_id)
        self.stats.samples_in += 1
        entry.samples += 1
        entry.sample_bytes += len(data)
        if entry.kind == C.OBJK_DATAWRITER:
            # The writer bound at creation when there is one (reassembled fragments come here).
            write = entry.write
            written = bool(write(data) if write is not None else self.middleware.write(key, data))
            if not written:
                self.stats.publish_errors += 1
            elif self.timelines.pending:
                self.timelines.sample_into_ros(client)
            return written
        if entry.kind == C.OBJK_REQUESTER:
            correlation_id = (entry.object_id << 16) + request_id
            return bool(self.middleware.write_request(key, correlation_id, data))
        if entry.kind == C.OBJK_REPLIER:
            return entry.write(data)
        return False

    def reply_writer(self, client: ClientProxy, object_id: int):
        """A replier's ``ObjectEntry.write``: its reply (sample identity, then the body) into the
        middleware, or to the compiled path when it took the request. Bound like a writer's so
        that ``fast_write`` takes a firmware's replies (one WRITE_DATA per message on its
        reliable stream) without the general path's decoding."""
        write_reply = self.middleware.write_reply
        key = client.entity(object_id)
        fastpaths = self.fastpaths

        def write(data: bytes) -> bool:
            if len(data) < 24:
                return False
            for fastpath in fastpaths:  # (only where C holds repliers)
                if fastpath.repliers:
                    sent = fastpath.send_reply(client, object_id, data)
                    if sent is not None:
                        return sent
            return bool(write_reply(key, data[:24], data[24:]))
        return write

    def sample_callback(self, client: ClientProxy, object_id: int):
        fastpaths = self.fastpaths

        def on_data(sample: bytes) -> None:
            for fastpath in fastpaths:  # (only where C holds the reader: see reclaim_reader)
                if fastpath.reader_tokens:
                    fastpath.reclaim_reader(client, object_id)
            self.from_middleware(client, object_id, bytes(sample))
        return on_data

    def request_callback(self, client: ClientProxy, object_id: int):
        fastpaths = self.fastpaths

        def on_request(sample_identity: bytes, request: bytes) -> None:
            for fastpath in fastpaths:  # (only where C holds the replier: see reclaim_reader)
                if fastpath.repliers:
                    fastpath.reclaim_reader(client, object_id)
            self.from_middleware(client, object_id, bytes(sample_identity) + bytes(request))
        return on_request

    def reply_callback(self, client: ClientProxy, object_id: int):
        def on_reply(correlation_id: int, reply: bytes) -> None:
            # The reply travels behind the BaseObjectRequest of the WRITE_DATA that asked (§6).
            request_id = correlation_id & 0xFFFF
            prefix = bytes((request_id >> 8, request_id & 0xFF, object_id >> 8, object_id & 0xFF))
            self.from_middleware(client, object_id, prefix + bytes(reply))
        return on_reply

    def from_middleware(self, client: ClientProxy, object_id: int, payload: bytes) -> None:
        """A sample for a reader, on the loop's thread or on the middleware's holding ``lock``
        (see ``xrce.agent.middleware``). It goes out from the calling thread when the client's
        link can send from any thread (UDP); otherwise it takes the loop's turn, behind what the
        loop already has to send."""
        scheduler = self.scheduler
        if scheduler.loop is not None and threading.get_ident() != scheduler.thread and \
                not client.link.sends_from_any_thread:
            scheduler.loop.call_soon_threadsafe(self.from_middleware, client, object_id, payload)
            return
        with self.lock:
            self._enqueue(client, object_id, payload)

    def _enqueue(self, client: ClientProxy, object_id: int, payload: bytes) -> None:
        if not client.alive:
            return
        entry = client.objects.get(object_id)
        if entry is None or entry.reader is None:
            return
        queue = entry.reader.queue
        size = len(payload)
        budget = self.budget
        # The reader's own bound pushes its oldest sample out when the new one is appended.
        pushed_out = len(queue[0]) if queue.maxlen is not None and len(queue) == queue.maxlen else 0
        if client.queued_bytes - pushed_out + size > self.max_output_queue_bytes:
            dropped = 0
            while queue and client.queued_bytes + size > self.max_output_queue_bytes:
                self._unqueue(client, queue.popleft())
                dropped += 1
            pushed_out = len(queue[0]) if queue.maxlen is not None and len(queue) == queue.maxlen \
                else 0
            if client.queued_bytes - pushed_out + size > self.max_output_queue_bytes:
                dropped += 1  # other readers hold the space: the new sample is the one to go
                self.stats.quota_output_dropped += dropped
                client.warn_quota("output", self.clock(), "output queue quota (%d bytes) full, "
                                  "sample for 0x%04X dropped", self.max_output_queue_bytes,
                                  object_id)
                return
            self.stats.quota_output_dropped += dropped
            client.warn_quota("output", self.clock(), "output queue quota (%d bytes) full, %d "
                              "oldest samples of 0x%04X dropped", self.max_output_queue_bytes,
                              dropped, object_id)
        grows = size - pushed_out  # the budget test inlined: this runs for every sample out
        if grows > 0 and (client.buffered + client.queued_bytes + grows > budget.max_client_bytes
                          or budget.buffered_total + budget.queued_total + grows >
                          budget.max_total_bytes):
            self.stats.quota_output_dropped += 1
            client.warn_quota("budget", self.clock(), "memory budget (%d bytes per client, %d in "
                              "all) spent: sample for 0x%04X dropped", budget.max_client_bytes,
                              budget.max_total_bytes, object_id)
            return
        if pushed_out:
            self.stats.samples_overwritten += 1
            self._unqueue(client, queue[0])  # append() below pushes it out
        queue.append(payload)
        client.queued_bytes += size
        budget.queued_total += size
        try:
            self.pump(client, entry)
        except Exception:
            self.stats.handler_errors += 1
            log.debug("delivering to reader 0x%04X failed", object_id, exc_info=True)

    def _unqueue(self, client: ClientProxy, sample: bytes) -> None:
        client.queued_bytes -= len(sample)
        self.budget.queued_total -= len(sample)

    def read_data(self, client: ClientProxy, request: ReadData) -> None:
        entry = client.objects.get(request.object_id)
        if entry is None or entry.reader is None:
            # Failed READ_DATA is answered on the reliable built-in stream whatever it came on.
            self._send_status(client, request, C.STATUS_ERR_UNKNOWN_REFERENCE, C.BUILTIN_RELIABLE)
            return
        reader = entry.reader
        delivery = request.delivery
        now = self.clock()
        reader.active = None  # a new READ_DATA stops the previous one first
        fastpath = client.link.fastpath
        if fastpath is not None:
            fastpath.reader_ready(client, entry)  # C stops sending for the old one
        client.blocked_readers.discard(entry.object_id)
        if delivery is None:
            remaining: Optional[int] = 1
            deadline = None
            rate = 0
        else:
            remaining = None if delivery.max_samples == C.MAX_SAMPLES_UNLIMITED else delivery.max_samples
            deadline = now + delivery.max_elapsed_time if delivery.max_elapsed_time else None
            rate = delivery.max_bytes_per_second
        zero = remaining == 0
        if zero:
            # max_samples 0 (uxr_buffer_cancel_data: stream none, all limits 0) as eProsima's
            # agent reads it: its reader checks, after each read of at most 100 ms, whether the
            # count of samples sent equals max_samples. The first read finding no sample ends it;
            # one that finds a sample sends it and the count never equals 0 again. So a queued
            # sample, or one arriving within 100 ms, answers the request at once (a DATA with its
            # request id, on stream none for a cancel), and reading goes on until the reader is
            # read again or deleted. rmw_microxrcedds waits up to 1 s for that answer before it
            # deletes a reader or replier.
            remaining = None
            if deadline is None or deadline > now + ZERO_SAMPLES_FIRST_READ_S:
                deadline = now + ZERO_SAMPLES_FIRST_READ_S
        reader.active = ReadRequest(request.request_id, request.stream_id, remaining, deadline, rate,
                                    now, deadline_until_first=zero and not delivery.max_elapsed_time)
        if deadline is not None:
            self._wake_at(deadline)
        if self.timelines.pending:
            self.timelines.read_data(client)
        self.pump(client, entry)

    def pump(self, client: ClientProxy, entry: ObjectEntry) -> None:
        """Deliver queued samples while the active READ_DATA allows and the stream has room."""
        reader = entry.reader
        budget = self.budget
        while reader.active is not None and reader.queue:
            active = reader.active
            now = self.clock()
            if active.deadline is not None and now >= active.deadline:
                reader.active = None
                break
            sample = reader.queue[0]
            if active.rate:
                active.tokens = min(float(active.rate),
                                    active.tokens + (now - active.refilled) * active.rate)
                active.refilled = now
                # A sample larger than one second's budget goes out whenever the bucket is full.
                if active.tokens < min(len(sample), active.rate):
                    self._wake_at(now + (min(len(sample), active.rate) - active.tokens) / active.rate)
                    break
                active.tokens -= len(sample)
            message = data_message(client, active.stream_id, active.request_id, entry.object_id,
                                   sample)
            if len(message) > client.mtu:  # the board's stream may not carry it: mismatch_report.py
                if not is_reliable(active.stream_id):
                    self.mismatches.too_large_for_best_effort(client, entry, len(sample), len(message))
                elif entry.info is not None:
                    entry.info["fragmented"] = len(sample)
            if not self._send_on_stream(client, active.stream_id, None, message):
                if active.rate:
                    active.tokens += len(sample)
                client.blocked_readers.add(entry.object_id)  # retried when an ACKNACK frees room
                break
            size = len(reader.queue.popleft())
            client.queued_bytes -= size
            budget.queued_total -= size
            self.stats.samples_out += 1
            entry.samples += 1
            entry.sample_bytes += len(sample)
            if active.deadline_until_first:
                active.deadline_until_first = False
                active.deadline = None
            if active.remaining is not None:
                active.remaining -= 1
                if active.remaining <= 0:
                    reader.active = None
        fastpath = client.link.fastpath
        if fastpath is not None:
            # Nothing queued and a READ_DATA without limits: C may send its samples itself
            fastpath.reader_ready(client, entry)

    def fragment(self, client: ClientProxy, stream_id: int, data: bytes, flags: int, start: int,
                  end: int) -> bool:
        if not is_reliable(stream_id):
            return False  # the agent only reassembles on reliable streams
        if isinstance(data, Reassembled):
            # A FRAGMENT inside a reassembled message: no peer writes that, and following it
            # would recurse once per level (2000 levels in one datagram reached RecursionError).
            self.stats.nested_fragments += 1
            client.warn_quota("nested", self.clock(), "nested FRAGMENT on stream 0x%02X dropped",
                              stream_id)
            return False
        self.stats.fragments_in += 1
        # While the compiled UDP path owns the stream it holds the reassembly (it takes in-order
        # fragments itself): taken for this fragment, and what is left unfinished goes back.
        compiled = client.in_reliable.get(stream_id)
        take_partial = getattr(compiled, "take_partial", None)
        if take_partial is not None:
            partial = take_partial()
            if partial is not None:
                client.reassembly[stream_id] = bytearray(partial)  # already charged
        buffer = client.reassembly.get(stream_id)
        if buffer is None:
            buffer = client.reassembly[stream_id] = bytearray(data[:header_size(data[0])])
            self.budget.charge(client, len(buffer))
        limit = self.max_reassembly_bytes or MAX_REASSEMBLY
        if len(buffer) + (end - start) > limit:
            del client.reassembly[stream_id]
            self.budget.charge(client, -len(buffer))
            self.stats.reassembly_overflows += 1
            client.warn_quota("reassembly", self.clock(), "reassembly on stream 0x%02X exceeds "
                              "the %d-byte quota, message abandoned", stream_id, limit)
            return False
        buffer += data[start:end]
        self.budget.charge(client, end - start)
        if take_partial is not None and not flags & C.FLAG_LAST_FRAGMENT:
            del client.reassembly[stream_id]
            if not compiled.put_partial(buffer):  # no memory there: everything back to Python
                client.reassembly[stream_id] = buffer
                client.fast.drop(client)
            return True
        if flags & C.FLAG_LAST_FRAGMENT:
            del client.reassembly[stream_id]
            self.budget.charge(client, -len(buffer))
            message = Reassembled(buffer)
            del buffer
            self._process_message(client, message, header_size(message[0]), stream_id)
            fastpath = client.link.fastpath
            if fastpath is not None and client.alive:
                self._offer_reassembled(fastpath, client, stream_id, message)
        return True

    @staticmethod
    def _offer_reassembled(fastpath, client: ClientProxy, stream_id: int, message: bytes) -> None:
        """A message put together from FRAGMENTs was one WRITE_DATA of a writer: the next ones
        of its stream may not need Python (xrce.agent.engine.compiled.fastpath reassembles in C)."""
        start = header_size(message[0])
        if len(message) < start + 8 or message[start] != C_WRITE_DATA:
            return
        entry = client.objects.get((message[start + 6] << 8) | message[start + 7])
        if entry is not None and entry.kind == C_DATAWRITER and entry.write is not None:
            fastpath.offer(client, stream_id, entry)


class Reassembled(bytes):
    """A message put together from FRAGMENTs: it may not hold FRAGMENTs itself."""

    __slots__ = ()
