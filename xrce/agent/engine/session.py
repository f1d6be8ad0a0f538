"""Session state: what the agent knows about each client, and how sessions begin and end (XRCE-WIRE.md §3, §4).

``ClientProxy`` is one client: its key, where replies go, its streams, its XRCE objects, its
quota warnings and its per-client counters. ``ClientTable`` holds the clients (by key, by
endpoint, by host); ``MemoryBudget`` counts the bytes their buffers hold. ``Sessions``, one part
of ``xrce.agent.engine.dispatch.Agent``, answers CREATE_CLIENT and GET_INFO, binds sessions to
endpoints, enforces ``max_clients``, says when a client is dead or certainly gone and deletes
clients. The agent-wide counters (``AgentStats``) and the per-client quota defaults live here too.
"""

from __future__ import annotations

import ipaddress
import logging
import math
from collections import deque
from dataclasses import dataclass, fields
from typing import Any, Callable, Deque, Dict, Hashable, Optional, Protocol, Set, Tuple

from xrce.wire import constants as C
from xrce.agent.engine.admission import endpoint_address
from xrce.agent.engine.scheduler import NEVER
from xrce.agent.middleware import ClientOrigin, EntityKey, TopicSpec
from xrce.agent.observe.names import client_tag
from xrce.wire.streams import (
    InputBestEffortStream, InputReliableStream, OutputBestEffortStream, OutputReliableStream,
)
from xrce.wire.submessages import GetInfo, Info, StatusAgent, encode_message

log = logging.getLogger("xrce.agent")

STREAM_WINDOW = 16  # RELIABLE_STREAM_DEPTH of the eProsima agent, both directions
# Per-client quotas (defaults; ``Agent`` takes each as a constructor argument, the CLI as a flag).
# A fragmented message larger than this is abandoned: room for a 1 MiB sample (camera frames,
# point clouds) and its headers.
MAX_REASSEMBLY = 1024 * 1024 + 1024
MAX_OBJECTS_PER_CLIENT = 4096  # beyond this CREATE answers ERR_RESOURCES
MAX_OUTPUT_QUEUE_BYTES = 1024 * 1024  # samples waiting for one client; the oldest go first
MAX_CLIENTS = 1024  # CREATE_CLIENT of a new key beyond this evicts a dead or idle client
# Memory budget: every buffer a client can fill (out-of-order input, reassembly, parked messages,
# reader queues, reliable output windows and fragments waiting for them) counts against its own
# budget and against the agent's total. Past either, buffered input is refused unacknowledged
# (the client retransmits later) and output for that client is dropped; the agent goes on.
MAX_CLIENT_BYTES = 8 * 1024 * 1024
MAX_TOTAL_BYTES = 64 * 1024 * 1024
TRIM_AFTER_BYTES = 256 * 1024  # a client deleted holding more: free heap pages go back (malloc_trim)
QUOTA_LOG_INTERVAL = 1.0  # seconds between repeated quota log lines for one client and quota
# eProsima's UAGENT_CONFIG_CLIENT_DEAD_TIME; eProsima never destroys a silent client's entities
# unless it asked for hard liveliness (uxr_hl), hence expiry off by default.
CLIENT_DEAD_TIME = 30.0
CLIENT_EXPIRE_TIME = 0.0
MIN_MTU = 24  # smaller CREATE_CLIENT mtu values would leave no room for a fragment chunk
DEFAULT_MTU = 508  # what eProsima assumes when CREATE_CLIENT carries none
INFO_CACHE_SIZE = 256  # encoded INFO replies kept (a ping repeats one question)
# After a new client appears on a host, how long (s) its dead neighbours are checked, and how
# often, for the participant that would show it to be one of them started over.
SUCCESSOR_WATCH_S = 60.0
SUCCESSOR_CHECK_S = 0.5


class Link(Protocol):
    """A transport server as the engine sees it."""

    name: str
    sends_from_any_thread: bool

    def send(self, endpoint: Any, data: bytes) -> None: ...


