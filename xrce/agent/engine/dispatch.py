"""The agent's protocol engine: the dispatcher that ties sessions, objects, data and liveliness together (XRCE-WIRE.md §1–§10, §12).

Transport servers hand every whole XRCE message to ``Agent.receive(link, endpoint, data)``; replies
leave through ``link.send(endpoint, bytes)``. The engine never blocks and never raises out of
``receive``: a malformed message is counted, logged at debug level with its hex and dropped without
touching any other client. Everything runs on one asyncio loop.

``Agent`` is assembled from one module per protocol seam, each readable alone:

- ``xrce.agent.engine.session``: per-client state (``ClientProxy``), CREATE_CLIENT, GET_INFO, deletion;
- ``xrce.agent.engine.objects``: CREATE/DELETE of XRCE objects and the middleware entities behind them;
- ``xrce.agent.engine.datapath``: the per-sample path, WRITE_DATA/FRAGMENT in, READ_DATA/DATA out;
- ``xrce.agent.engine.liveliness``: ACKNACK/HEARTBEAT and the timed work per client;
- this module: message header, stream admission and submessage dispatch, parking of clients whose
  CREATE waits for a type build, and the agent's lifecycle.

What a client's objects map onto is the middleware's business (``xrce.agent.middleware``); the engine
keeps the XRCE view: ids, parents, REUSE/REPLACE signatures and the READ_DATA state of each reader.

Threads: the engine runs on the asyncio loop's thread, and on the middleware's thread for the
samples it delivers to UDP clients (``DataPath._from_middleware``): whoever runs it holds
``Agent.lock``. Taking that lock costs a fraction of a microsecond per message; waking the loop
for every sample from ROS cost more than the sample itself (bench/agent_cost.py, TurtleBot3 load).
"""

from __future__ import annotations

import asyncio
import gc
import logging
import threading
import time
from collections import deque
from typing import Any, Callable, Deque, Dict, Hashable, Optional, Tuple

from xrce import constants as C, names as wire_names
from xrce.agent.engine.admission import RefusalLog
from xrce.agent.engine.datapath import DataPath
from xrce.agent.engine.liveliness import NEVER, Liveliness
from xrce.agent.middleware import Middleware
from xrce.agent.engine.objects import ObjectRegistry, Parked
from xrce.agent.engine.session import (  # noqa: F401 (re-exported: the CLI documents these defaults)
    CLIENT_DEAD_TIME, CLIENT_EXPIRE_TIME, MAX_CLIENT_BYTES, MAX_CLIENTS, MAX_OBJECTS_PER_CLIENT,
    MAX_OUTPUT_QUEUE_BYTES, MAX_REASSEMBLY, MAX_TOTAL_BYTES, STREAM_WINDOW, TRACE, AgentStats,
    ClientProxy, Link, SessionTable,
)
from xrce.agent.engine.timeline import TIMELINE_CHECK_S, RecoveryTimelines
from xrce.errors import DecodeError
from xrce.message import decode_header, header_size, iter_submessages
from xrce.streams import InputBestEffortStream, InputReliableStream, is_reliable, seq_add, seq_sub
from xrce.submessages import TimestampReply, decode_payload, encode_message, sample_ids, Status

log = logging.getLogger("xrce.agent")

# Messages a parked client may queue while its type builds. Beyond, its reliable streams stop
# advancing (the client retransmits: nothing acknowledged is lost); best-effort ones are dropped.
MAX_PARKED_MESSAGES = 512

_HANDLED = frozenset((C.CREATE, C.DELETE, C.READ_DATA, C.ACKNACK, C.HEARTBEAT, C.GET_INFO,
                      C.TIMESTAMP, C.RESET))


def _return_free_heap() -> None:
    """Give the C heap's free pages back to the system once start-up is over (glibc only).
    Through the compiled helper where it is built: the ctypes package, once imported, stays in
    the process (0.57 MB of classes)."""
    try:
        from xrce.agent.engine._fastpath import return_free_heap
    except ImportError:
        try:
            import ctypes
            ctypes.CDLL(None).malloc_trim(0)
        except (ImportError, OSError, AttributeError):
            pass
    else:
        return_free_heap()


