"""The agent's protocol engine: sessions, streams, object trees and data delivery (XRCE-WIRE.md §1–§10, §12).

Transport servers hand every whole XRCE message to ``Agent.receive(link, endpoint, data)``; replies
leave through ``link.send(endpoint, bytes)``. The engine never blocks and never raises out of
``receive``: a malformed message is counted, logged at debug level with its hex and dropped without
touching any other client. Everything runs on one asyncio loop; ``Agent.run()`` does the periodic
work (HEARTBEATs while output is unacknowledged, liveliness, paced READ_DATA delivery).

What a client's objects map onto is the middleware's business (``xrce.agent.middleware``); the engine
keeps the XRCE view: ids, parents, REUSE/REPLACE signatures and the READ_DATA state of each reader.
"""

from __future__ import annotations

import asyncio
import logging
import os
import time
from collections import deque
from dataclasses import dataclass, fields
from typing import Any, Callable, Deque, Dict, Hashable, Optional, Protocol, Set, Tuple

from xrce import constants as C, names as wire_names
from xrce.agent import xmlrep
from xrce.agent.middleware import (
    EndpointQosSpec, EntityKey, Middleware, MiddlewareError, ServiceSpec, TopicSpec, TypeNotReady,
)
from xrce.errors import DecodeError
from xrce.message import decode_header, header_size, iter_submessages
from xrce.objects import PARENT_KIND, with_kind
from xrce.streams import (
    InputBestEffortStream, InputReliableStream, OutputBestEffortStream, OutputReliableStream,
    is_reliable,
)
from xrce.submessages import (
    AckNack, Create, Data, Delete, Fragment, GetInfo, Heartbeat, Info, ReadData, Status,
    StatusAgent, TimestampReply, decode_payload, encode_message, sample_ids,
)

TRACE = 5
logging.addLevelName(TRACE, "TRACE")
log = logging.getLogger("xrce.agent")

STREAM_WINDOW = 16  # RELIABLE_STREAM_DEPTH of the eProsima agent, both directions
# Per-client quotas (defaults; ``Agent`` takes each as a constructor argument, the CLI as a flag).
MAX_REASSEMBLY = 256 * 1024  # a fragmented message larger than this is abandoned
MAX_OBJECTS_PER_CLIENT = 4096  # beyond this CREATE answers ERR_RESOURCES
MAX_OUTPUT_QUEUE_BYTES = 1024 * 1024  # samples waiting for one client; the oldest go first
MAX_CLIENTS = 1024  # CREATE_CLIENT of a new key beyond this evicts a dead client or is refused
QUOTA_LOG_INTERVAL = 1.0  # seconds between repeated quota log lines for one client and quota
# eProsima's UAGENT_CONFIG_CLIENT_DEAD_TIME; eProsima never destroys a silent client's entities
# unless it asked for hard liveliness (uxr_hl), hence expiry off by default.
CLIENT_DEAD_TIME = 30.0
CLIENT_EXPIRE_TIME = 0.0
MAX_QUEUE_KEEP_ALL = 1024  # reader queue bound when its QoS is KEEP_ALL
MIN_MTU = 24  # smaller CREATE_CLIENT mtu values would leave no room for a fragment chunk
HARD_LIVELINESS_PROBES = 3
MAX_DOMAIN_ID = 232  # the highest DDS domain id with the default RTPS port mapping
DEFAULT_PARTICIPANT_NAME = "MicroXRCEParticipant"

_GROUP_KINDS = (C.OBJK_PUBLISHER, C.OBJK_SUBSCRIBER)
_READER_KINDS = (C.OBJK_DATAREADER, C.OBJK_REQUESTER, C.OBJK_REPLIER)
_NO_OP_KINDS = (C.OBJK_TYPE, C.OBJK_QOSPROFILE, C.OBJK_APPLICATION)
_DURABILITY_FLAGS = ((C.QOS_PERSISTENT, "persistent"), (C.QOS_TRANSIENT, "transient"),
                     (C.QOS_TRANSIENT_LOCAL, "transient_local"))


class Link(Protocol):
    """A transport server as the engine sees it."""

    name: str

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
    status_lost: int = 0  # STATUS that found the reliable window full (eProsima drops them too)
    samples_in: int = 0
    samples_out: int = 0
    samples_overwritten: int = 0  # reader queue full: oldest sample dropped
    clients_created: int = 0
    clients_deleted: int = 0
    clients_dead: int = 0  # times a client went silent for client_dead_time
    clients_revived: int = 0  # dead clients that spoke again
    clients_expired: int = 0  # silent for client_expire_time: deleted with their entities
    clients_refused: int = 0  # CREATE_CLIENT beyond max_clients with no dead client to evict
    endpoints_closed: int = 0  # TCP connections / serial ports that went away under a session
    quota_objects: int = 0  # CREATE refused with ERR_RESOURCES
    quota_output_dropped: int = 0  # samples dropped because a client's output queue was full

    def as_dict(self) -> Dict[str, int]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