@dataclass
class AgentStats:
    messages_in: int = 0
    messages_out: int = 0
    bytes_in: int = 0
    bytes_out: int = 0
    decode_errors: int = 0
    dropped: int = 0  # whole input messages not processed (malformed, unknown client, stale)
    handler_errors: int = 0  # unexpected exceptions while handling a message
    duplicates: int = 0
    retransmissions: int = 0
    heartbeats_out: int = 0
    acknacks_out: int = 0
    fragments_in: int = 0
    fragments_out: int = 0
    reassembly_overflows: int = 0
    oversize_dropped: int = 0  # best-effort output larger than the client's mtu
    status_lost: int = 0  # STATUS not sent (none since a reply waits for room in a full window)
    samples_in: int = 0
    samples_compiled: int = 0  # of samples_in, those the compiled UDP read published
    samples_out_compiled: int = 0  # of samples_out, those the compiled path sent to a board
    publish_errors: int = 0  # board samples the middleware refused to publish (either path)
    samples_out: int = 0
    samples_overwritten: int = 0  # reader queue full: oldest sample dropped
    clients_created: int = 0
    clients_deleted: int = 0
    clients_dead: int = 0  # times a client went silent for client_dead_time
    clients_revived: int = 0  # dead clients that spoke again
    clients_expired: int = 0  # silent for client_expire_time: deleted with their entities
    clients_replaced: int = 0  # deleted at once: a new key took over their endpoint
    clients_retired: int = 0  # dead and certainly gone (a newer client on their host, or closed)
    clients_refused: int = 0  # CREATE_CLIENT beyond max_clients with no dead client to evict
    endpoints_closed: int = 0  # TCP connections / serial ports that went away under a session
    quota_objects: int = 0  # CREATE refused with ERR_RESOURCES
    quota_output_dropped: int = 0  # samples dropped because a client's output queue was full
    budget_refused: int = 0  # reliable input left unacknowledged: the memory budget was spent
    clients_evicted: int = 0  # idle sessions (no objects) deleted to admit a new client
    nested_fragments: int = 0  # reassembled messages holding FRAGMENTs again: dropped
    sources_refused: int = 0  # datagrams from outside --allow-from, dropped before any lookup
    mismatches: int = 0  # board/ROS endpoint pairs that cannot talk, each warned once (objects.py)

    def as_dict(self) -> Dict[str, int]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


class ReadRequest:
    """An active READ_DATA: where to deliver and when to stop."""

    __slots__ = ("request_id", "stream_id", "remaining", "deadline", "rate", "tokens", "refilled",
                 "deadline_until_first")

    def __init__(self, request_id: int, stream_id: int, remaining: Optional[int],
                 deadline: Optional[float], rate: int, now: float,
                 deadline_until_first: bool = False):
        self.request_id = request_id
        self.stream_id = stream_id
        self.remaining = remaining  # None = unlimited
        self.deadline = deadline
        self.deadline_until_first = deadline_until_first  # the first sample lifts the deadline
        self.rate = rate  # bytes per second, 0 = unlimited
        self.tokens = float(rate)
        self.refilled = now


class ReaderState:
    __slots__ = ("queue", "active")

    def __init__(self, bound: int):
        self.queue: Deque[bytes] = deque(maxlen=bound)
        self.active: Optional[ReadRequest] = None


@dataclass
class ObjectEntry:
    object_id: int
    kind: int
    parent: Optional[int]
    signature: Tuple[int, Any, int]  # (format, decoded representation, tail): xrce.agent.engine.reuse
    topic: Optional[int] = None  # the topic object a writer/reader uses
    topic_spec: Optional[TopicSpec] = None
    reader: Optional[ReaderState] = None
    samples: int = 0  # written into the middleware (writers) or delivered to the client (readers)
    sample_bytes: int = 0
    # Writers: the middleware's publish for this entity, looked up once (see DataPath.fast_write).
    write: Optional[Callable[[bytes], bool]] = None
    info: Optional[dict] = None  # what it is in words, for logs and stats (observe/entities.py)