class Agent(SessionTable, ObjectRegistry, DataPath, Liveliness):
    def __init__(self, middleware: Middleware, *, refs: Optional[Dict[str, str]] = None,
                 heartbeat_period: float = 0.2, client_dead_time: float = CLIENT_DEAD_TIME,
                 client_expire_time: float = CLIENT_EXPIRE_TIME,
                 max_objects_per_client: Optional[int] = None,
                 max_reassembly_bytes: Optional[int] = None,
                 max_output_queue_bytes: int = MAX_OUTPUT_QUEUE_BYTES,
                 max_clients: int = MAX_CLIENTS,
                 max_client_bytes: int = MAX_CLIENT_BYTES,
                 max_total_bytes: int = MAX_TOTAL_BYTES,
                 loop: Optional[asyncio.AbstractEventLoop] = None):
        """``client_dead_time`` (s): silence after which a client gets no more HEARTBEATs;
        ``client_expire_time`` (s, counted from its last message, 0 = never): silence after which
        the client and all its entities are deleted. Quotas are per client except ``max_clients``;
        None for the first two means the module defaults, looked up when used."""
        self.middleware = middleware
        self.refs = dict(refs or {})
        self.heartbeat_period = heartbeat_period
        self.client_dead_time = client_dead_time
        self.client_expire_time = client_expire_time
        self.max_objects_per_client = max_objects_per_client
        self.max_reassembly_bytes = max_reassembly_bytes
        self.max_output_queue_bytes = max_output_queue_bytes
        self.max_clients = max_clients
        self.max_client_bytes = max_client_bytes
        self.max_total_bytes = max_total_bytes
        self.buffered_total = 0  # the clients' ClientProxy.buffered, summed
        self.queued_total = 0  # the clients' ClientProxy.queued_bytes, summed
        self.loop = loop
        self.stats = AgentStats()
        self._trim_due = False  # clients holding buffers were deleted (see _tick_locked)
        self._trimmed_at = -NEVER
        self.clock: Callable[[], float] = time.monotonic  # tests may substitute a fake clock
        self.clients: Dict[bytes, ClientProxy] = {}
        self.endpoints: Dict[Tuple[Any, Hashable], bytes] = {}  # (link, endpoint) → key, sessions ≥ 0x81
        # Where such a session's TCP connection or serial port closed: the next CREATE there
        # replaces it (xrce.agent.engine.session). Host → HostRecord: see Liveliness._retirement.
        self._closed_endpoints: Dict[Tuple[Any, Hashable], bytes] = {}
        self.hosts: Dict[Hashable, Any] = {}
        self._started = False
        # Held by whichever thread runs the engine (module docstring); reentrant because an
        # in-process middleware (-m ced) delivers samples while the engine is receiving.
        self.lock = threading.RLock()
        middleware.engine_lock = self.lock
        middleware.on_mismatch = self._middleware_mismatch  # engine/mismatches.py
        self._held_fragments: Dict[tuple, tuple] = {}  # engine/mismatches.py
        self._loop_thread = threading.get_ident()  # the thread the loop runs on, once started
        self._timer: Optional[asyncio.TimerHandle] = None  # the next tick(), see liveliness
        self._timer_due = NEVER
        self._info_cache: Dict[tuple, bytes] = {}  # see SessionTable._info_message
        self._acks_due: Dict[Tuple[bytes, int], Tuple[ClientProxy, InputReliableStream]] = {}
        self._resumable: Deque[ClientProxy] = deque()  # parked clients whose build finished
        # A CREATE was handled in this turn of the loop: the client's next submessage waits for
        # the next turn (see _process_message).
        self._yield_due = False
        # Called as tap(direction, link, endpoint, message) for every message in ("in") and out
        # ("out"), e.g. by a capture file (xrce.agent.observe.capture); None costs one test.
        self.tap: Optional[Callable[[str, Any, Hashable, bytes], None]] = None
        self.admission = None  # who may open a session (xrce.agent.engine.admission); None: anyone
        # Failed CREATEs (a type no package provides, a bad profile): a stranger's flood of them
        # must not fill the operator's log (see ObjectRegistry._create).
        self.create_failures = RefusalLog(log, "failed CREATEs", lambda: self.clock())
        self.timelines = RecoveryTimelines(lambda: self.clock())  # clients that come back
        self.fastpaths: list = []  # compiled UDP receive paths (xrce.agent.engine.fastpath) feeding this agent

    # ------------------------------------------------------------------ public entry points --

    def receive(self, link: Link, endpoint: Hashable, data) -> None:
        """Handle one whole XRCE message from ``endpoint`` on ``link``. Never raises."""
        data = bytes(data)
        stats = self.stats
        with self.lock:
            self._yield_due = False
            stats.messages_in += 1
            stats.bytes_in += len(data)
            if self.admission is not None and not self.admission.admits_datagram(link, endpoint,
                                                                                  data):
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

    def _build_finished(self, client: ClientProxy) -> None:
        """Called from the build's thread: hand the client back to the loop."""
        self._resumable.append(client)
        if self.loop is not None:
            self.loop.call_soon_threadsafe(self._resume_parked)
        # Without a loop (synchronous tests), tick() resumes it.

    def _resume_parked(self) -> None:
        with self.lock:
            self._resume_parked_locked()

    def _resume_parked_locked(self) -> None:
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
                    self._process_message(client, data, start, stream_id)
                except Exception:
                    self.stats.handler_errors += 1
                    log.debug("resumed message of client %s failed", client.key.hex(), exc_info=True)
                if client.parked is not None:  # parked again by another CREATE
                    rest = pending[index + 1:]
                    client.parked.extend(rest)
                    self._charge(client, sum(len(entry[0]) for entry in rest))
                    break

    # ------------------------------------------------------------------ memory budget --

    def _charge(self, client: ClientProxy, delta: int) -> None:
        if client.alive:  # a deleted client gave all its bytes back at once
            client.buffered += delta
            self.buffered_total += delta

    def _over_budget(self, client: ClientProxy, extra: int) -> bool:
        return client.buffered + client.queued_bytes + extra > self.max_client_bytes or \
            self.buffered_total + self.queued_total + extra > self.max_total_bytes

    def tick(self) -> None:
        """The timed work that is due: HEARTBEATs, liveliness probes, paced delivery. Sets the
        loop timer for the next (``run()`` calls it from there; tests call it directly)."""
        with self.lock:
            # The compiled path's thread hands everything over while liveliness and parking
            # are judged: it takes no datagram of a client found dead until sync() has told it.
            for fastpath in self.fastpaths:
                fastpath.pause()
            try:
                self._tick_locked()
            finally:
                for fastpath in self.fastpaths:
                    fastpath.resume()

    def fold_compiled(self) -> None:
        """Bring the counters of the compiled receive paths' threads into the engine's (before
        statistics are read: those threads never wake Python to count)."""
        with self.lock:
            for fastpath in self.fastpaths:
                if fastpath.clients:
                    fastpath.fold()

    def _tick_locked(self) -> None:
        self._resume_parked_locked()
        for fastpath in self.fastpaths:
            if fastpath.clients:  # the compiled path's last_seen, before liveliness judges it
                fastpath.fold()
        now = self.clock()
        due = NEVER
        if self.timelines.pending:
            self.timelines.tick(now)
            if self.timelines.pending:  # reported by a later tick at the latest
                due = now + TIMELINE_CHECK_S
        for client in list(self.clients.values()):
            try:
                client_due = self._tick_client(client, now)
            except Exception:
                self.stats.handler_errors += 1
                log.debug("periodic work for client %s failed", client.key.hex(), exc_info=True)
                client_due = now + self.heartbeat_period
            if client_due < due:
                due = client_due
        if self._trim_due and now - self._trimmed_at >= 1.0:
            # Clients holding buffers were deleted: without this the heap kept their pages
            # (a 60 s flood's expired sessions left RSS at 62 MB, 19 MB before it).
            self._trim_due = False
            self._trimmed_at = now
            _return_free_heap()
        elif self._trim_due and due > now + 1.0:
            due = now + 1.0
        if due < NEVER:
            self._wake_at(due)
        for fastpath in self.fastpaths:
            # Clients found dead just now must come back through Python.
            fastpath.sync()

    @property
    def next_wakeup(self) -> Optional[float]:
        """When (agent clock) the timed work next runs; None when nothing is scheduled."""
        return None if self._timer is None else self._timer_due

    async def start(self) -> None:
        """Start the middleware (it joins no ROS domain until a client's participant asks for
        one). Idempotent; ``run`` calls it too, the CLI awaits it before opening any link so that
        no client is answered meanwhile."""
        if self.loop is None:
            self.loop = asyncio.get_running_loop()
        self._loop_thread = threading.get_ident()
        if not self._started:
            self._started = True
            await self.middleware.start()
            # Everything built so far (rclpy and the modules the agent imported) lives as long as
            # the agent: out of the collector's sight, full collections stay short (ping p99).
            gc.freeze()
            _return_free_heap()

    async def run(self) -> None:
        """Start the middleware, then serve until cancelled. No polling: the loop wakes the agent
        for traffic and for the timer of the next due work (see ``xrce.agent.engine.liveliness``)."""
        await self.start()
        self.tick()
        try:
            await self.loop.create_future()
        finally:
            self._cancel_timer()

    async def close(self) -> None:
        self._cancel_timer()
        with self.lock:
            for client in list(self.clients.values()):
                self._delete_client(client)
            # The counts of refusals not logged since their last line
            self.create_failures.flush()
            if self.admission is not None:
                self.admission.flush()
        self._cancel_timer()  # deleting clients may have scheduled replies' HEARTBEATs
        await self.middleware.close()

    # ------------------------------------------------------------------ input dispatch --

    def _receive(self, link: Link, endpoint: Hashable, data: bytes) -> None:
        header = decode_header(data)
        if log.isEnabledFor(TRACE):
            self._trace("in", link, endpoint, data, header.size)
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
        client.last_seen = self.clock()
        client.probes = 0
        if client.dead:
            client.dead = False
            self.stats.clients_revived += 1
            log.info("client %s is alive again", client.key.hex())
            self._wake_at(client.last_seen + self._quiet_limit(client))
        client.messages_in += 1
        client.bytes_in += len(data)
        stream_id = header.stream_id
        if stream_id == C.STREAM_NONE:
            self._process_message(client, data, header.size, stream_id)
        elif is_reliable(stream_id):
            self._receive_reliable(client, stream_id, header.seq, data)
        else:
            stream = client.in_best_effort.get(stream_id)
            if stream is None:
                stream = client.in_best_effort[stream_id] = InputBestEffortStream(stream_id)
            if stream.accept(header.seq):
                self._process_message(client, data, header.size, stream_id)
            else:
                self.stats.dropped += 1

    def _receive_reliable(self, client: ClientProxy, stream_id: int, seq: int, data: bytes) -> None:
        stream = client.in_reliable.get(stream_id)
        if stream is None:
            stream = client.in_reliable[stream_id] = InputReliableStream(stream_id, STREAM_WINDOW)
        if self._hold_back(client, stream, seq, data):
            # Not accepted, so not acknowledged: the client sends it again after its next
            # HEARTBEAT, and nothing the agent acknowledged is ever dropped. No ACKNACK now: one
            # per refused message would make the client resend its window at once, in a loop.
            self.stats.budget_refused += 1
            return
        duplicates = stream.duplicates
        stored = stream.stored_bytes
        try:
            for message in stream.receive(seq, data):
                self._process_reliable_message(client, stream_id, message)
        finally:
            self._charge(client, stream.stored_bytes - stored)
            self.stats.duplicates += stream.duplicates - duplicates
            client.duplicates += stream.duplicates - duplicates
            if client.alive:  # every reliable message is acknowledged, duplicates included
                # (a reassembled sample may have handed the stream to the compiled path)
                self._acknack_soon(client, client.in_reliable.get(stream_id, stream))

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
        return self._over_budget(client, len(data))

    def _acknack_soon(self, client: ClientProxy, stream: InputReliableStream) -> None:
        """ACKNACK once per stream for all the messages of one read batch: the ACKNACK is
        cumulative, so one sent after the batch says what one per message would have said last.
        Without a loop (synchronous use, tests, golden replays) it goes out at once."""
        if self.loop is None:
            self._send_acknack(client, stream)
            return
        if not self._acks_due:
            self.loop.call_soon(self._send_due_acknacks)
        self._acks_due[(client.key, stream.stream_id)] = (client, stream)

    def _send_due_acknacks(self) -> None:
        with self.lock:
            due, self._acks_due = self._acks_due, {}
            for client, stream in due.values():
                if client.alive and self.clients.get(client.key) is client and \
                        client.in_reliable.get(stream.stream_id) is stream:
                    try:
                        self._send_acknack(client, stream)
                    except Exception:
                        self.stats.handler_errors += 1
                        log.debug("ACKNACK to client %s failed", client.key.hex(), exc_info=True)

    def _process_reliable_message(self, client: ClientProxy, stream_id: int, message: bytes) -> None:
        """One message of a batch the stream handed out: whatever goes wrong with it, the ones
        behind it (already taken from the stream and acknowledged) are still processed."""
        size = header_size(message[0])
        try:
            self._process_message(client, message, size, stream_id)
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
                self._create_client(link, endpoint, header, payload)
            elif sub_id == C.GET_INFO:
                key = self.endpoints.get((link, endpoint))
                established = key is not None and key in self.clients and \
                    self.clients[key].session_id > C.SESSION_ID_WITHOUT_KEY_MASK
                self._reply_info(link, endpoint, header, payload, 1 if established else 0)
            else:
                self.stats.dropped += 1
            return  # only the first submessage of a session-less message counts

    def _receive_unknown_client(self, link: Link, endpoint: Hashable, data: bytes, header) -> None:
        """A message for a session the agent does not know: only its first submessage counts
        (as eProsima), and only two kinds get an answer, one at most per datagram: UDP sources
        are spoofable, and answering each of a datagram's submessages made the agent a
        reflector (5000 replies, 2-4x the bytes, for one 60 KB datagram)."""
        self.timelines.unknown_traffic(link, endpoint, header)
        for sub_id, flags, start, end in iter_submessages(data, header.size):
            if sub_id == C.DELETE:
                payload = decode_payload(sub_id, flags, data, start, end)
                if payload.object_id == C.OBJECTID_CLIENT:
                    self._send_raw(link, endpoint, encode_message(
                        header.session_id, header.stream_id, header.seq, header.key,
                        [Status(payload.request_id, payload.object_id)]))
                    return
            elif sub_id == C.GET_INFO:
                payload = decode_payload(sub_id, flags, data, start, end)
                self._reply_info(link, endpoint, header, payload, 0)
                return
            break
        self.stats.dropped += 1

    def _process_message(self, client: ClientProxy, data: bytes, start: int, stream_id: int) -> None:
        """Submessages in order; the first failing one stops the rest of the message."""
        if client.parked is not None and stream_id != C.STREAM_NONE:
            if not is_reliable(stream_id) and (len(client.parked) >= MAX_PARKED_MESSAGES or
                                               self._over_budget(client, len(data))):
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
                    self.loop.call_soon(self._resume_parked)
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
                if sub_id == C.CREATE and self.loop is not None and \
                        threading.get_ident() == self._loop_thread:
                    self._yield_due = True
        except DecodeError as exc:
            self.stats.decode_errors += 1
            client.decode_errors += 1
            log.debug("client %s: malformed submessage (%s) in %s", client.key.hex(), exc, data.hex())

    def _park(self, client: ClientProxy, data: bytes, start: int, stream_id: int) -> None:
        if client.parked is None:
            client.parked = []
        client.parked.insert(0, (data, start, stream_id))  # before anything queued meanwhile
        self._charge(client, len(data))

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
            return self._fragment(client, stream_id, data, flags, start, end)
        if sub_id not in _HANDLED:
            return False  # CREATE_CLIENT in session, STATUS, INFO, DATA, … stop the message
        payload = decode_payload(sub_id, flags, data, start, end)
        if sub_id == C.CREATE or sub_id == C.DELETE:
            queued = client.queued_bytes  # a REPLACE or DELETE of a reader drops its queue
            if sub_id == C.CREATE:
                self._create(client, payload, stream_id)
            else:
                self._delete(client, payload, stream_id)
            self.queued_total -= queued - client.queued_bytes
        elif sub_id == C.READ_DATA:
            self._read_data(client, payload)
        elif sub_id == C.ACKNACK:
            self._on_acknack(client, payload)
        elif sub_id == C.HEARTBEAT:
            self._on_heartbeat(client, payload)
        elif sub_id == C.GET_INFO:
            self._send_client(client, self._info_message(None, client.session_id, C.STREAM_NONE, 0,
                                                         client.header_key, payload, 1))
        elif sub_id == C.TIMESTAMP:
            receive_ns = time.time_ns()
            client.timestamp_skew_ns = receive_ns - payload.ns()
            self._send_stream0(client, TimestampReply(time.time_ns(), receive_ns, payload.ns()))
        elif sub_id == C.RESET:
            self._reset_streams(client)
        return True

    # ------------------------------------------------------------------ logging --

    def _trace(self, direction: str, link: Link, endpoint: Hashable, data: bytes, start: int) -> None:
        try:
            names = [wire_names.SUBMESSAGE_NAMES.get(sub_id, str(sub_id))
                     for sub_id, _, _, _ in iter_submessages(data, start)]
        except DecodeError:
            names = ["<malformed>"]
        log.log(TRACE, "%s %s %r session 0x%02X stream 0x%02X seq %d: %s | %s", direction, link.name,
                endpoint, data[0], data[1], data[2] | (data[3] << 8), " ".join(names), data.hex())



def _is_fragment(message: bytes) -> bool:
    head = header_size(message[0])
    return len(message) > head and message[head] == C.FRAGMENT


__all__ = ["Agent", "AgentStats", "ClientProxy", "Link", "TRACE"]
