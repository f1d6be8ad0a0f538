"""The agent's protocol engine: the dispatcher that ties sessions, objects, data and liveliness together (XRCE-WIRE.md §1–§10, §12).

Transport servers hand every whole XRCE message to ``Agent.receive(link, endpoint, data)``; replies
leave through ``link.send(endpoint, bytes)``. The engine never blocks and never raises out of
``receive``: a malformed message is counted, logged at debug level with its hex and dropped without
touching any other client. Everything runs on one asyncio loop.

``Agent`` is composed of parts, one per protocol seam, each an object with its own state that gets
its collaborators in its constructor (as eProsima's agent has Root, ProxyClient, Session and
Processor); each module is readable alone:

- ``xrce.agent.engine.client``: ``ClientProxy`` (one client: its objects, streams, quotas and
  counters); ``xrce.agent.engine.clients``: ``ClientTable`` (the clients by key, endpoint and
  host) and ``MemoryBudget`` (the bytes their buffers hold); ``xrce.agent.engine.sessions``:
  ``Sessions`` (CREATE_CLIENT, GET_INFO, dead time, retirement, deletion); ``limits``, ``link``
  and ``stats``: the quotas' defaults, the ``Link`` a transport server is, ``AgentStats``;
- ``xrce.agent.engine.objects``: ``ObjectRegistry``, CREATE/DELETE of XRCE objects and the
  middleware entities behind them;
- ``xrce.agent.engine.datapath``: ``DataPath``, the per-sample path, WRITE_DATA/FRAGMENT in,
  READ_DATA/DATA out, and output on a client's streams;
- ``xrce.agent.engine.liveliness``: ``Acknowledgments`` (ACKNACK for input) and ``Liveliness``
  (retransmission on ACKNACK, HEARTBEATs, the timed work per client);
- ``xrce.agent.engine.mismatch_report``: ``MismatchReport``, board endpoints that cannot reach their
  peers, named once;
- ``xrce.agent.engine.scheduler`` (``Scheduler``: the loop, its thread, the one timer of the
  timed work) and ``xrce.agent.engine.output`` (``Output``: whole messages out, counted, traced
  and tapped);
- this module: ``Agent`` builds and wires those parts and keeps the message header, stream
  admission and submessage dispatch, parking of clients whose CREATE waits for a type build,
  and the agent's lifecycle.

What a client's objects map onto is the middleware's business (``xrce.agent.middleware``); the engine
keeps the XRCE view: ids, parents, REUSE/REPLACE signatures and the READ_DATA state of each reader.

Threads: the engine runs on the asyncio loop's thread, and on the middleware's thread for the
samples it delivers to UDP clients (``DataPath.from_middleware``): whoever runs it holds
``Agent.lock``. Taking that lock costs a fraction of a microsecond per message; waking the loop
for every sample from ROS cost more than the sample itself (bench/agent/cost.py, TurtleBot3 load).
"""

from __future__ import annotations

import asyncio
import gc
import logging
import threading
import time
from collections import deque
from typing import Any, Callable, Deque, Dict, Hashable, Optional

from xrce.wire import constants as C
from xrce.agent.engine.admission import RefusalLog
from xrce.agent.engine.datapath import DataPath
from xrce.agent.engine.liveliness import Acknowledgments, Liveliness
from xrce.agent.engine.client import ClientProxy, ResumingStream
from xrce.agent.engine.clients import ClientTable, MemoryBudget
from xrce.agent.engine.limits import (
    CLIENT_DEAD_TIME, CLIENT_EXPIRE_TIME, MAX_CLIENT_BYTES, MAX_CLIENTS, MAX_OUTPUT_QUEUE_BYTES,
    MAX_REASSEMBLY, MAX_TOTAL_BYTES, STREAM_WINDOW, DataLimits,
)
from xrce.agent.engine.link import Link
from xrce.agent.engine.mismatch_report import MismatchReport
from xrce.agent.engine.objects import ObjectRegistry, Parked
from xrce.agent.engine.output import Output, trace
from xrce.agent.engine.scheduler import NEVER, Scheduler
from xrce.agent.engine.sessions import Sessions
from xrce.agent.engine.stats import AgentStats
from xrce.agent.engine.stream_output import StreamOutput
from xrce.agent.log_levels import TRACE
from xrce.agent.engine.timeline import TIMELINE_CHECK_S, RecoveryTimelines, Timeline
from xrce.agent.heap import return_free_heap
from xrce.agent.middleware import Middleware
from xrce import DecodeError
from xrce.wire.message import decode_header, header_size, iter_submessages
from xrce.wire.streams import InputBestEffortStream, InputReliableStream, is_reliable, seq_sub
from xrce.wire.submessages import (
    Heartbeat, TimestampReply, decode_payload, encode_message, sample_ids, Status,
)