class ClientProxy:
    """One client session: key, destination, streams and XRCE objects."""

    def __init__(self, key: bytes, session_id: int, mtu: int, link: Link, endpoint: Hashable,
                 now: float, hard_liveliness: Optional[float]):
        self.key = key
        self.key_int = int.from_bytes(key, "big")
        self.session_id = session_id
        self.header_key = key if session_id < C.SESSION_ID_WITHOUT_KEY_MASK else None
        self.mtu = max(mtu, MIN_MTU)
        self.link = link
        self.endpoint = endpoint
        self.last_seen = now
        self.hard_liveliness = hard_liveliness
        self.probes = 0
        self.dead = False  # silent for the dead time: no HEARTBEATs until it speaks again
        # The machine or device it speaks from (``client_host``) and whether its TCP connection
        # or serial port went away: what the retirement rule (xrce.agent.engine.liveliness) uses.
        self.host: Hashable = None
        self.closed = False
        self.queued_bytes = 0  # sample bytes waiting in this client's reader queues
        # Bytes of this client's other buffers (see MAX_CLIENT_BYTES); MemoryBudget.charge keeps it.
        self.buffered = 0
        self.quota_logged: Dict[str, float] = {}
        self.objects: Dict[int, ObjectEntry] = {}
        self.in_best_effort: Dict[int, InputBestEffortStream] = {}
        self.in_reliable: Dict[int, InputReliableStream] = {}
        # Per reliable input stream: the first_unacked of the last ACKNACK sent, how many repeats
        # of it are still allowed, and what the stream held and had seen twice then
        # (xrce.agent.engine.liveliness.Acknowledgments).
        self.acknacks_sent: Dict[int, list] = {}
        self.out_best_effort: Dict[int, OutputBestEffortStream] = {}
        self.out_reliable: Dict[int, OutputReliableStream] = {}
        self.reassembly: Dict[int, bytearray] = {}
        # Reliable output not yet sent, per stream: fragments of a sample longer than the window
        # has room for, sent as ACKNACKs free room (xrce.agent.engine.datapath.DataPath.send_pending).
        self.out_pending: Dict[int, Deque[bytes]] = {}
        self.blocked_readers: Set[int] = set()
        self.alive = True  # False once deleted: late middleware callbacks are ignored
        # While a CREATE waits for its type to be built: the messages to process afterwards, in
        # order, starting with the rest of the one that held the CREATE. None when not parked.
        self.parked: Optional[list] = None
        # xrce.agent.engine.fastpath.CompiledClient while the UDP link's compiled path knows this client.
        self.fast: Any = None
        # Per-client counters for xrce.agent.observe.observability; plain ints so the hot path stays cheap.
        self.created_at = now
        self.messages_in = 0
        self.bytes_in = 0
        self.messages_out = 0
        self.bytes_out = 0
        self.decode_errors = 0
        self.duplicates = 0
        self.retransmissions = 0
        # The agent cannot know the client's clock offset; it can time HEARTBEAT -> ACKNACK and
        # see how far a client's TIMESTAMP is from its own clock on arrival (skew + one-way delay).
        self.heartbeat_sent_at: Optional[float] = None
        self.rtt_s: Optional[float] = None
        self.timestamp_skew_ns: Optional[int] = None
        # Restored from the state store by a restarted agent (xrce.agent.state.recorder): the
        # board does not know the agent went away. ``spoken``: it has sent something since.
        # ``resume_inputs``: its input streams start where the board's first message or
        # HEARTBEAT says (until its next CREATE_CLIENT). ``resuming``: its reliable output
        # streams still wait for the board's ACKNACK to say where they are (ResumingStream).
        self.restored = False
        self.spoken = False
        self.resume_inputs = False
        self.resuming = False
        # ``input_resync``: its own reliable output streams, which the agent must set going
        # again itself (xrce.agent.engine.resync.InputResync), None once they all are.
        self.input_resync: Any = None

    def entity(self, object_id: int) -> EntityKey:
        return (self.key_int, object_id)

    def warn_quota(self, quota: str, now: float, message: str, *args) -> None:
        """A WARNING that one of its quotas was hit, at most once per QUOTA_LOG_INTERVAL."""
        last = self.quota_logged.get(quota)
        if last is None or now - last >= QUOTA_LOG_INTERVAL:
            self.quota_logged[quota] = now
            log.warning("client %s: " + message, self.key.hex(), *args)

    def reset_streams(self) -> None:
        if self.fast is not None:  # its sequence numbers live in the compiled path
            self.fast.drop(self)
        self.in_best_effort.clear()
        self.in_reliable.clear()
        self.out_best_effort.clear()
        self.out_reliable.clear()
        self.reassembly.clear()
        self.out_pending.clear()
        self.blocked_readers.clear()

    def stream_bytes(self) -> int:
        """Bytes held by its streams (what ``reset_streams`` frees)."""
        return sum(s.stored_bytes for s in self.in_reliable.values()) + \
            sum(s.stored_bytes for s in self.out_reliable.values()) + \
            sum(len(b) for b in self.reassembly.values()) + \
            sum(len(m) for q in self.out_pending.values() for m in q)



