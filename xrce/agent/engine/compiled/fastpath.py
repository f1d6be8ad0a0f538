"""The UDP link's optional compiled receive path (``xrce/agent/engine/compiled/_fastpath.c``), Python side.

When the extension is built and the middleware is rclpy, a thread of the extension's own reads
the UDP link's socket (``_receive_thread.c``): ``recvmmsg`` batches, best-effort WRITE_DATA of
registered writers published straight through rcl (and on reliable streams, a datagram of one
WRITE_DATA that is the next in order, or a FRAGMENT of one), the board's HEARTBEATs, plain
ACKNACKs and TIMESTAMPs answered, all without the interpreter. Whatever C leaves (creation, pings,
gaps, a client C may not serve) is handed over in arrival order, and from it on every later
datagram too until Python has handled them: an eventfd wakes the loop, ``handed_over`` delivers
them to the link's usual ``_deliver``. ``XRCE_FASTPATH=0`` (or a missing extension, or another
middleware) leaves the pure Python path, the loop reading the socket.

What is fast is decided here, one piece at a time, when the Python path has just handled a
best-effort or in-order reliable sample (``DataPath.fast_write`` calls ``offer``): the client (by
its source address and, for sessions with a key in the header, that key: a datagram from anywhere
else is Python's to judge, e.g. against --allow-from), the stream (its sequence numbers move into
C; Python's stream object becomes a ``CompiledStream`` or ``CompiledReliableStream`` asking C,
``xrce.agent.engine.compiled.streams``, so the numbers have one owner) and the writer (its rcl
publisher, which C lets go of before the middleware destroys it: ``CompiledClient.forget_writer``).
A client that needs the engine's attention (dead, parked while a type builds, a recovery timeline
pending) and every client while the capture tap or the -v 6 trace is on are left to Python; the
thread is paused while Python decides that (``handed_over``, the engine's timed work), so C never
takes a datagram Python would judge differently. C's counters are folded into the agent's, the
link's, the clients' and the writers' whenever Python runs for the link (a hand-over, the timed
work, which folds before it judges liveliness, and every read of the statistics:
``xrce.agent.engine.compiled.fold``); a reliable stream whose ACKNACK only Python can write (a
NACK to send) wakes Python for it.
C only moves a reliable stream for a sample it published: a failed publish, like every
duplicate, gap or retransmission, reaches Python unchanged.
A registered client's TIMESTAMPs are answered in C (PX4's time sync counts only fast round trips).
The board's ACKNACKs for the agent's reliable output streams are taken in C too when they only
move the acknowledged point (no NACK, the window not full, no HEARTBEAT being timed): the stream
becomes a ``CompiledOutputStream`` whose acknowledged point C owns, and whose history Python frees
as it next looks at the window (``_reliable_out.c`` says why that keeps every rule).
Samples from ROS to a board's reader, and ROS's requests to a board's replier, are taken by the
receive thread from rcl (``_reader_out.c``, ``_replier_out.c``) and sent as the DATA Python would
send while the board's READ_DATA has no limits; a board's reply to a request the thread took goes
back to ROS from the thread too (``send_reply`` when Python decoded it).
"""

from __future__ import annotations

import asyncio
import logging
import os
from dataclasses import dataclass
from typing import Any, Callable, Dict, Optional

from xrce.agent.engine.compiled.client import CompiledClient
from xrce.agent.engine.compiled.fold import CounterFold
from xrce.agent.engine.compiled.streams import CompiledOutputBestEffort, CompiledOutputStream, \
    CompiledReliableStream, CompiledStream
from xrce.agent.engine.limits import STREAM_WINDOW
from xrce.agent.log_levels import TRACE
from xrce.agent.middleware import CompiledPathSupport
from xrce.wire import constants as C
from xrce.wire.streams import OutputBestEffortStream, OutputReliableStream

log = logging.getLogger("xrce.agent")

try:
    from xrce.agent.engine.compiled import _fastpath
except ImportError:  # built without a compiler: the Python path serves
    _fastpath = None


def enabled_by_environment() -> bool:
    return os.environ.get("XRCE_FASTPATH", "1").strip().lower() not in ("0", "no", "off", "false")