class ReadRequest:
    """An active READ_DATA: where to deliver and when to stop."""

    __slots__ = ("request_id", "stream_id", "remaining", "deadline", "rate", "tokens", "refilled")

    def __init__(self, request_id: int, stream_id: int, remaining: Optional[int],
                 deadline: Optional[float], rate: int, now: float):
        self.request_id = request_id
        self.stream_id = stream_id
        self.remaining = remaining  # None = unlimited
        self.deadline = deadline
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
    signature: Tuple[int, bytes, int]  # (format, representation bytes, tail) for REUSE
    topic: Optional[int] = None  # the topic object a writer/reader uses
    topic_spec: Optional[TopicSpec] = None
    reader: Optional[ReaderState] = None
    samples: int = 0  # written into the middleware (writers) or delivered to the client (readers)
    sample_bytes: int = 0


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
        self.queued_bytes = 0  # sample bytes waiting in this client's reader queues
        self.quota_logged: Dict[str, float] = {}
        self.objects: Dict[int, ObjectEntry] = {}
        self.in_best_effort: Dict[int, InputBestEffortStream] = {}
        self.in_reliable: Dict[int, InputReliableStream] = {}
        self.out_best_effort: Dict[int, OutputBestEffortStream] = {}
        self.out_reliable: Dict[int, OutputReliableStream] = {}
        self.reassembly: Dict[int, bytearray] = {}
        self.blocked_readers: Set[int] = set()
        self.alive = True  # False once deleted: late middleware callbacks are ignored
        # While a CREATE waits for its type to be built: the messages to process afterwards, in
        # order, starting with the rest of the one that held the CREATE. None when not parked.
        self.parked: Optional[list] = None
        # Per-client counters for xrce.agent.observability; plain ints so the hot path stays cheap.
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

    def entity(self, object_id: int) -> EntityKey:
        return (self.key_int, object_id)

    def reset_streams(self) -> None:
        self.in_best_effort.clear()
        self.in_reliable.clear()
        self.out_best_effort.clear()
        self.out_reliable.clear()
        self.reassembly.clear()
        self.blocked_readers.clear()


class _Parked(Exception):
    """A CREATE needs a type that is being built: this client's processing waits for ``future``."""

    def __init__(self, future):
        super().__init__()
        self.future = future


# Messages a parked client may queue while its type builds; more are dropped and counted.
MAX_PARKED_MESSAGES = 512