class ResumingStream(OutputReliableStream):
    """A restored client's reliable output stream until the board says where it is.

    The board's input stream expects the sequence number after the last one the previous agent
    process sent, which this process cannot know (it is not stored per sample). eProsima's client
    ignores a HEARTBEAT's first sequence number, and answers every HEARTBEAT with an ACKNACK whose
    first unacknowledged number is exactly that one. So until that ACKNACK arrives this stream
    sends nothing (its window is "full": samples wait in their readers' queues, replies in
    ``out_pending``) and asks with ``heartbeat``; ``Agent`` then puts a plain stream starting
    there in its place (``resumed_at``).

    The HEARTBEAT names ``last`` (the number stored at the last checkpoint) as its last
    unacknowledged one, never one ahead of the board's: a board raises what it was announced to
    that, and would then count as missing every number up to it."""

    __slots__ = ()

    def __init__(self, stream_id: int, history: int, last: int):
        super().__init__(stream_id, history)
        self.last_sent = self.last_acknowledged = last & 0xFFFF

    def has_room(self):
        return False

    def next_seq(self):
        return None

    def heartbeat(self):
        return (self.last_sent + 1) & 0xFFFF, self.last_sent

    def on_acknack(self, first_unacked, nack_bitmap, now_ms=0, holdoff_ms=0, session=None):
        return ()

    def release(self) -> int:  # (the compiled streams' interface: nothing is held here)
        return 0

    def hold(self, held: bool) -> None:
        pass

    @staticmethod
    def resumed_at(stream_id: int, history: int, first_unacked: int) -> OutputReliableStream:
        """The plain stream that carries on from the board's ``first_unacked``."""
        stream = OutputReliableStream(stream_id, history)
        stream.last_sent = stream.last_acknowledged = (first_unacked - 1) & 0xFFFF
        return stream


class ClientTable:
    """Who the clients are: ``clients`` (key → ClientProxy), ``endpoints`` ((link, endpoint) →
    key, for sessions without a key in their headers, ≥ 0x81), the endpoints closed under such a
    session (``closed_endpoints``: the next CREATE there replaces it) and the clients of each
    host (``hosts``: ``client_host`` → HostRecord, what the retirement rule looks at).

    ``Sessions`` changes it; the dispatcher and the data path look clients up in it (the dicts
    stay the same objects for the agent's life, so a hot path binds them once)."""

    def __init__(self):
        self.clients: Dict[bytes, ClientProxy] = {}
        self.endpoints: Dict[Tuple[Any, Hashable], bytes] = {}
        self.closed_endpoints: Dict[Tuple[Any, Hashable], bytes] = {}
        self.hosts: Dict[Hashable, HostRecord] = {}

    def at(self, link: Link, endpoint: Hashable) -> Optional[ClientProxy]:
        """The session without a key bound to ``endpoint`` on ``link``, if any."""
        key = self.endpoints.get((link, endpoint))
        return self.clients.get(key) if key is not None else None