@dataclass(frozen=True)
class EngineParts:
    """What the compiled path works with of the engine the link delivers to, given by the one who
    builds the engine (``Agent.attach_compiled_path``): ``support``, what the middleware offers
    this path; ``fastpaths``, the engine's list of compiled paths, which this one joins while it
    reads; ``output``, whose ``tap`` (the capture) leaves every client to Python while it is
    set; ``timelines``, the recovery timelines whose clients Python keeps; ``datapath``, which
    takes the samples C leaves to Python; ``acks``, ``scheduler``, ``budget``, ``stats``, ``lock``
    and ``clock`` as every part of the engine has them; ``reassembly_limit``, the bytes one
    reassembly may hold."""

    support: CompiledPathSupport
    fastpaths: list
    output: Any
    timelines: Any
    datapath: Any
    acks: Any
    scheduler: Any
    budget: Any
    stats: Any
    lock: Any
    clock: Callable[[], float]
    reassembly_limit: int


class FastPath:
    """One UDP link's compiled read, bound to the engine parts the link delivers to."""

    def __init__(self, link, sock, engine: EngineParts):
        self.link = link
        self.support = engine.support
        self.fastpaths = engine.fastpaths
        self.output = engine.output
        self.timelines = engine.timelines
        self.datapath = engine.datapath
        self.acks = engine.acks
        self.scheduler = engine.scheduler
        self.budget = engine.budget
        self.lock = engine.lock
        self.receiver = _fastpath.Receiver(sock.fileno())
        self.receiver.set_reassembly_limit(engine.reassembly_limit)
        self.clients: Dict[int, object] = {}  # handle -> ClientProxy
        # Readers whose samples C takes (_reader_out.c): token -> (ClientProxy, object id), the
        # token of each (client key, object id), and each token's READ_DATA C serves, if any.
        self.readers: Dict[int, tuple] = {}
        self.reader_tokens: Dict[tuple, int] = {}
        self.direct: Dict[int, Optional[tuple]] = {}
        self.repliers: set = set()  # the tokens of those readers that are repliers
        self.counters = CounterFold(self.receiver, link, self.clients, self.readers, self.repliers,
                                    engine.support, engine.acks, engine.budget, engine.stats,
                                    engine.clock)
        self.fold = self.counters.fold
        self._register_soon: set = set()  # (client key, object id) the loop is asked to register
        self.serves_readers = bool(_fastpath.resolve_readers())
        # While Python handles a hand-over, readers it delivered to wait here to be given back
        # to C (reader_ready): C would otherwise send a newer sample before Python has sent an
        # older one still in the same hand-over.
        self._handing = False
        self._revisit: Dict[tuple, tuple] = {}
        self._loop = asyncio.get_running_loop()
        # The thread writes it when it has handed datagrams over or wants a fold.
        self._wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self.fastpaths.append(self)
        self._loop.add_reader(self._wake_fd, self.handed_over)
        self.receiver.start(self._wake_fd)

    @property
    def clock(self) -> Callable[[], float]:
        """The engine's clock, which only the fold reads; ``Agent.clock`` sets it again when a
        test swaps it."""
        return self.counters.clock

    @clock.setter
    def clock(self, clock: Callable[[], float]) -> None:
        self.counters.clock = clock

    def close(self) -> None:
        self.receiver.stop()  # before the clients go: it reads their tables
        for token in list(self.readers):  # the link goes with the agent: its readers too
            self.receiver.remove_reader(token)
        self.readers.clear()
        self.reader_tokens.clear()
        self.repliers.clear()
        self._loop.remove_reader(self._wake_fd)
        os.close(self._wake_fd)
        with self.lock:
            for client in list(self.clients.values()):
                if client.fast is not None:
                    client.fast.drop(client)
        if self in self.fastpaths:
            self.fastpaths.remove(self)

    def handed_over(self) -> None:
        """The receive thread has datagrams for Python, or wants a fold (the loop's reader of the
        eventfd). They are delivered in arrival order with the thread paused, so it takes none
        of a client's datagrams while Python still holds an earlier one or is deciding (``sync``)
        whether C may serve that client."""
        try:
            os.eventfd_read(self._wake_fd)
        except BlockingIOError:
            pass
        link = self.link
        stats = link.stats
        receiver = self.receiver
        receiver.pause()
        self._handing = True
        try:
            while True:
                rest = receiver.take()
                if rest and self.clients:
                    # What C did before the first datagram it left counts before Python handles
                    # that one: a reassembly's bytes (the client's budget) and the stream's ACKNACK.
                    self.fold()
                for data, source in rest:
                    if source.__class__ is int:  # a reader's sample C did not send
                        self._sample_for_python(source, data)
                        continue
                    stats.bytes_in += len(data)
                    link._deliver(source, data)
                if not rest:
                    break
                # The thread is paused, so what a client sent in answer to this round comes in
                # the next: what this round owes goes out first (Acknowledgments.acknack_soon).
                self.acks.flush()
            self._handing = False
            while self._revisit:  # every sample C handed over is out: C may send again
                self.reader_ready(*self._revisit.popitem()[1])
            dropped = receiver.handoff_dropped()
            if dropped:
                stats.drops += dropped
            if self.clients:
                self.fold()
                self.sync()
            if receiver.heartbeat_due(False):  # C sent reliable DATA: its HEARTBEAT round
                self.scheduler.heartbeat_soon()
        finally:
            self._handing = False
            self._revisit.clear()
            receiver.resume()  # what came meanwhile waits in the hand-off: the eventfd is set

    def pause(self) -> None:
        """Python's engine is about to judge the clients and send the HEARTBEATs (timed work):
        C hands every datagram over until ``resume``, and asks again for a HEARTBEAT round for
        reliable DATA it sends from now on."""
        self.receiver.pause()
        self.receiver.heartbeat_due(True)

    def resume(self) -> None:
        self.receiver.resume()

    def _sample_for_python(self, token: int, cdr: bytes) -> None:
        """A sample C took and left to Python (its READ_DATA is not C's to serve, or the window
        is full): delivered as the middleware's own callback would. C serves the reader again
        once Python's queue is empty (``reader_ready`` from ``DataPath.pump``)."""
        reader = self.readers.get(token)
        if reader is None:
            return
        self.direct[token] = None  # C stopped sending for it when it handed this one over
        client, object_id = reader
        # a replier's request comes as its identity and body (C holds the request for the reply)
        self.datapath.from_middleware(client, object_id,
                                            cdr if token in self.repliers else cdr[4:])

    # -- registration ---------------------------------------------------------------------

    def _eligible(self, client) -> bool:
        pending = self.timelines.pending
        return client.alive and not client.dead and client.parked is None and \
            not client.resuming and client.link is self.link and not (pending and
                                                                      client.key in pending)

    def _compiled(self, client, what: str) -> Optional[CompiledClient]:
        """The client's registration in C, made now if it has none; None if it may not have
        one (the capture tap or the trace is on, or the client needs the engine's attention)."""
        if self.output.tap is not None or log.isEnabledFor(TRACE) or not self._eligible(client):
            return None
        state: Optional[CompiledClient] = client.fast
        if state is None:
            key = client.key if client.session_id < 0x80 else b"\0\0\0\0"
            handle = self.receiver.add_client(client.session_id, key, client.endpoint)
            state = client.fast = CompiledClient(self, handle)
            self.clients[handle] = client
            for token, (owner, _object_id) in self.readers.items():
                if owner is client:  # its readers, kept while it was not registered
                    self.receiver.set_reader_client(token, handle)
            log.debug("client %s: %s take the compiled path", client.key.hex(), what)
        return state

    def reader_ready(self, client, entry) -> None:
        """After Python delivered what it could for a reader (``DataPath.pump``) or a READ_DATA
        replaced the last (``DataPath.read_data``): C sends the reader's samples itself while its
        READ_DATA has no limits (no count, deadline or rate) and nothing waits in Python's
        queue; otherwise every sample is Python's. Runs per sample Python delivers: the common
        answer (unchanged) is a dictionary look-up."""
        reader = entry.reader
        active = reader.active
        want = None
        if active is not None and not reader.queue and active.remaining is None and \
                active.deadline is None and not active.rate and client.alive:
            want = (active.request_id, active.stream_id)
        token = self.reader_tokens.get((client.key_int, entry.object_id))
        if token is not None and self.direct.get(token) == want:
            return
        if want is not None and self._handing and self.scheduler.on_loop_thread():
            self._revisit[(client.key_int, entry.object_id)] = (client, entry)
            return
        if want is None:
            if token is not None:
                self.direct[token] = None
                self.receiver.set_reader_direct(token, -1, 0, 0)
            return
        if not self.serves_readers:
            return
        if not self.scheduler.on_loop_thread():
            # Registration is the loop's. A sample (or request) delivered on rclpy's thread asks
            # the loop to try: the entity may not have existed when its READ_DATA came (created
            # in a burst the domain's executor takes in later), and every later sample could
            # come this way.
            key = (client.key_int, entry.object_id)
            if key not in self._register_soon:
                self._register_soon.add(key)
                try:
                    self._loop.call_soon_threadsafe(self._register_later, key, client, entry)
                except RuntimeError:  # the loop has closed: the agent is going away
                    pass
            return
        state = self._compiled(client, "samples from ROS")
        if state is None:
            return
        if token is None:
            token = self._add_reader(client, state, entry)
            if not token:
                return
        stream_id = want[1]
        if stream_id & 0x80:
            if stream_id not in client.out_reliable:
                client.out_reliable[stream_id] = OutputReliableStream(stream_id, STREAM_WINDOW)
            with self.lock:
                state.compile_output(client)
            stream = client.out_reliable[stream_id]
            if not isinstance(stream, CompiledOutputStream):
                return
            if stream_id in client.out_pending:
                stream.hold(True)
        elif stream_id:
            stream = client.out_best_effort.get(stream_id)
            if stream is None:
                stream = OutputBestEffortStream(stream_id)
            if not isinstance(stream, CompiledOutputBestEffort):
                client.out_best_effort[stream_id] = CompiledOutputBestEffort(
                    self.receiver, state.handle, stream)
        else:
            return  # stream none (a cancel's answer): Python's
        self.direct[token] = want
        self.receiver.set_reader_direct(token, want[0], stream_id, client.mtu)

    def _register_later(self, key: tuple, client, entry) -> None:
        self._register_soon.discard(key)
        if client.objects.get(entry.object_id) is not entry:
            return  # deleted meanwhile
        with self.lock:  # (reentrant: reader_ready takes it again to compile output)
            self.reader_ready(client, entry)

    def _add_reader(self, client, state: CompiledClient, entry) -> int:
        """Register the reader's (or replier's) rcl entity in C; its token, 0 if C cannot take
        it."""
        support = self.support
        key = client.entity(entry.object_id)
        if entry.kind == C.OBJK_REPLIER:
            service = support.replier_service(key)
            if service is None:
                return 0
            try:
                token = self.receiver.add_replier(state.handle, entry.object_id, *service)
            except RuntimeError as exc:  # rcl refused the callback: Python's path goes on
                log.debug("client %s: replier 0x%04X stays Python's: %s", client.key.hex(),
                          entry.object_id, exc)
                return 0
            if not token:
                return 0
            self.repliers.add(token)
            receiver = self.receiver
            support.replier_sequence_from(key, lambda: receiver.replier_sequence(token))
            what = "requests from ROS and their replies"
        else:
            address = support.subscription_address(key)
            if not address:
                return 0
            token = self.receiver.add_reader(state.handle, entry.object_id, address)
            if not token:
                return 0
            what = "samples from ROS"
        self.readers[token] = (client, entry.object_id)
        self.reader_tokens[(client.key_int, entry.object_id)] = token
        log.debug("client %s: %s 0x%04X: %s take the compiled path", client.key.hex(),
                  "replier" if token in self.repliers else "reader", entry.object_id, what)
        return token

    def send_reply(self, client, object_id: int, sample: bytes) -> Optional[bool]:
        """A replier's reply Python decoded (identity, then body): sent by C when it answers a
        request C holds; None when it is not C's (the middleware's own then)."""
        token = self.reader_tokens.get((client.key_int, object_id))
        if token is None or token not in self.repliers:
            return None
        sent = self.receiver.send_reply(token, sample)
        if sent == 0:
            return None
        if sent < 0:
            log.warning("client %s: reply of replier 0x%04X does not deserialize, or ROS refused "
                        "it", client.key.hex(), object_id)
        return sent > 0

    def reclaim_reader(self, client, object_id: int) -> None:
        """rclpy's executor delivered a sample of a reader C holds: it set the subscription's
        callback after C did (it adds a new domain's entities once the first client's burst of
        CREATEs is over), so C takes the callback back; this sample goes Python's way."""
        token = self.reader_tokens.get((client.key_int, object_id))
        if token is not None and self.receiver.reclaim_reader(token):
            log.debug("client %s: %s 0x%04X: taken back from rclpy's executor", client.key.hex(),
                      "replier" if token in self.repliers else "reader", object_id)

    def forget_reader(self, client, object_id: int) -> None:
        """Before the reader's subscription is destroyed: C lets go of it (and rmw calls C's
        callback no more)."""
        token = self.reader_tokens.pop((client.key_int, object_id), None)
        if token is None:
            return
        self.fold()
        if token in self.repliers:  # identities are the record's again (it is going anyway)
            self.repliers.discard(token)
            self.support.replier_sequence_from(client.entity(object_id), None)
        self.receiver.remove_reader(token)
        self.readers.pop(token, None)
        self.direct.pop(token, None)

    def offer(self, client, stream_id: int, entry) -> None:
        """The Python path just accepted a sample for ``entry`` on ``stream_id`` (best-effort,
        or reliable in order): make what is not compiled yet compiled, if the client qualifies."""
        state = self._compiled(client, "best-effort samples")
        if state is None:
            return
        if len(client.out_reliable) != len(state.out_streams):
            state.compile_output(client)
        if stream_id not in state.streams and stream_id & 0x80:
            stream = client.in_reliable.get(stream_id)
            if stream is None or stream.stored or stream_id in client.reassembly:
                return  # (the reassembly has one holder: Python's ends before C's may begin)
            client.in_reliable[stream_id] = CompiledReliableStream(self.receiver, state.handle,
                                                                   stream)
            state.streams.add(stream_id)
            state.reliable = True
            self.receiver.set_room(state.handle, self.room(client))
            log.debug("client %s: reliable stream 0x%02X: samples in order take the compiled path",
                      client.key.hex(), stream_id)
        elif stream_id not in state.streams:
            stream = client.in_best_effort.get(stream_id)
            if stream is None:
                return
            self.receiver.add_stream(state.handle, stream_id, stream.last_handled)
            client.in_best_effort[stream_id] = CompiledStream(self.receiver, state.handle, stream_id)
            state.streams.add(stream_id)
        if entry.object_id not in state.writers:
            address = self.support.publisher_address(client.entity(entry.object_id))
            if address:
                self.receiver.add_writer(state.handle, entry.object_id, address)
                state.writers.add(entry.object_id)

    def sync(self) -> None:
        """Disable the clients that need the engine's attention; re-enable the others."""
        self.receiver.set_enabled(self.output.tap is None and not log.isEnabledFor(TRACE))
        for client in self.clients.values():
            state = client.fast
            if state is None:
                continue
            eligible = self._eligible(client)
            if eligible != state.enabled:
                state.enabled = eligible
                self.receiver.set_client_enabled(state.handle, eligible)
            if eligible and state.reliable:
                self.receiver.set_room(state.handle, self.room(client))
            if eligible and len(client.out_reliable) != len(state.out_streams):
                with self.lock:  # a stream created since: its ACKNACKs reached Python
                    if client.fast is state:
                        state.compile_output(client)

    def room(self, client) -> int:
        """What the client's byte budget leaves (``MemoryBudget.over``): C stores a FRAGMENT
        only within it, as Python's ``_hold_back`` refuses one beyond it. Refreshed whenever
        Python has handled a datagram; between, C counts down what it adds itself."""
        budget = self.budget
        return min(budget.max_client_bytes - client.buffered - client.queued_bytes,
                   budget.max_total_bytes - budget.buffered_total - budget.queued_total)


