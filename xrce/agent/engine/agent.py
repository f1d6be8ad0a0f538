"""The agent's protocol engine: ``Agent``, which ties sessions, objects, data and liveliness together (XRCE-WIRE.md §1–§10, §12).

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
  ``Sessions`` (CREATE_CLIENT, GET_INFO, dead time, retirement, deletion, traffic for sessions
  it does not know); ``limits``, ``link`` and ``stats``: the quotas' defaults, the ``Link`` a
  transport server is, ``AgentStats``;
- ``xrce.agent.engine.inbound``: ``Inbound``, every message in: the message header, stream
  admission and submessage dispatch, and the parking of clients whose CREATE waits for a type
  build;
- ``xrce.agent.engine.objects``: ``ObjectRegistry``, CREATE/DELETE of XRCE objects and the
  middleware entities behind them;
- ``xrce.agent.engine.datapath``: ``DataPath``, the per-sample path, WRITE_DATA/FRAGMENT in,
  READ_DATA/DATA out; ``xrce.agent.engine.stream_output``: ``StreamOutput``, output on a
  client's streams (numbering, the reliable window, FRAGMENTs out);
- ``xrce.agent.engine.liveliness``: ``Acknowledgments`` (ACKNACK for input) and ``Liveliness``
  (retransmission on ACKNACK, HEARTBEATs, the timed work per client);
- ``xrce.agent.engine.mismatch_report``: ``MismatchReport``, board endpoints that cannot reach their
  peers, named once;
- ``xrce.agent.engine.scheduler`` (``Scheduler``: the loop, its thread, the one timer of the
  timed work) and ``xrce.agent.engine.output`` (``Output``: whole messages out, counted, traced
  and tapped);
- this module: ``Agent`` builds and wires those parts and keeps the agent's lifecycle (start,
  run, the timed work, close).

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
from typing import Any, Callable, Dict, Hashable, Optional

from xrce.agent.engine.admission import RefusalLog
from xrce.agent.engine.datapath import DataPath
from xrce.agent.engine.inbound import Inbound
from xrce.agent.engine.liveliness import Acknowledgments, Liveliness
from xrce.agent.engine.clients import ClientTable, MemoryBudget
from xrce.agent.engine.limits import (
    CLIENT_DEAD_TIME, CLIENT_EXPIRE_TIME, MAX_CLIENT_BYTES, MAX_CLIENTS, MAX_OUTPUT_QUEUE_BYTES,
    MAX_REASSEMBLY, MAX_TOTAL_BYTES, DataLimits,
)
from xrce.agent.engine.link import Link
from xrce.agent.engine.mismatch_report import MismatchReport
from xrce.agent.engine.objects import ObjectRegistry
from xrce.agent.engine.output import Output
from xrce.agent.engine.scheduler import NEVER, Scheduler
from xrce.agent.engine.sessions import Sessions
from xrce.agent.engine.stats import AgentStats
from xrce.agent.engine.stream_output import StreamOutput
from xrce.agent.engine.timeline import TIMELINE_CHECK_S, RecoveryTimelines
from xrce.agent.heap import return_free_heap
from xrce.agent.middleware import Middleware

log = logging.getLogger("xrce.agent")


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
        # Built before the parts that hand it messages back (a message put together from
        # FRAGMENTs, the ones a HEARTBEAT lets out), given them by connect().
        self.inbound = inbound = Inbound(table, output, budget, scheduler, self.timelines, stats,
                                         lock, clock)
        self.acks = acks = Acknowledgments(table.clients, output, budget, scheduler, lock, stats,
                                           inbound.process_reliable_message)
        self.stream_output = stream_output = StreamOutput(output, budget, scheduler,
                                                          self.timelines, stats)
        self.datapath = datapath = DataPath(
            table, middleware, stream_output, budget, scheduler, acks, mismatches, self.timelines,
            self.fastpaths, lock, stats, clock, inbound.process_message,
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
        inbound.connect(datapath, acks, objects, sessions, self.liveliness)
        self._clocked = (scheduler, mismatches, inbound, datapath, objects, sessions,
                         self.liveliness)
        middleware.engine_lock = lock
        middleware.on_mismatch = mismatches.middleware_mismatch

        self.clients = table.clients  # key → ClientProxy (the links, the CLI, the stats read it)
        self.endpoints = table.endpoints
        self._receive = inbound.receive  # per message: bound once

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
        return self.output.tap

    @tap.setter
    def tap(self, tap) -> None:
        self.output.tap = self.inbound.tap = tap

    @property
    def admission(self):
        """Who may open a session (xrce.agent.engine.admission); None: anyone."""
        return self.sessions.admission

    @admission.setter
    def admission(self, admission) -> None:
        self.sessions.admission = self.inbound.admission = admission

    @property
    def state(self):
        """The state store's recorder (xrce.agent.state.recorder), told of every control-plane
        change; None: nothing outlives the process."""
        return self.sessions.state

    @state.setter
    def state(self, state) -> None:
        self.sessions.state = self.inbound.state = state

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
        """Handle one whole XRCE message from ``endpoint`` on ``link`` (``Inbound.receive``).
        Never raises."""
        self._receive(link, endpoint, data)

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
        self.inbound.resume_parked()
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
            state, self.state = self.state, None
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


__all__ = ["Agent"]