class MemoryBudget:
    """The bytes the clients' buffers hold, per client (``ClientProxy.buffered`` and
    ``queued_bytes``) and in all (``buffered_total``, ``queued_total``), against
    ``max_client_bytes`` and ``max_total_bytes`` (see MAX_CLIENT_BYTES)."""

    def __init__(self, max_client_bytes: int, max_total_bytes: int):
        self.max_client_bytes = max_client_bytes
        self.max_total_bytes = max_total_bytes
        self.buffered_total = 0  # the clients' ClientProxy.buffered, summed
        self.queued_total = 0  # the clients' ClientProxy.queued_bytes, summed
        self.trim_due = False  # clients holding buffers were deleted (see Agent._tick_locked)

    def charge(self, client: ClientProxy, delta: int) -> None:
        if client.alive:  # a deleted client gave all its bytes back at once
            client.buffered += delta
            self.buffered_total += delta

    def over(self, client: ClientProxy, extra: int) -> bool:
        """True if ``extra`` more bytes for ``client`` would exceed its budget or the agent's."""
        return client.buffered + client.queued_bytes + extra > self.max_client_bytes or \
            self.buffered_total + self.queued_total + extra > self.max_total_bytes


class Sessions:
    """Session establishment and teardown: CREATE_CLIENT and GET_INFO, sessions bound to
    endpoints, ``max_clients``, a client's dead time, its retirement and its deletion.

    Collaborators: ``table`` (changed here only), ``objects`` (a deleted client's objects go
    with it: ``ObjectRegistry.delete_object``), ``output`` (STATUS_AGENT, INFO), ``budget``,
    ``scheduler`` (a new session's dead time is due), ``timelines`` (clients that come back).
    ``admission`` (who may open a session, None: anyone) is set by the agent.
    """

    def __init__(self, table: ClientTable, objects, output, budget: MemoryBudget, scheduler,
                 timelines, stats: AgentStats, clock: Callable[[], float], *, max_clients: int,
                 client_dead_time: float, client_expire_time: float, heartbeat_period: float):
        self.table = table
        self.clients = table.clients
        self.endpoints = table.endpoints
        self.hosts = table.hosts
        self.objects = objects
        self.output = output
        self.budget = budget
        self.scheduler = scheduler
        self.timelines = timelines
        self.stats = stats
        self.clock = clock
        self.max_clients = max_clients
        self.client_dead_time = client_dead_time
        self.client_expire_time = client_expire_time
        self.heartbeat_period = heartbeat_period
        self.admission = None
        # The state store's recorder (xrce.agent.state.recorder), None without one: told of
        # every session established and deleted. Set by the agent.
        self.state = None
        self._info_cache: Dict[tuple, bytes] = {}  # see info_message

    def endpoint_closed(self, link: Link, endpoint: Hashable) -> None:
        """A TCP connection or serial port went away: sessions identified by that endpoint need a
        new CREATE_CLIENT (as a new UDP socket would). Their objects stay for REUSE until the
        board comes back with its key, a new client takes the endpoint (replaced at once), or
        the dead time passes (retired: ``retirement``)."""
        key = self.endpoints.pop((link, endpoint), None)
        for client in self.clients.values():
            if client.link is link and client.endpoint == endpoint:
                self.stats.endpoints_closed += 1
                client.closed = True
                if client.header_key is None:  # bound to it: the next CREATE there replaces it
                    self.table.closed_endpoints[(link, endpoint)] = client.key
                log.info("client %s: %s %r closed; its entities are kept until it returns or its "
                         "dead time passes", client.key.hex(), link.name, endpoint)
                # Already dead: nothing of it is scheduled any more.
                self.scheduler.wake_at(self.clock() + self.heartbeat_period)
        if key is not None and key not in self.clients:
            log.debug("endpoint %s %r was mapped to unknown client %s", link.name, endpoint, key.hex())

    def create_client(self, link: Link, endpoint: Hashable, header, request,
                      raw: Optional[tuple] = None) -> None:
        """``raw``: (flags, message, start, end) of the CREATE_CLIENT, for the state store."""
        session_id = request.session_id
        reply_key = bytes(request.client_key) if session_id < C.SESSION_ID_WITHOUT_KEY_MASK else None
        status = C.STATUS_OK
        if request.client_key == b"\x00\x00\x00\x00" or request.cookie != C.XRCE_COOKIE:
            status = C.STATUS_ERR_INVALID_DATA
        elif request.version[0] != C.XRCE_VERSION_MAJOR:
            status = C.STATUS_ERR_INCOMPATIBLE
        elif self.admission is not None and \
                not self.admission.admits(bytes(request.client_key), link, endpoint):
            status = C.STATUS_ERR_DENIED  # --allow-keys / --allow-from (xrce.agent.engine.admission)
        elif not self._room_for_client(bytes(request.client_key), link, endpoint, session_id):
            status = C.STATUS_ERR_RESOURCES
        if status == C.STATUS_OK:
            self._establish(link, endpoint, request, raw)
        self.output.send_raw(link, endpoint, encode_message(session_id, C.STREAM_NONE, 0, reply_key,
                                                            [StatusAgent(status)]))

    def _establish(self, link: Link, endpoint: Hashable, request, raw: Optional[tuple] = None
                   ) -> None:
        key = bytes(request.client_key)
        session_id = request.session_id
        now = self.clock()
        if session_id >= C.SESSION_ID_WITHOUT_KEY_MASK:
            # The endpoint is the only identity of a session without a key in its headers: a new
            # key created there means the board behind it started over (a reboot, rmw's fini and
            # init). The old session cannot be reached any more: delete it now, not as a ghost.
            bound = self.endpoints.get((link, endpoint)) or \
                self.table.closed_endpoints.get((link, endpoint))
            if bound is not None and bound != key and bound in self.clients:
                self.stats.clients_replaced += 1
                log.info("client %s replaced by client %s on %s %r: deleting its %d objects",
                         bound.hex(), key.hex(), link.name, endpoint,
                         len(self.clients[bound].objects))
                self.delete_client(self.clients[bound])
        host = client_host(link, endpoint)
        client = self.clients.get(key)
        restarted = client is not None and client.session_id == session_id
        if restarted:
            self.reset_streams(client)  # session restart: objects survive for REUSE
            self._unbind(client)
            client.link, client.endpoint, client.last_seen, client.probes = link, endpoint, now, 0
            client.dead = client.closed = False
            if host != client.host:
                self._leave_host(client)
                self._join_host(client, host, None)
            log.info("client %s session 0x%02X restarted on %s %r, %d objects kept for reuse",
                     key.hex(), session_id, link.name, endpoint, len(client.objects))
        else:
            if client is not None:
                log.info("client %s replaced (session 0x%02X → 0x%02X)", key.hex(),
                         client.session_id, session_id)
                self.delete_client(client)
            mtu = request.mtu if request.mtu is not None else DEFAULT_MTU
            client = ClientProxy(key, session_id, mtu, link, endpoint, now,
                                 _hard_liveliness(request.properties))
            self.clients[key] = client
            self.stats.clients_created += 1
            log.info("client %s session 0x%02X created on %s %r (mtu %d; shown to others as %s)",
                     key.hex(), session_id, link.name, endpoint, client.mtu, client_tag(key))
            self._join_host(client, host, now)
        if session_id >= C.SESSION_ID_WITHOUT_KEY_MASK:
            self.endpoints[(link, endpoint)] = key
        # A CREATE_CLIENT says where the board's streams are (at their start): a restored
        # session stops guessing (xrce.agent.state.recorder).
        client.resume_inputs = client.resuming = False
        client.input_resync = None
        self.scheduler.wake_at(now + self.quiet_limit(client))
        self.timelines.established(client, restarted)
        if self.state is not None and raw is not None:
            self.state.client_established(client, *raw, restarted)

    def _join_host(self, client: ClientProxy, host: Hashable, born: Optional[float]) -> None:
        """Count ``client`` among ``host``'s; ``born``: it is a new client there (not a restart),
        whose entities may show that a dead neighbour was its previous life (``retirement``)."""
        client.host = host
        record = self.hosts.get(host)
        if record is None:
            record = self.hosts[host] = HostRecord()
        record.members.add(client)
        if born is not None:
            record.born_at = born
            if len(record.members) > 1:  # its neighbours are looked at from the next tick on
                self.scheduler.wake_at(born + self.heartbeat_period)

    def _leave_host(self, client: ClientProxy) -> None:
        record = self.hosts.get(client.host)
        if record is not None:
            record.members.discard(client)
            if not record.members:  # bounded by the clients: a spoofed flood's hosts go too
                del self.hosts[client.host]

    def _room_for_client(self, key: bytes, link: Link, endpoint: Hashable, session_id: int) -> bool:
        """True if a session for ``key`` fits under max_clients, evicting what it takes: the
        longest-silent dead client first, else the least recently heard session that never
        created an object. A flood of CREATE_CLIENTs with new keys (spoofable, from anywhere)
        only ever evicts its own kind, so it cannot lock out a board that goes on to create its
        entities; sessions holding entities are refused only when every slot holds one."""
        if key in self.clients or len(self.clients) < self.max_clients:
            return True
        if session_id >= C.SESSION_ID_WITHOUT_KEY_MASK and self.endpoints.get((link, endpoint)) \
                in self.clients:
            return True  # re-binding this endpoint deletes its current client first
        now = self.clock()
        dead = idle = None
        for c in self.clients.values():
            if now - c.last_seen >= self.dead_time(c):
                if dead is None or c.last_seen < dead.last_seen:
                    dead = c
            elif not c.objects and (idle is None or c.last_seen < idle.last_seen):
                idle = c
        victim = dead or idle
        if victim is not None:
            self.stats.clients_evicted += 1
            if victim is dead:
                log.warning("%d clients: evicting dead client %s to admit %s", len(self.clients),
                            victim.key.hex(), key.hex())
            elif self.stats.clients_evicted & 0x3FF == 1:  # a flood: one line per 1024
                log.warning("%d clients: evicting client %s (no objects, silent %.1f s) to admit "
                            "%s; %d evicted so far", len(self.clients), victim.key.hex(),
                            now - victim.last_seen, key.hex(), self.stats.clients_evicted)
            self.delete_client(victim)
            return True
        self.stats.clients_refused += 1
        log.warning("%d clients, none dead or idle: refusing client %s (max_clients)",
                    len(self.clients), key.hex())
        return False

    def dead_time(self, client: ClientProxy) -> float:
        """Silence after which ``client`` is dead: its hard liveliness, else the agent's."""
        return client.hard_liveliness or self.client_dead_time

    def quiet_limit(self, client: ClientProxy) -> float:
        """Silence after which something happens to ``client``: its dead time, or its expiry if
        that comes first (the timer is set for it)."""
        dead_time = self.dead_time(client)
        expire_time = self.client_expire_time
        return expire_time if expire_time and expire_time < dead_time else dead_time

    def retirement(self, client: ClientProxy, now: float) -> Tuple[str, float]:
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

    def _unbind(self, client: ClientProxy) -> None:
        place = (client.link, client.endpoint)
        if self.endpoints.get(place) == client.key:
            del self.endpoints[place]
        closed = self.table.closed_endpoints
        if closed.get(place) == client.key:
            del closed[place]

    def reset_streams(self, client: ClientProxy) -> None:
        if client.fast is not None:  # first: it frees (and uncharges) what C acknowledged
            client.fast.drop(client)
        self.budget.charge(client, -client.stream_bytes())
        client.reset_streams()

    def delete_client(self, client: ClientProxy) -> None:
        budget = self.budget
        budget.queued_total -= client.queued_bytes  # its reader queues go with its objects
        if client.fast is not None:  # before any of its publishers is destroyed
            client.fast.drop(client)
        self.objects.delete_all(client)
        # Everything it held is garbage now: give its bytes back to the agent's budget (and
        # count nothing more for it: see MemoryBudget.charge), and the heap's free pages to the
        # system at the next tick if that was much (a flood's sessions expiring).
        if client.buffered + client.queued_bytes > TRIM_AFTER_BYTES:
            budget.trim_due = True
        budget.charge(client, -client.buffered)
        client.alive = False
        client.queued_bytes = 0
        client.parked = None
        self._unbind(client)
        if self.clients.get(client.key) is client:
            del self.clients[client.key]
            self._leave_host(client)
        self.stats.clients_deleted += 1
        if self.state is not None:
            self.state.client_deleted(client)
        if self.timelines.pending:
            self.timelines.forget(client)
        log.info("client %s deleted", client.key.hex())

    def reply_info(self, link: Link, endpoint: Hashable, header, request, impl_status: int) -> None:
        self.output.send_raw(link, endpoint, self.info_message(
            link, header.session_id, header.stream_id, header.seq, header.key, request,
            impl_status))

    def info_message(self, link: Optional[Link], session_id: int, stream_id: int, seq: int,
                     key: Optional[bytes], request: GetInfo, impl_status: int) -> bytes:
        """The INFO answering a GET_INFO, encoded once per distinct question: pings repeat the
        same one, and encoding an INFO is most of what answering it costs (~12 of 17 µs)."""
        cache_key = (link, session_id, stream_id, seq, key, request.request_id, request.object_id,
                     impl_status)
        message = self._info_cache.get(cache_key)
        if message is None:
            locators = getattr(link, "info_locators", ()) if link is not None else ()
            message = encode_message(session_id, stream_id, seq, key,
                                     [_info(request, impl_status, locators)])
            if len(self._info_cache) >= INFO_CACHE_SIZE:
                self._info_cache.clear()
            self._info_cache[cache_key] = message
        return message