def stale_build(module) -> Optional[str]:
    """Why ``module`` (the built extension) is not what the C sources beside it build, or None.

    An editable install keeps the .so it built while the .c changes under it; a stale receive
    path would publish by the old rules (``xrce.agent.c_sources``)."""
    from xrce.agent import c_sources

    return c_sources.stale_build(module, os.path.dirname(os.path.abspath(__file__)))


def attach(link, sock, engine: EngineParts) -> Optional[FastPath]:
    """A ``FastPath`` for ``link`` over ``sock``, working with ``engine``'s parts, if the
    extension, the environment and the middleware (``engine.support``) allow one."""
    if _fastpath is None:
        log.debug("%s: compiled receive path not built; Python path", link.name)
        return None
    if not enabled_by_environment():
        log.debug("%s: compiled receive path off (XRCE_FASTPATH); Python path", link.name)
        return None
    stale = stale_build(_fastpath)
    if stale is not None:
        log.warning("%s: compiled receive path %s: `pip install -e .` rebuilds it; Python path",
                    link.name, stale)
        return None
    if engine.support is None:
        log.debug("%s: middleware without rcl publishers; Python path", link.name)
        return None
    if not _fastpath.resolve_rcl():
        log.debug("%s: rcl_publish_serialized_message not found; Python path", link.name)
        return None
    log.debug("%s: compiled receive path", link.name)
    return FastPath(link, sock, engine)