class Agent:
    def __init__(self, middleware: Middleware, *, refs: Optional[Dict[str, str]] = None,
                 heartbeat_period: float = 0.2, client_dead_time: float = CLIENT_DEAD_TIME,
                 client_expire_time: float = CLIENT_EXPIRE_TIME,
                 max_objects_per_client: Optional[int] = None,
                 max_reassembly_bytes: Optional[int] = None,
                 max_output_queue_bytes: int = MAX_OUTPUT_QUEUE_BYTES,
                 max_clients: int = MAX_CLIENTS,
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
        self.loop = loop
        self.stats = AgentStats()
        self.clock: Callable[[], float] = time.monotonic  # tests may substitute a fake clock
        self.clients: Dict[bytes, ClientProxy] = {}
        self.endpoints: Dict[Tuple[Any, Hashable], bytes] = {}  # (link, endpoint) → key, sessions ≥ 0x81
        self._started = False
        self._resumable: Deque[ClientProxy] = deque()  # parked clients whose build finished
        # Called as tap(direction, link, endpoint, message) for every message in ("in") and out
        # ("out"), e.g. by a capture file (xrce.agent.observability); None costs one test.
        self.tap: Optional[Callable[[str, Any, Hashable, bytes], None]] = None

    # ------------------------------------------------------------------ public entry points --

    def receive(self, link: Link, endpoint: Hashable, data) -> None:
        """Handle one whole XRCE message from ``endpoint`` on ``link``. Never raises."""
        data = bytes(data)
        self.stats.messages_in += 1
        self.stats.bytes_in += len(data)
        if self.tap is not None:
            self.tap("in", link, endpoint, data)
        try:
            self._receive(link, endpoint, data)
        except DecodeError as exc:
            self.stats.decode_errors += 1
            self.stats.dropped += 1
            log.debug("dropped malformed message from %s %r (%s): %s", link.name, endpoint, exc,
                      data.hex())
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
        while self._resumable:
            client = self._resumable.popleft()
            pending, client.parked = client.parked, None
            if not client.alive or pending is None:
                continue
            while pending:
                data, start, stream_id = pending.pop(0)
                try:
                    self._process_message(client, data, start, stream_id)
                except Exception:
                    self.stats.handler_errors += 1
                    log.debug("resumed message of client %s failed", client.key.hex(), exc_info=True)
                if client.parked is not None:  # parked again by another type being built
                    client.parked.extend(pending)
                    break

    def tick(self) -> None:
        """One round of periodic work: HEARTBEATs, liveliness probes, paced delivery."""
        self._resume_parked()
        now = self.clock()
        for client in list(self.clients.values()):
            try:
                self._tick_client(client, now)
            except Exception:
                self.stats.handler_errors += 1
                log.debug("periodic work for client %s failed", client.key.hex(), exc_info=True)

    async def run(self) -> None:
        if self.loop is None:
            self.loop = asyncio.get_running_loop()
        if not self._started:
            self._started = True
            await self.middleware.start()
        while True:
            await asyncio.sleep(self.heartbeat_period)
            self.tick()

    async def close(self) -> None:
        for client in list(self.clients.values()):
            self._delete_client(client)
        await self.middleware.close()

    def endpoint_closed(self, link: Link, endpoint: Hashable) -> None:
        """A TCP connection or serial port went away: sessions identified by that endpoint need a
        new CREATE_CLIENT (as a new UDP socket would). Their objects stay for REUSE; liveliness
        decides when a client that never comes back is forgotten."""
        key = self.endpoints.pop((link, endpoint), None)
        for client in self.clients.values():
            if client.link is link and client.endpoint == endpoint:
                self.stats.endpoints_closed += 1
                log.info("client %s: %s %r closed; its entities are kept until it returns or expires",
                         client.key.hex(), link.name, endpoint)
        if key is not None and key not in self.clients:
            log.debug("endpoint %s %r was mapped to unknown client %s", link.name, endpoint, key.hex())

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
        duplicates = stream.duplicates
        try:
            for message in stream.receive(seq, data):
                self._process_reliable_message(client, stream_id, message)
        finally:
            self.stats.duplicates += stream.duplicates - duplicates
            client.duplicates += stream.duplicates - duplicates
            if client.alive:  # every reliable message is acknowledged, duplicates included
                self._send_acknack(client, stream)

    def _process_reliable_message(self, client: ClientProxy, stream_id: int, message: bytes) -> None:
        size = header_size(message[0])
        try:
            self._process_message(client, message, size, stream_id)
        except DecodeError:
            self.stats.decode_errors += 1
            client.decode_errors += 1
            log.debug("malformed reliable message from client %s: %s", client.key.hex(), message.hex())

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
        answered = False
        for sub_id, flags, start, end in iter_submessages(data, header.size):
            if sub_id == C.DELETE:
                payload = decode_payload(sub_id, flags, data, start, end)
                if payload.object_id == C.OBJECTID_CLIENT:
                    self._send_raw(link, endpoint, encode_message(
                        header.session_id, header.stream_id, header.seq, header.key,
                        [Status(payload.request_id, payload.object_id)]))
                    answered = True
            elif sub_id == C.GET_INFO:
                payload = decode_payload(sub_id, flags, data, start, end)
                self._reply_info(link, endpoint, header, payload, 0)
                answered = True
        if not answered:
            self.stats.dropped += 1

    def _process_message(self, client: ClientProxy, data: bytes, start: int, stream_id: int) -> None:
        """Submessages in order; the first failing one stops the rest of the message."""
        if client.parked is not None and stream_id != C.STREAM_NONE:
            if len(client.parked) >= MAX_PARKED_MESSAGES:
                self.stats.dropped += 1
            else:
                client.parked.append((data, start, stream_id))
            return
        try:
            for sub_id, flags, sub_start, sub_end in iter_submessages(data, start):
                if not client.alive:
                    return
                try:
                    handled = self._handle_submessage(client, stream_id, data, sub_id, flags,
                                                      sub_start, sub_end)
                except _Parked as parked:
                    # Resume at this CREATE's submessage header once the build is done.
                    client.parked = [(data, sub_start - 4, stream_id)]
                    parked.future.add_done_callback(lambda _, c=client: self._build_finished(c))
                    return
                if not handled:
                    return
        except DecodeError as exc:
            self.stats.decode_errors += 1
            client.decode_errors += 1
            log.debug("client %s: malformed submessage (%s) in %s", client.key.hex(), exc, data.hex())

    def _handle_submessage(self, client: ClientProxy, stream_id: int, data: bytes, sub_id: int,
                           flags: int, start: int, end: int) -> bool:
        if sub_id == C.WRITE_DATA:
            if flags & C.FLAG_FORMAT_MASK != C.FORMAT_DATA:
                return False
            request_id, object_id = sample_ids(data, start, end)
            return self._write_data(client, request_id, object_id, data[start + 4:end])
        if sub_id == C.FRAGMENT:
            return self._fragment(client, stream_id, data, flags, start, end)
        if sub_id not in _HANDLED:
            return False  # CREATE_CLIENT in session, STATUS, INFO, DATA, … stop the message
        payload = decode_payload(sub_id, flags, data, start, end)
        if sub_id == C.CREATE:
            self._create(client, payload, stream_id)
        elif sub_id == C.DELETE:
            self._delete(client, payload, stream_id)
        elif sub_id == C.READ_DATA:
            self._read_data(client, payload)
        elif sub_id == C.ACKNACK:
            self._on_acknack(client, payload)
        elif sub_id == C.HEARTBEAT:
            self._on_heartbeat(client, payload)
        elif sub_id == C.GET_INFO:
            self._send_stream0(client, self._info(payload, 1))
        elif sub_id == C.TIMESTAMP:
            receive_ns = time.time_ns()
            client.timestamp_skew_ns = receive_ns - payload.ns()
            self._send_stream0(client, TimestampReply(time.time_ns(), receive_ns, payload.ns()))
        elif sub_id == C.RESET:
            client.reset_streams()
        return True

    # ------------------------------------------------------------------ sessions --

    def _create_client(self, link: Link, endpoint: Hashable, header, request) -> None:
        session_id = request.session_id
        reply_key = bytes(request.client_key) if session_id < C.SESSION_ID_WITHOUT_KEY_MASK else None
        status = C.STATUS_OK
        if request.client_key == b"\x00\x00\x00\x00" or request.cookie != C.XRCE_COOKIE:
            status = C.STATUS_ERR_INVALID_DATA
        elif request.version[0] != C.XRCE_VERSION_MAJOR:
            status = C.STATUS_ERR_INCOMPATIBLE
        elif not self._room_for_client(bytes(request.client_key), link, endpoint, session_id):
            status = C.STATUS_ERR_RESOURCES
        if status == C.STATUS_OK:
            self._establish(link, endpoint, request)
        self._send_raw(link, endpoint, encode_message(session_id, C.STREAM_NONE, 0, reply_key,
                                                      [StatusAgent(status)]))

    def _establish(self, link: Link, endpoint: Hashable, request) -> None:
        key = bytes(request.client_key)
        session_id = request.session_id
        now = self.clock()
        if session_id >= C.SESSION_ID_WITHOUT_KEY_MASK:
            bound = self.endpoints.get((link, endpoint))
            if bound is not None and bound != key and bound in self.clients:
                log.info("endpoint %s %r re-bound from client %s to %s", link.name, endpoint,
                         bound.hex(), key.hex())
                self._delete_client(self.clients[bound])
        client = self.clients.get(key)
        if client is not None and client.session_id == session_id:
            client.reset_streams()  # session restart: objects survive for REUSE
            self._unbind(client)
            client.link, client.endpoint, client.last_seen, client.probes = link, endpoint, now, 0
            client.dead = False
            log.info("client %s session 0x%02X restarted on %s %r, %d objects kept for reuse",
                     key.hex(), session_id, link.name, endpoint, len(client.objects))
        else:
            if client is not None:
                log.info("client %s replaced (session 0x%02X → 0x%02X)", key.hex(),
                         client.session_id, session_id)
                self._delete_client(client)
            mtu = request.mtu if request.mtu is not None else 508
            client = ClientProxy(key, session_id, mtu, link, endpoint, now,
                                 _hard_liveliness(request.properties))
            self.clients[key] = client
            self.stats.clients_created += 1
            log.info("client %s session 0x%02X created on %s %r (mtu %d)", key.hex(), session_id,
                     link.name, endpoint, client.mtu)
        if session_id >= C.SESSION_ID_WITHOUT_KEY_MASK:
            self.endpoints[(link, endpoint)] = key

    def _room_for_client(self, key: bytes, link: Link, endpoint: Hashable, session_id: int) -> bool:
        """True if a session for ``key`` fits under max_clients, evicting the longest-silent dead
        client if that is what it takes (a hostile or buggy peer must not grow the table forever)."""
        if key in self.clients or len(self.clients) < self.max_clients:
            return True
        if session_id >= C.SESSION_ID_WITHOUT_KEY_MASK and self.endpoints.get((link, endpoint)) \
                in self.clients:
            return True  # re-binding this endpoint deletes its current client first
        now = self.clock()
        silent = [c for c in self.clients.values()
                  if now - c.last_seen >= (c.hard_liveliness or self.client_dead_time)]
        if silent:
            victim = min(silent, key=lambda c: c.last_seen)
            log.warning("%d clients: evicting dead client %s to admit %s", len(self.clients),
                        victim.key.hex(), key.hex())
            self._delete_client(victim)
            return True
        self.stats.clients_refused += 1
        log.warning("%d clients, none dead: refusing client %s (max_clients)", len(self.clients),
                    key.hex())
        return False

    def _quota_warning(self, client: ClientProxy, quota: str, message: str, *args) -> None:
        now = self.clock()
        last = client.quota_logged.get(quota)
        if last is None or now - last >= QUOTA_LOG_INTERVAL:
            client.quota_logged[quota] = now
            log.warning("client %s: " + message, client.key.hex(), *args)

    def _unbind(self, client: ClientProxy) -> None:
        if self.endpoints.get((client.link, client.endpoint)) == client.key:
            del self.endpoints[(client.link, client.endpoint)]

    def _delete_client(self, client: ClientProxy) -> None:
        for object_id in [oid for oid, e in client.objects.items() if e.parent is None]:
            if object_id in client.objects:
                self._delete_object(client, object_id)
        for object_id in list(client.objects):
            self._delete_object(client, object_id)
        client.alive = False
        self._unbind(client)
        if self.clients.get(client.key) is client:
            del self.clients[client.key]
        self.stats.clients_deleted += 1
        log.info("client %s deleted", client.key.hex())

    def _reply_info(self, link: Link, endpoint: Hashable, header, request, impl_status: int) -> None:
        self._send_raw(link, endpoint, encode_message(
            header.session_id, header.stream_id, header.seq, header.key,
            [self._info(request, impl_status, getattr(link, "info_locators", ()))]))

    @staticmethod
    def _info(request: GetInfo, impl_status: int, locators=()) -> Info:
        # The eProsima agent ignores the mask and object id and always reports both parts.
        return Info(request.request_id, request.object_id, C.STATUS_OK, impl_status,
                    locators=list(locators))

    # ------------------------------------------------------------------ objects --

    def _status(self, client: ClientProxy, request, status: int, stream_id: int) -> None:
        reply_stream = C.BUILTIN_RELIABLE if is_reliable(stream_id) else C.BUILTIN_BEST_EFFORT
        if not self._send_on_stream(client, reply_stream,
                                    Status(request.request_id, request.object_id, status)):
            self.stats.status_lost += 1

    def _create(self, client: ClientProxy, request: Create, stream_id: int) -> None:
        kind = request.kind
        if kind in _NO_OP_KINDS:
            self._status(client, request, C.STATUS_OK, stream_id)  # eProsima creates nothing here
            return
        if kind not in _CREATABLE:
            raise DecodeError("CREATE of object kind %d" % kind)
        object_id = with_kind(request.object_id, kind)
        signature = (request.fmt, bytes(request.representation_bytes()), request.tail_id)
        existing = client.objects.get(object_id)
        if existing is not None:
            if not request.reuse and not request.replace:
                self._status(client, request, C.STATUS_ERR_ALREADY_EXISTS, stream_id)
                return
            if request.reuse:
                if existing.signature == signature:
                    self._status(client, request, C.STATUS_OK_MATCHED, stream_id)
                    return
                if not request.replace:
                    self._status(client, request, C.STATUS_ERR_MISMATCH, stream_id)
                    return
            self._delete_object(client, object_id)
        if len(client.objects) >= (self.max_objects_per_client or MAX_OBJECTS_PER_CLIENT):
            self.stats.quota_objects += 1
            self._quota_warning(client, "objects", "%d objects, quota reached: CREATE of 0x%04X "
                                "refused (ERR_RESOURCES)", len(client.objects), object_id)
            self._status(client, request, C.STATUS_ERR_RESOURCES, stream_id)
            return
        parent = None if kind == C.OBJK_PARTICIPANT else with_kind(request.tail_id, PARENT_KIND[kind])
        if parent is not None and parent not in client.objects:
            self._status(client, request, C.STATUS_ERR_UNKNOWN_REFERENCE, stream_id)
            return
        entry = ObjectEntry(object_id, kind, parent, signature)
        try:
            status = self._build(client, request, entry)
        except TypeNotReady as pending:
            raise _Parked(pending.future)
        except (MiddlewareError, xmlrep.XmlRepresentationError) as exc:
            log.warning("client %s: creating %s 0x%04X failed: %s", client.key.hex(),
                        wire_names.OBJECT_KIND_NAMES.get(kind), object_id, exc)
            status = C.STATUS_ERR_DDS_ERROR
        if status == C.STATUS_OK:
            client.objects[object_id] = entry
        self._status(client, request, status, stream_id)

    def _reference(self, request: Create) -> str:
        try:
            return self.refs[request.representation]
        except KeyError:
            raise MiddlewareError("no profile called %r" % request.representation) from None

    def _xml_text(self, request: Create) -> str:
        if request.fmt == C.REPRESENTATION_BY_REFERENCE:
            return self._reference(request)
        return request.representation

    def _build(self, client: ClientProxy, request: Create, entry: ObjectEntry) -> int:
        """Create the middleware entity behind ``entry``; a status other than OK if not possible."""
        kind, fmt, rep = request.kind, request.fmt, request.representation
        key = client.entity(entry.object_id)
        mw = self.middleware
        if kind == C.OBJK_PARTICIPANT:
            domain = request.tail_id
            if fmt == C.REPRESENTATION_IN_BINARY:
                name = rep.name or DEFAULT_PARTICIPANT_NAME
                profile_domain = None
            else:
                parsed = xmlrep.parse_participant(self._xml_text(request))
                name = parsed.name or (rep if fmt == C.REPRESENTATION_BY_REFERENCE else "") \
                    or DEFAULT_PARTICIPANT_NAME
                profile_domain = parsed.domain_id
            if domain == 255:
                if fmt == C.REPRESENTATION_BY_REFERENCE:
                    domain = profile_domain or 0
                else:
                    domain = _domain_override()
            if not 0 <= domain <= MAX_DOMAIN_ID:
                # Fast DDS cannot compute ports beyond it and aborts the whole process (found by
                # bench/fuzz_live_agent.py): refuse here, as a DDS error, before it gets there.
                raise MiddlewareError("domain id %d is not in 0..%d" % (domain, MAX_DOMAIN_ID))
            mw.create_participant(key, domain, name)
        elif kind == C.OBJK_TOPIC:
            if fmt == C.REPRESENTATION_IN_BINARY:
                spec = TopicSpec(rep.topic_name, rep.type_name or rep.type_reference or "")
            else:
                spec = xmlrep.parse_topic(self._xml_text(request))
            entry.topic_spec = spec
            mw.create_topic(key, client.entity(entry.parent), spec)
        elif kind in _GROUP_KINDS:
            if fmt == C.REPRESENTATION_BY_REFERENCE:
                return C.STATUS_ERR_INVALID_DATA  # groups have no by-reference representation
            if fmt == C.REPRESENTATION_AS_XML_STRING:
                xmlrep.check_group(rep, "publisher" if kind == C.OBJK_PUBLISHER else "subscriber")
            if kind == C.OBJK_PUBLISHER:
                mw.create_publisher(key, client.entity(entry.parent))
            else:
                mw.create_subscriber(key, client.entity(entry.parent))
        elif kind in (C.OBJK_DATAWRITER, C.OBJK_DATAREADER):
            writer = kind == C.OBJK_DATAWRITER
            if fmt == C.REPRESENTATION_IN_BINARY:
                topic = with_kind(rep.topic_id, C.OBJK_TOPIC)
                if topic not in client.objects:
                    return C.STATUS_ERR_UNKNOWN_REFERENCE
                qos = _binary_qos(rep.qos, writer)
            else:
                parsed = xmlrep.parse_endpoint(self._xml_text(request), writer)
                topic = self._find_topic(client, entry.parent, parsed.topic.name)
                if topic is None:
                    raise MiddlewareError("no topic %r in this participant" % parsed.topic.name)
                qos = parsed.qos
            entry.topic = topic
            entry.topic_spec = client.objects[topic].topic_spec
            if writer:
                mw.create_datawriter(key, client.entity(entry.parent), client.entity(topic), qos)
            else:
                entry.reader = ReaderState(_queue_bound(qos))
                mw.create_datareader(key, client.entity(entry.parent), client.entity(topic), qos,
                                     self._sample_callback(client, entry.object_id))
        elif kind in (C.OBJK_REQUESTER, C.OBJK_REPLIER):
            if fmt == C.REPRESENTATION_IN_BINARY:
                spec = ServiceSpec(rep.service_name, rep.request_type, rep.reply_type,
                                   rep.request_topic, rep.reply_topic)
            else:
                spec = xmlrep.parse_service(
                    self._xml_text(request), "requester" if kind == C.OBJK_REQUESTER else "replier")
            qos = EndpointQosSpec()
            entry.reader = ReaderState(_queue_bound(qos))
            if kind == C.OBJK_REQUESTER:
                mw.create_requester(key, client.entity(entry.parent), spec, qos,
                                    self._reply_callback(client, entry.object_id))
            else:
                mw.create_replier(key, client.entity(entry.parent), spec, qos,
                                  self._request_callback(client, entry.object_id))
        return C.STATUS_OK

    @staticmethod
    def _find_topic(client: ClientProxy, group: int, name: str) -> Optional[int]:
        participant = client.objects[group].parent
        for object_id, entry in client.objects.items():
            if entry.kind == C.OBJK_TOPIC and entry.parent == participant and \
                    entry.topic_spec is not None and entry.topic_spec.name == name:
                return object_id
        return None

    def _delete(self, client: ClientProxy, request: Delete, stream_id: int) -> None:
        if request.object_id == C.OBJECTID_CLIENT:
            self._delete_client(client)
            self._send_raw(client.link, client.endpoint, encode_message(
                client.session_id, C.STREAM_NONE, 0, client.header_key,
                [Status(request.request_id, request.object_id)]))
            return
        if request.object_id not in client.objects:
            self._status(client, request, C.STATUS_ERR_UNKNOWN_REFERENCE, stream_id)
            return
        self._delete_object(client, request.object_id)
        self._status(client, request, C.STATUS_OK, stream_id)

    def _delete_object(self, client: ClientProxy, object_id: int) -> None:
        """Delete an object after everything that depends on it (children, a topic's users)."""
        dependents = [oid for oid, e in client.objects.items()
                      if oid != object_id and (e.parent == object_id or e.topic == object_id)]
        for dependent in dependents:
            if dependent in client.objects:
                self._delete_object(client, dependent)
        entry = client.objects.pop(object_id, None)
        if entry is None:
            return
        client.blocked_readers.discard(object_id)
        if entry.reader is not None:
            client.queued_bytes -= sum(len(sample) for sample in entry.reader.queue)
            entry.reader.queue.clear()
        try:
            self.middleware.delete(client.entity(object_id))
        except Exception:
            log.warning("middleware failed to delete %r", client.entity(object_id), exc_info=True)

    # ------------------------------------------------------------------ data --

    def _write_data(self, client: ClientProxy, request_id: int, object_id: int, data: bytes) -> bool:
        entry = client.objects.get(object_id)
        if entry is None:
            return False
        key = client.entity(entry.object_id)
        self.stats.samples_in += 1
        entry.samples += 1
        entry.sample_bytes += len(data)
        if entry.kind == C.OBJK_DATAWRITER:
            return bool(self.middleware.write(key, data))
        if entry.kind == C.OBJK_REQUESTER:
            correlation_id = (entry.object_id << 16) + request_id
            return bool(self.middleware.write_request(key, correlation_id, data))
        if entry.kind == C.OBJK_REPLIER:
            if len(data) < 24:
                return False
            return bool(self.middleware.write_reply(key, data[:24], data[24:]))
        return False

    def _sample_callback(self, client: ClientProxy, object_id: int):
        def on_data(sample: bytes) -> None:
            self._enqueue(client, object_id, bytes(sample))
        return on_data

    def _request_callback(self, client: ClientProxy, object_id: int):
        def on_request(sample_identity: bytes, request: bytes) -> None:
            self._enqueue(client, object_id, bytes(sample_identity) + bytes(request))
        return on_request

    def _reply_callback(self, client: ClientProxy, object_id: int):
        def on_reply(correlation_id: int, reply: bytes) -> None:
            # The reply travels behind the BaseObjectRequest of the WRITE_DATA that asked (§6).
            request_id = correlation_id & 0xFFFF
            prefix = bytes((request_id >> 8, request_id & 0xFF, object_id >> 8, object_id & 0xFF))
            self._enqueue(client, object_id, prefix + bytes(reply))
        return on_reply

    def _enqueue(self, client: ClientProxy, object_id: int, payload: bytes) -> None:
        if not client.alive:
            return
        entry = client.objects.get(object_id)
        if entry is None or entry.reader is None:
            return
        queue = entry.reader.queue
        if queue.maxlen is not None and len(queue) == queue.maxlen:
            self.stats.samples_overwritten += 1
            client.queued_bytes -= len(queue[0])  # append() below pushes it out
        if client.queued_bytes + len(payload) > self.max_output_queue_bytes:
            dropped = 0
            while queue and client.queued_bytes + len(payload) > self.max_output_queue_bytes:
                client.queued_bytes -= len(queue.popleft())
                dropped += 1
            if client.queued_bytes + len(payload) > self.max_output_queue_bytes:
                dropped += 1  # other readers hold the space: the new sample is the one to go
                self.stats.quota_output_dropped += dropped
                self._quota_warning(client, "output", "output queue quota (%d bytes) full, "
                                    "sample for 0x%04X dropped", self.max_output_queue_bytes,
                                    object_id)
                return
            self.stats.quota_output_dropped += dropped
            self._quota_warning(client, "output", "output queue quota (%d bytes) full, %d oldest "
                                "samples of 0x%04X dropped", self.max_output_queue_bytes, dropped,
                                object_id)
        queue.append(payload)
        client.queued_bytes += len(payload)
        try:
            self._pump(client, entry)
        except Exception:
            self.stats.handler_errors += 1
            log.debug("delivering to reader 0x%04X failed", object_id, exc_info=True)

    def _read_data(self, client: ClientProxy, request: ReadData) -> None:
        entry = client.objects.get(request.object_id)
        if entry is None or entry.reader is None:
            # Failed READ_DATA is answered on the reliable built-in stream whatever it came on.
            self._status(client, request, C.STATUS_ERR_UNKNOWN_REFERENCE, C.BUILTIN_RELIABLE)
            return
        reader = entry.reader
        delivery = request.delivery
        now = self.clock()
        reader.active = None  # a new READ_DATA stops the previous one first
        client.blocked_readers.discard(entry.object_id)
        if delivery is None:
            remaining: Optional[int] = 1
            deadline = None
            rate = 0
        else:
            if request.stream_id == C.STREAM_NONE and delivery.max_samples == 0 and \
                    delivery.max_elapsed_time == 0 and delivery.max_bytes_per_second == 0 and \
                    delivery.min_pace_period == 0:
                return  # uxr_buffer_cancel_data
            remaining = None if delivery.max_samples == C.MAX_SAMPLES_UNLIMITED else delivery.max_samples
            deadline = now + delivery.max_elapsed_time if delivery.max_elapsed_time else None
            rate = delivery.max_bytes_per_second
        if remaining == 0:
            return
        reader.active = ReadRequest(request.request_id, request.stream_id, remaining, deadline, rate,
                                    now)
        self._pump(client, entry)

    def _pump(self, client: ClientProxy, entry: ObjectEntry) -> None:
        """Deliver queued samples while the active READ_DATA allows and the stream has room."""
        reader = entry.reader
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
                    break
                active.tokens -= len(sample)
            if not self._send_on_stream(client, active.stream_id,
                                        Data(active.request_id, entry.object_id, sample)):
                if active.rate:
                    active.tokens += len(sample)
                client.blocked_readers.add(entry.object_id)  # retried when an ACKNACK frees room
                break
            client.queued_bytes -= len(reader.queue.popleft())
            self.stats.samples_out += 1
            entry.samples += 1
            entry.sample_bytes += len(sample)
            if active.remaining is not None:
                active.remaining -= 1
                if active.remaining <= 0:
                    reader.active = None

    def _fragment(self, client: ClientProxy, stream_id: int, data: bytes, flags: int, start: int,
                  end: int) -> bool:
        if not is_reliable(stream_id):
            return False  # the agent only reassembles on reliable streams
        self.stats.fragments_in += 1
        buffer = client.reassembly.get(stream_id)
        if buffer is None:
            buffer = client.reassembly[stream_id] = bytearray(data[:header_size(data[0])])
        limit = self.max_reassembly_bytes or MAX_REASSEMBLY
        if len(buffer) + (end - start) > limit:
            del client.reassembly[stream_id]
            self.stats.reassembly_overflows += 1
            self._quota_warning(client, "reassembly", "reassembly on stream 0x%02X exceeds the "
                                "%d-byte quota, message abandoned", stream_id, limit)
            return False
        buffer += data[start:end]
        if flags & C.FLAG_LAST_FRAGMENT:
            del client.reassembly[stream_id]
            message = bytes(buffer)
            self._process_message(client, message, header_size(message[0]), stream_id)
        return True

    # ------------------------------------------------------------------ reliability --

    def _on_acknack(self, client: ClientProxy, acknack: AckNack) -> None:
        stream = client.out_reliable.get(acknack.stream_id)
        if stream is None:
            return
        now = self.clock()
        if client.heartbeat_sent_at is not None:
            client.rtt_s = now - client.heartbeat_sent_at
            client.heartbeat_sent_at = None
        now_ms = int(now * 1000)
        holdoff_ms = int(self.heartbeat_period * 1000) // 2
        for message in stream.on_acknack(acknack.first_unacked, acknack.nack_bitmap, now_ms,
                                         holdoff_ms):
            self.stats.retransmissions += 1
            client.retransmissions += 1
            self._send_client(client, message)
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
        for message in stream.on_heartbeat(heartbeat.first_unacked, heartbeat.last_unacked):
            self._process_reliable_message(client, stream_id, message)
        if client.alive:
            self._send_acknack(client, stream)

    def _send_acknack(self, client: ClientProxy, stream: InputReliableStream) -> None:
        first, bitmap = stream.acknack()
        self.stats.acknacks_out += 1
        self._send_stream0(client, AckNack(first, bitmap, stream.stream_id))

    def _tick_client(self, client: ClientProxy, now: float) -> None:
        dead_time = client.hard_liveliness or self.client_dead_time
        silent = now - client.last_seen
        if silent >= dead_time:
            if not client.dead:
                client.dead = True
                self.stats.clients_dead += 1
                log.info("client %s silent for %d ms: dead (no more HEARTBEATs)", client.key.hex(),
                         int(silent * 1000))
            if not client.hard_liveliness and self.client_expire_time and \
                    silent >= self.client_expire_time:
                self.stats.clients_expired += 1
                log.info("client %s silent for %d ms: expired, deleting its %d objects",
                         client.key.hex(), int(silent * 1000), len(client.objects))
                self._delete_client(client)
                return
            if client.hard_liveliness:
                if client.probes >= HARD_LIVELINESS_PROBES:
                    log.info("client %s missed %d liveliness probes", client.key.hex(), client.probes)
                    self._delete_client(client)
                    return
                client.probes += 1
                self._send_stream0(client, GetInfo(C.REQUEST_ID_INVALID, C.OBJECTID_CLIENT,
                                                   C.INFO_CONFIGURATION))
            return  # dead clients get no HEARTBEATs
        for stream in list(client.out_reliable.values()):
            span = stream.heartbeat()
            if span is not None:
                self.stats.heartbeats_out += 1
                client.heartbeat_sent_at = now
                self._send_stream0(client, Heartbeat(span[0], span[1], stream.stream_id))
        for object_id, entry in list(client.objects.items()):
            reader = entry.reader
            if reader is not None and reader.active is not None:
                if reader.queue:
                    self._pump(client, entry)
                elif reader.active.deadline is not None and now >= reader.active.deadline:
                    reader.active = None

    # ------------------------------------------------------------------ output --

    def _send_raw(self, link: Link, endpoint: Hashable, message: bytes) -> None:
        self.stats.messages_out += 1
        self.stats.bytes_out += len(message)
        if log.isEnabledFor(TRACE):
            self._trace("out", link, endpoint, message, header_size(message[0]))
        if self.tap is not None:
            self.tap("out", link, endpoint, message)
        link.send(endpoint, message)

    def _send_client(self, client: ClientProxy, message: bytes) -> None:
        client.messages_out += 1
        client.bytes_out += len(message)
        self._send_raw(client.link, client.endpoint, message)

    def _send_stream0(self, client: ClientProxy, payload) -> None:
        self._send_client(client, encode_message(
            client.session_id, C.STREAM_NONE, 0, client.header_key, [payload]))

    def _send_on_stream(self, client: ClientProxy, stream_id: int, payload) -> bool:
        """Send one submessage alone in a message on ``stream_id``.

        False only when a reliable window has no room (the caller decides whether to keep it);
        best-effort output larger than the mtu is dropped, counted, and reported as handled.
        """
        if stream_id == C.STREAM_NONE:
            self._send_stream0(client, payload)
            return True
        message = encode_message(client.session_id, stream_id, 0, client.header_key, [payload])
        if not is_reliable(stream_id):
            if len(message) > client.mtu:
                self.stats.oversize_dropped += 1
                log.warning("client %s: %d-byte best-effort message exceeds mtu %d, dropped",
                            client.key.hex(), len(message), client.mtu)
                return True
            stream = client.out_best_effort.get(stream_id)
            if stream is None:
                stream = client.out_best_effort[stream_id] = OutputBestEffortStream(stream_id)
            self._send_client(client, _with_seq(message, stream.next_seq()))
            return True
        stream = client.out_reliable.get(stream_id)
        if stream is None:
            stream = client.out_reliable[stream_id] = OutputReliableStream(stream_id, STREAM_WINDOW)
        if len(message) <= client.mtu:
            seq = stream.next_seq()
            if seq is None:
                return False
            message = _with_seq(message, seq)
            stream.commit(seq, message)
            self._send_client(client, message)
            return True
        return self._send_fragmented(client, stream, message)

    def _send_fragmented(self, client: ClientProxy, stream: OutputReliableStream,
                         message: bytes) -> bool:
        head = header_size(message[0])
        inner = message[head:]
        chunk = client.mtu - head - 4
        count = (len(inner) + chunk - 1) // chunk
        if count > stream.history:
            self.stats.oversize_dropped += 1
            log.warning("client %s: %d-byte message needs %d fragments, more than the window",
                        client.key.hex(), len(message), count)
            return True
        if stream.history - stream.in_flight() < count:
            return False
        for index in range(count):
            last = index == count - 1
            flags = C.FLAG_LITTLE_ENDIAN | (C.FLAG_LAST_FRAGMENT if last else 0)
            seq = stream.next_seq()
            fragment = encode_message(client.session_id, stream.stream_id, seq, client.header_key,
                                      [Fragment(inner[index * chunk:(index + 1) * chunk], flags)])
            stream.commit(seq, fragment)
            self.stats.fragments_out += 1
            self._send_client(client, fragment)
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


_HANDLED = frozenset((C.CREATE, C.DELETE, C.READ_DATA, C.ACKNACK, C.HEARTBEAT, C.GET_INFO,
                      C.TIMESTAMP, C.RESET))
_CREATABLE = frozenset(PARENT_KIND) | {C.OBJK_PARTICIPANT}


def _with_seq(message: bytes, seq: int) -> bytes:
    return message[:2] + bytes((seq & 0xFF, seq >> 8)) + message[4:]


def _binary_qos(qos, writer: bool) -> EndpointQosSpec:
    if qos is None:
        return xmlrep.WRITER_DEFAULTS if writer else xmlrep.READER_DEFAULTS
    durability = "volatile"
    for flag, name in _DURABILITY_FLAGS:
        if qos.flags & flag:
            durability = name
            break
    return EndpointQosSpec(reliable=qos.reliable, keep_last=qos.keep_last,
                           depth=qos.history_depth or 1, durability=durability)


def _queue_bound(qos: EndpointQosSpec) -> int:
    return max(1, qos.depth) if qos.keep_last else MAX_QUEUE_KEEP_ALL


def _domain_override() -> int:
    value = os.environ.get("XRCE_DOMAIN_ID_OVERRIDE")
    try:
        return int(value) if value is not None else 0
    except ValueError:
        log.warning("XRCE_DOMAIN_ID_OVERRIDE=%r is not a number, using domain 0", value)
        return 0


def _hard_liveliness(properties) -> Optional[float]:
    for name, value in properties or ():
        if name == "uxr_hl":
            try:
                return int(value) / 1000.0 or None
            except ValueError:
                return None
    return None


__all__ = ["Agent", "AgentStats", "ClientProxy", "Link", "TRACE"]