def _info(request: GetInfo, impl_status: int, locators=()) -> Info:
    # The eProsima agent ignores the mask and object id and always reports both parts.
    return Info(request.request_id, request.object_id, C.STATUS_OK, impl_status,
                locators=list(locators))


def _participants(client: ClientProxy) -> list:
    """The signatures (xrce.agent.engine.reuse) of the client's participants: equal for the same
    node created again, whatever the key or object ids."""
    return [entry.signature for entry in client.objects.values()
            if entry.kind == C.OBJK_PARTICIPANT]


def _host_text(host) -> str:
    if isinstance(host, tuple):  # (link name, serial device)
        return "%s %s" % host[:2]
    return str(host)


class HostRecord:
    """The clients of one host (``client_host``), and when the latest new one was created."""

    __slots__ = ("members", "born_at")

    def __init__(self):
        self.members: Set[ClientProxy] = set()
        self.born_at = -math.inf


def client_host(link: Link, endpoint: Hashable) -> Hashable:
    """Where a client speaks from, as far as the agent can tell boards apart: the IP address of a
    UDP or TCP endpoint (several boards behind one NAT share it), the device of a serial one
    (several boards on one bus share it)."""
    address = endpoint_address(endpoint)
    if address is not None:
        return address
    name = getattr(link, "name", "link")
    if isinstance(endpoint, tuple) and endpoint:
        return (name, endpoint[0])
    return (name, endpoint)


def client_origin(client: ClientProxy) -> ClientOrigin:
    """What a middleware naming boards per board matches a client on (``ClientOrigin``): from
    its host, which a restored client has before its link is known."""
    host = client.host
    if isinstance(host, (ipaddress.IPv4Address, ipaddress.IPv6Address)):
        return ClientOrigin(client.key, address=host)
    if isinstance(host, tuple) and len(host) == 2 and isinstance(host[1], str):
        return ClientOrigin(client.key, device=host[1])
    return ClientOrigin(client.key)


def _hard_liveliness(properties) -> Optional[float]:
    for name, value in properties or ():
        if name == "uxr_hl":
            try:
                return int(value) / 1000.0 or None
            except ValueError:
                return None
    return None
