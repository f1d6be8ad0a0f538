"""How sessions begin and end (XRCE-WIRE.md §3, §4): ``Sessions``, one part of
``xrce.agent.engine.agent.Agent``, answers CREATE_CLIENT and GET_INFO, binds sessions to endpoints,
enforces ``max_clients``, says when a client is dead or certainly gone and deletes clients, and
tells the operator of traffic for sessions it does not know.
"""

from __future__ import annotations

import logging
from typing import Any, Callable, Dict, Hashable, Optional, Tuple

from xrce.wire import constants as C
from xrce.agent.engine.admission import RefusalLog
from xrce.agent.engine.scheduler import NEVER
from xrce.agent.engine.client import ClientProxy, _hard_liveliness, client_host
from xrce.agent.engine.clients import ClientTable, HostRecord, MemoryBudget
from xrce.agent.engine.limits import (
    DEFAULT_MTU, INFO_CACHE_SIZE, SUCCESSOR_CHECK_S, SUCCESSOR_WATCH_S, TRIM_AFTER_BYTES,
)
from xrce.agent.engine.link import Link
from xrce.agent.engine.stats import AgentStats
from xrce.agent.observe.names import client_tag, endpoint_text
from xrce.wire.submessages import GetInfo, Info, StatusAgent, encode_message

log = logging.getLogger("xrce.agent")

# Traffic of sessions the agent does not know: one line per source per this many seconds, and
# at most UNKNOWN_LOG_BURST lines per UNKNOWN_LOG_PERIOD_S in all (a spoofed flood's sources).
UNKNOWN_SOURCE_LOG_S = 60.0
UNKNOWN_LOG_BURST = 5
UNKNOWN_LOG_PERIOD_S = 10.0
MAX_UNKNOWN_SOURCES = 1024


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
        self.unknown_log = RefusalLog(log, "lines about unknown sessions", lambda: self.clock(),
                                      burst=UNKNOWN_LOG_BURST, period=UNKNOWN_LOG_PERIOD_S)
        self._unknown_logged: Dict[Any, float] = {}  # source -> when its line was logged

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

    def unknown_session(self, link: Link, endpoint: Hashable, header) -> None:
        """A message for a session this agent does not know: noted for the recovery timelines,
        and logged once per source and minute: a board that kept its session while this agent
        restarted without its state goes quiet otherwise, with nothing in the log saying why."""
        self.timelines.unknown_traffic(link, endpoint, header)
        keyed = header.session_id < C.SESSION_ID_WITHOUT_KEY_MASK
        source = (header.key if keyed else None, link, endpoint)
        now = self.clock()
        last = self._unknown_logged.get(source)
        if last is not None and now - last < UNKNOWN_SOURCE_LOG_S:
            return
        if len(self._unknown_logged) >= MAX_UNKNOWN_SOURCES:
            self._unknown_logged.clear()
        self._unknown_logged[source] = now
        who = "client key %s" % bytes(header.key).hex() if keyed else \
            "no client key in its headers (session 0x%02X)" % header.session_id
        self.unknown_log.warning(
            "traffic for session 0x%02X from %s %s (%s) that this agent does not know: the "
            "board kept its session while the agent restarted without its state. Reset the "
            "board, or run the agent with its state store (on unless --no-state; --state FILE) "
            "so that a restarted agent resumes the session", header.session_id, link.name,
            endpoint_text(getattr(endpoint, "peer", endpoint)), who)

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
            locators = link.info_locators if link is not None else ()
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