log = logging.getLogger("xrce.agent")

# Messages a parked client may queue while its type builds. Beyond, its reliable streams stop
# advancing (the client retransmits: nothing acknowledged is lost); best-effort ones are dropped.
MAX_PARKED_MESSAGES = 512

# Traffic of sessions the agent does not know: one line per source per this many seconds, and
# at most UNKNOWN_LOG_BURST lines per UNKNOWN_LOG_PERIOD_S in all (a spoofed flood's sources).
UNKNOWN_SOURCE_LOG_S = 60.0
UNKNOWN_LOG_BURST = 5
UNKNOWN_LOG_PERIOD_S = 10.0
MAX_UNKNOWN_SOURCES = 1024

_HANDLED = frozenset((C.CREATE, C.DELETE, C.READ_DATA, C.ACKNACK, C.HEARTBEAT, C.GET_INFO,
                      C.TIMESTAMP, C.RESET))


class Agent:
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
        self.stats = stats = AgentStats()
        # The agent's clock, handed to every part that reads it (tests substitute a fake one:
        # see the ``clock`` property).
        self._clock: Callable[[], float] = time.monotonic
        clock = self._clock
        self._trimmed_at = -NEVER
        self._started = False
        # Held by whichever thread runs the engine (module docstring); reentrant because an
        # in-process middleware (-m ced) delivers samples while the engine is receiving.
        self.lock = lock = threading.RLock()
        self.fastpaths: list = []  # compiled UDP receive paths (xrce.agent.engine.compiled.fastpath) feeding this agent
        # Failed CREATEs (a type no package provides, a bad profile): a stranger's flood of them
        # must not fill the operator's log (see ObjectRegistry.create).
        self.create_failures = RefusalLog(log, "failed CREATEs", lambda: self._clock())
        self.timelines = RecoveryTimelines(lambda: self._clock())  # clients that come back

        # The parts, each given its collaborators (module docstring).
        self.table = table = ClientTable()
        self.scheduler = scheduler = Scheduler(clock, heartbeat_period, self._on_timer, loop)
        self.budget = budget = MemoryBudget(max_client_bytes, max_total_bytes)
        self.output = output = Output(stats)
        self.mismatches = mismatches = MismatchReport(table.clients, scheduler, stats, clock,
                                                      heartbeat_period)
        self.acks = acks = Acknowledgments(table.clients, output, budget, scheduler, lock, stats,
                                           self._process_reliable_message)
        self.stream_output = stream_output = StreamOutput(output, budget, scheduler,
                                                          self.timelines, stats)
        self.datapath = datapath = DataPath(
            table, middleware, stream_output, budget, scheduler, acks, mismatches, self.timelines,
            self.fastpaths, lock, stats, clock, self._process_message,
            DataLimits(max_reassembly_bytes, max_output_queue_bytes))
        self.objects = objects = ObjectRegistry(
            middleware, datapath, stream_output, self.fastpaths, self.create_failures, stats,
            clock, refs=dict(refs or {}), max_objects_per_client=max_objects_per_client)
        self.sessions = sessions = Sessions(
            table, objects, output, budget, scheduler, self.timelines, stats, clock,
            max_clients=max_clients, client_dead_time=client_dead_time,
            client_expire_time=client_expire_time, heartbeat_period=heartbeat_period)
        self.liveliness = Liveliness(sessions, datapath, stream_output, output, budget, mismatches,
                                     stats, clock, heartbeat_period=heartbeat_period,
                                     client_expire_time=client_expire_time)
        self._clocked = (scheduler, mismatches, datapath, objects, sessions, self.liveliness)
        middleware.engine_lock = lock
        middleware.on_mismatch = mismatches.middleware_mismatch

        # What the dispatcher uses per message, bound once.
        self.clients = table.clients  # key → ClientProxy (the links, the CLI, the stats read it)
        self.endpoints = table.endpoints
        self._fast_write = datapath.fast_write
        self._write_data = datapath.write_data
        self._charge = budget.charge
        self._tap = None  # Output.tap, mirrored: see ``tap``
        self._admission = None  # Sessions.admission, mirrored: see ``admission``
        self._state = None  # Sessions.state, mirrored: see ``state``
        self.unknown_log = RefusalLog(log, "lines about unknown sessions", lambda: self._clock(),
                                      burst=UNKNOWN_LOG_BURST, period=UNKNOWN_LOG_PERIOD_S)
        self._unknown_logged: Dict[Any, float] = {}  # source -> when its line was logged
        self._resumable: Deque[ClientProxy] = deque()  # parked clients whose build finished
        # A CREATE was handled in this turn of the loop: the client's next submessage waits for
        # the next turn (see _process_message).
        self._yield_due = False

    # ------------------------------------------------------------------ configuration --

    @property
    def clock(self) -> Callable[[], float]:
        return self._clock

    @clock.setter
    def clock(self, clock: Callable[[], float]) -> None:
        """Every part reads the same clock (tests move a fake one by hand)."""
        self._clock = clock
        for part in self._clocked:
            part.clock = clock
        for fastpath in self.fastpaths:
            fastpath.clock = clock

    def attach_compiled_path(self, link, sock):
        """The compiled receive path for the UDP ``link`` over ``sock`` (its own thread reads it),
        given the parts of this engine it works with; None where the extension, the environment
        or the middleware allow none (the link's loop reads the socket then)."""
        from xrce.agent.engine.compiled import fastpath  # after the middleware started: it looks for rcl

        datapath = self.datapath
        return fastpath.attach(link, sock, fastpath.EngineParts(
            support=self.middleware.compiled_path_support(), fastpaths=self.fastpaths,
            output=self.output, timelines=self.timelines, datapath=datapath, acks=self.acks,
            scheduler=self.scheduler, budget=self.budget, stats=self.stats, lock=self.lock,
            clock=self._clock, reassembly_limit=datapath.max_reassembly_bytes or MAX_REASSEMBLY))

    @property
    def tap(self) -> Optional[Callable[[str, Any, Hashable, bytes], None]]:
        """Called as tap(direction, link, endpoint, message) for every message in ("in") and out
        ("out"), e.g. by a capture file (xrce.agent.observe.capture); None costs one test."""
        return self._tap

    @tap.setter
    def tap(self, tap) -> None:
        self._tap = self.output.tap = tap

    @property
    def admission(self):
        """Who may open a session (xrce.agent.engine.admission); None: anyone."""
        return self._admission

    @admission.setter
    def admission(self, admission) -> None:
        self._admission = self.sessions.admission = admission

    @property
    def state(self):
        """The state store's recorder (xrce.agent.state.recorder), told of every control-plane
        change; None: nothing outlives the process."""
        return self._state

    @state.setter
    def state(self, state) -> None:
        self._state = self.sessions.state = state

    @property
    def refs(self) -> Dict[str, str]:
        return self.objects.refs

    @refs.setter
    def refs(self, refs: Dict[str, str]) -> None:
        self.objects.refs = refs

    @property
    def max_reassembly_bytes(self) -> Optional[int]:
        return self.datapath.max_reassembly_bytes

    @max_reassembly_bytes.setter
    def max_reassembly_bytes(self, limit: Optional[int]) -> None:
        self.datapath.max_reassembly_bytes = limit

    loop = property(lambda self: self.scheduler.loop)
    heartbeat_period = property(lambda self: self.scheduler.heartbeat_period)
    client_dead_time = property(lambda self: self.sessions.client_dead_time)
    client_expire_time = property(lambda self: self.sessions.client_expire_time)
    max_clients = property(lambda self: self.sessions.max_clients)
    max_objects_per_client = property(lambda self: self.objects.max_objects_per_client)
    max_output_queue_bytes = property(lambda self: self.datapath.max_output_queue_bytes)
    max_client_bytes = property(lambda self: self.budget.max_client_bytes)
    max_total_bytes = property(lambda self: self.budget.max_total_bytes)
    buffered_total = property(lambda self: self.budget.buffered_total)
    queued_total = property(lambda self: self.budget.queued_total)

    # ------------------------------------------------------------------ public entry points --

    def receive(self, link: Link, endpoint: Hashable, data) -> None:
        """Handle one whole XRCE message from ``endpoint`` on ``link``. Never raises."""
        data = bytes(data)
        stats = self.stats
        with self.lock:
            self._yield_due = False
            stats.messages_in += 1
            stats.bytes_in += len(data)
            admission = self._admission
            if admission is not None and not admission.admits_datagram(link, endpoint, data):
                stats.sources_refused += 1  # outside --allow-from: no session is looked up
                stats.dropped += 1
                return
            if self._tap is not None:
                self._tap("in", link, endpoint, data)
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
        loop = self.scheduler.loop
        if loop is not None:
            loop.call_soon_threadsafe(self._resume_parked)
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

    # ------------------------------------------------------------------ timed work --

    def _on_timer(self) -> None:
        self.tick()  # looked up now: a test may wrap the agent's tick

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
        now = self._clock()
        due = NEVER
        if self.timelines.pending:
            self.timelines.tick(now)
            if self.timelines.pending:  # reported by a later tick at the latest
                due = now + TIMELINE_CHECK_S
        for client in list(self.clients.values()):
            try:
                client_due = self.liveliness.tick_client(client, now)
            except Exception:
                self.stats.handler_errors += 1
                log.debug("periodic work for client %s failed", client.key.hex(), exc_info=True)
                client_due = now + self.scheduler.heartbeat_period
            if client_due < due:
                due = client_due
        budget = self.budget
        if budget.trim_due and now - self._trimmed_at >= 1.0:
            # Clients holding buffers were deleted: without this the heap kept their pages
            # (a 60 s flood's expired sessions left RSS at 62 MB, 19 MB before it).
            budget.trim_due = False
            self._trimmed_at = now
            return_free_heap()
        elif budget.trim_due and due > now + 1.0:
            due = now + 1.0
        if due < NEVER:
            self.scheduler.wake_at(due)
        for fastpath in self.fastpaths:
            # Clients found dead just now must come back through Python.
            fastpath.sync()

    @property
    def next_wakeup(self) -> Optional[float]:
        """When (agent clock) the timed work next runs; None when nothing is scheduled."""
        return self.scheduler.next_wakeup

    async def start(self) -> None:
        """Start the middleware (it joins no ROS domain until a client's participant asks for
        one). Idempotent; ``run`` calls it too, the CLI awaits it before opening any link so that
        no client is answered meanwhile."""
        self.scheduler.bind(asyncio.get_running_loop())
        if not self._started:
            self._started = True
            await self.middleware.start()
            # Everything built so far (rclpy and the modules the agent imported) lives as long as
            # the agent: out of the collector's sight, full collections stay short (ping p99).
            gc.freeze()
            return_free_heap()

    async def run(self) -> None:
        """Start the middleware, then serve until cancelled. No polling: the loop wakes the agent
        for traffic and for the timer of the next due work (see ``xrce.agent.engine.liveliness``)."""
        await self.start()
        self.tick()
        try:
            await self.scheduler.loop.create_future()
        finally:
            self.scheduler.cancel()

    def endpoint_closed(self, link: Link, endpoint: Hashable) -> None:
        """A TCP connection or serial port went away (the links call it): see
        ``Sessions.endpoint_closed``."""
        self.sessions.endpoint_closed(link, endpoint)

    async def close(self) -> None:
        self.scheduler.cancel()
        with self.lock:
            # The store first, and let go of: closing deletes every client here, which must
            # not delete them from the store (a restarted agent restores them).
            state, self.state = self._state, None
            if state is not None:
                # No more input for good: what the store records as handled on the boards'
                # streams is then at least what any board was acknowledged (xrce.agent.engine.resync).
                for fastpath in self.fastpaths:
                    fastpath.pause()
                state.close()
            for client in list(self.clients.values()):
                self.sessions.delete_client(client)
            # The counts of refusals not logged since their last line
            self.create_failures.flush()
            if self.admission is not None:
                self.admission.flush()
        self.scheduler.cancel()  # deleting clients may have scheduled replies' HEARTBEATs
        await self.middleware.close()

    # ------------------------------------------------------------------ input dispatch --

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
        client.last_seen = self._clock()
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
            self._process_message(client, data, header.size, stream_id)
        elif is_reliable(stream_id):
            self._receive_reliable(client, stream_id, header.seq, data)
        else:
            stream = client.in_best_effort.get(stream_id)
            if stream is None:
                stream = client.in_best_effort[stream_id] = InputBestEffortStream(stream_id)
                if client.resume_inputs:  # restored: the board's numbers go on from where they are
                    stream.last_handled = (header.seq - 1) & 0xFFFF
            if stream.accept(header.seq):
                self._process_message(client, data, header.size, stream_id)
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
                self._process_reliable_message(client, stream_id, message)
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
        self.timelines.unknown_traffic(link, endpoint, header)
        self._log_unknown_session(link, endpoint, header)
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

    def _process_message(self, client: ClientProxy, data: bytes, start: int, stream_id: int) -> None:
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
                    self.scheduler.loop.call_soon(self._resume_parked)
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
            if self._state is not None and client.alive:
                self._state.objects_changed(client, sub_id, flags, data, start, end, payload)
        elif sub_id == C.READ_DATA:
            self.datapath.read_data(client, payload)
            if self._state is not None:
                self._state.read_data(client, flags, data, start, end, payload)
        elif sub_id == C.ACKNACK:
            if client.resuming:
                self._resume_output(client, payload)
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

    # ------------------------------------------------------------------ restored sessions --

    def _restored_spoke(self, client: ClientProxy, link: Link, endpoint: Hashable) -> None:
        """The first message of a client restored from the state store: its session carries
        on. A session with its key in its headers may speak from another port now."""
        client.spoken = True
        if client.header_key is not None and (link, endpoint) != (client.link, client.endpoint):
            client.link, client.endpoint = link, endpoint
            if self._state is not None:
                self._state.client_moved(client)
        now = self._clock()
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

    def _resume_output(self, client: ClientProxy, acknack) -> None:
        """The board's ACKNACK says where a restored reliable output stream goes on
        (``ResumingStream``): a plain stream takes its place there; once none is left, the
        client is like any other (the compiled path may take it)."""
        stream = client.out_reliable.get(acknack.stream_id)
        if stream.__class__ is ResumingStream:
            client.out_reliable[acknack.stream_id] = ResumingStream.resumed_at(
                acknack.stream_id, STREAM_WINDOW, acknack.first_unacked)
            log.debug("client %s: output stream 0x%02X resumes at %d", client.key.hex(),
                      acknack.stream_id, acknack.first_unacked)
        client.resuming = any(s.__class__ is ResumingStream for s in client.out_reliable.values())

    def _log_unknown_session(self, link: Link, endpoint: Hashable, header) -> None:
        """One line per source and minute: a board that kept its session while this agent
        restarted without its state goes quiet otherwise, with nothing in the log saying why."""
        keyed = header.session_id < C.SESSION_ID_WITHOUT_KEY_MASK
        source = (header.key if keyed else None, link, endpoint)
        now = self._clock()
        last = self._unknown_logged.get(source)
        if last is not None and now - last < UNKNOWN_SOURCE_LOG_S:
            return
        if len(self._unknown_logged) >= MAX_UNKNOWN_SOURCES:
            self._unknown_logged.clear()
        self._unknown_logged[source] = now
        from xrce.agent.observe.names import endpoint_text

        who = "client key %s" % bytes(header.key).hex() if keyed else \
            "no client key in its headers (session 0x%02X)" % header.session_id
        self.unknown_log.warning(
            "traffic for session 0x%02X from %s %s (%s) that this agent does not know: the "
            "board kept its session while the agent restarted without its state. Reset the "
            "board, or run the agent with its state store (on unless --no-state; --state FILE) "
            "so that a restarted agent resumes the session", header.session_id, link.name,
            endpoint_text(getattr(endpoint, "peer", endpoint)), who)

    def _delete_session(self, client: ClientProxy, request) -> None:
        """DELETE of the client itself: the session and everything it created go; the STATUS
        goes out on stream none (the client's streams are gone with it)."""
        self.sessions.delete_client(client)
        self.output.send_raw(client.link, client.endpoint, encode_message(
            client.session_id, C.STREAM_NONE, 0, client.header_key,
            [Status(request.request_id, request.object_id)]))


def _is_fragment(message: bytes) -> bool:
    head = header_size(message[0])
    return len(message) > head and message[head] == C.FRAGMENT


__all__ = ["Agent", "AgentStats", "ClientProxy", "Link", "TRACE"]
