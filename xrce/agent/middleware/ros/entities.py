"""``-m dds``: XRCE objects backed by rclpy nodes, publishers, subscriptions, service clients/servers.

The threads (one rclpy context and executor thread per domain, its job queue and wake-up, the
bounded hand-off of samples back to the loop) and the measurements behind them are in
``xrce.agent.middleware.ros.domain``; requesters and repliers (the request/reply path) in
``xrce.agent.middleware.ros.services``; joining and leaving domains, the agent's own publishers
and micro-ROS' graph feed in ``xrce.agent.middleware.ros.membership``; what is kept per entity in
``xrce.agent.middleware.ros.records``; what logs and stats are told of them in
``xrce.agent.middleware.ros.shown``; two boards given one name in ``collisions``; names
translated back where a board reads them in ``roundtrip``. This module maps the XRCE entities
onto rclpy ones and moves their data.
"""

from __future__ import annotations

import asyncio
import os
import time

from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks

from xrce.agent.middleware import (
    ClientOrigin,
    CompiledPathSupport,
    DataCallback,
    EndpointQosSpec,
    EntityKey,
    Middleware,
    MiddlewareError,
    TopicSpec,
    TypeNotReady,
)
from xrce.agent.middleware.ros.domain import (
    ENCAPSULATION_LE,
    EXECUTOR_EVENTS,
    EXECUTOR_SINGLE,
    IDLE_WAIT_S,
    DomainRuntime,
    log,
)
from xrce.agent.middleware.ros.handoff import ReaderHandoff
from xrce.agent.observe.names import client_tag
from xrce.agent.middleware.ros.collisions import NameCollisions
from xrce.agent.middleware.ros.creation import ParkedCreation
from xrce.agent.middleware.ros.shown import ShownEntities
from xrce.agent.middleware.ros.graph import GRAPH_SPEC
from xrce.agent.middleware.ros.membership import DOMAIN_LINGER_S, RosDomains
from xrce.agent.middleware.ros.mismatch import MismatchWatch, TypeWatch
from xrce.agent.middleware.ros.records import (
    GroupRecord,
    ParticipantRecord,
    ReaderRecord,
    TopicRecord,
    WriterRecord,
)
from xrce.agent.middleware.ros.roundtrip import reader_delivery, writer_rewrite
from xrce.agent.middleware.ros.services import RosServices
from xrce.agent.middleware.ros.raw_types import raw_message_type
from xrce.agent.middleware.ros import REQUEST_TIMEOUT_S
from xrce.agent.middleware.ros.naming import Naming
from xrce.agent.middleware.ros.types import dds_topic_to_ros, node_name_and_namespace, qos_profile


MISMATCH_RETRY_S = 0.3  # a peer whose node the ROS graph does not know yet is looked for again


class RosMiddleware(RosDomains, RosServices, ParkedCreation, ShownEntities, NameCollisions,
                    Middleware):
    """XRCE entities as rclpy entities. All public methods run on the asyncio loop's thread."""

    name = "dds"

    def __init__(self, executor: str | None = None, handoff_depth: int = 1024,
                 request_timeout_s: float = REQUEST_TIMEOUT_S, entity_timeout_s: float = 5.0,
                 idle_wait_s: float = IDLE_WAIT_S, park_creation: bool = False,
                 linger_s: float = DOMAIN_LINGER_S, naming: Naming | None = None,
                 fleet=None):
        """``park_creation``: an entity's creation on the executor thread does not hold up the
        loop (``xrce.agent.middleware.ros.creation``); for the engine, which parks the creating client.
        Without it, ``create_*`` wait for the executor (direct callers, tests). ``linger_s``: how
        long a domain stays joined after its last client participant (``membership``).
        ``naming``: the namespace, remaps and domain the agent gives every board (``naming``);
        None changes nothing. ``fleet``: what gives a board other names than those, by who it is
        (``assign(origin)`` -> (Naming, rule name or None)); None: every board gets ``naming``."""
        self.naming = naming or Naming()
        self.fleet = fleet
        self.executor_kind = executor or os.environ.get("XRCE_ROS_EXECUTOR", EXECUTOR_EVENTS)
        if self.executor_kind not in (EXECUTOR_EVENTS, EXECUTOR_SINGLE):
            raise MiddlewareError("unknown executor %r" % (self.executor_kind,))
        self.handoff_depth = handoff_depth
        self.request_timeout_s = request_timeout_s
        self.entity_timeout_s = entity_timeout_s
        self.idle_wait_s = idle_wait_s
        self.linger_s = linger_s
        self.requests_timed_out = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._domains: dict[int, DomainRuntime] = {}
        # Started at start, no participant asked for them yet (membership.prepare).
        self._prepared: dict[int, DomainRuntime] = {}
        self._kept: set = set()  # joined at start for the agent's life (membership.prepare)
        self._default_domain: int | None = None  # prepared again once left (prepare_default)
        self._entities: dict[EntityKey, object] = {}
        # 12-byte guidPrefix for generated sample identities: random per agent run so identities
        # from two runs never collide in a client that survived an agent restart.
        self._guid_prefix = os.urandom(12)
        self._replier_counter = 0
        self._closed = False
        # The agent's own node per domain (e.g. for /diagnostics), not tied to any XRCE client.
        self._agent_publishers: dict[tuple, object] = {}
        self._domain_listeners: list = []  # called with each domain id joined (loop thread)
        self._leave_listeners: list = []  # and with each domain id left
        # domain id -> the loop's timer that leaves a domain without participants (membership)
        self._lingering: dict = {}
        self._leaving: list = []  # threads stopping domains whose last participant went
        self.park_creation = park_creation
        # key -> Creation: entities being created on an executor thread while their client is
        # parked, taken by the CREATE when the engine retries it (xrce.agent.middleware.ros.creation).
        self._creating: dict = {}
        # domain id -> (GraphFeed, number of client readers of the graph topic there): the graph
        # is published only where a client asked for it (xrce.agent.middleware.ros.graph).
        self._graph_feeds: dict[int, list] = {}
        # key -> MismatchWatch of each client endpoint (xrce.agent.middleware.ros.mismatch).
        self._watches: dict = {}
        self._type_watches: dict = {}  # domain id -> TypeWatch (mismatch.py)

    # -- plumbing -----------------------------------------------------------------------------

    def _get_loop(self) -> asyncio.AbstractEventLoop:
        if self._loop is None:
            self._loop = asyncio.get_running_loop()
        return self._loop

    def _record(self, key: EntityKey, kinds: tuple):
        record = self._entities.get(key)
        if record is None or record.kind not in kinds:
            raise MiddlewareError("no %s %r" % ("/".join(kinds), key))
        return record

    def _participant_of(self, key: EntityKey, kinds: tuple):
        record = self._record(key, kinds)
        owner = key if record.kind == "participant" else record.participant
        return owner, self._record(owner, ("participant",))

    def _on_executor(self, participant: ParticipantRecord, job):
        try:
            return participant.domain.call(job, self.entity_timeout_s)
        except MiddlewareError:
            raise
        except Exception as exc:
            raise MiddlewareError("%s: %s" % (type(exc).__name__, exc)) from exc

    def _add(self, key: EntityKey, record) -> None:
        if key in self._entities:
            raise MiddlewareError("entity %r already exists" % (key,))
        self._entities[key] = record

    # -- creation -----------------------------------------------------------------------------

    def _assign(self, origin: ClientOrigin | None) -> tuple:
        if self.fleet is None or origin is None:
            return self.naming, None
        return self.fleet.assign(origin)

    def create_participant(self, key: EntityKey, domain_id: int, name: str,
                           origin: ClientOrigin | None = None) -> None:
        naming, rule = self._assign(origin)
        domain_id = naming.domain_id(domain_id)  # --domain: the board's ask is overridden
        if key in self._entities:
            raise MiddlewareError("entity %r already exists" % (key,))
        self._get_loop()
        creation = self._creating.get(key)
        # A retry takes its node from the domain it was submitted to.
        domain, started = (creation.domain, False) if creation is not None else \
            self._domain(domain_id)
        # The whole ROS domain reads node names: a client's tag, never its key (observability).
        fallback = "xrce_%s_%04x" % (client_tag((key[0] & 0xFFFFFFFF).to_bytes(4, "big")),
                                     key[1] & 0xFFFF)
        node_name, namespace = node_name_and_namespace(name or "", fallback)
        namespace = naming.node_namespace(namespace)

        def make_node():
            node = domain.make_node(node_name, namespace)
            domain.add_client_node(node)
            return node

        def destroy_node(node):
            domain.remove_client_node(node)

        try:
            node, _ = self._create_on_executor(key, ParticipantRecord(domain, None, naming, rule),
                                               make_node,
                                               destroy_node)
        except TypeNotReady:
            raise
        except Exception as exc:
            # A domain joined for a participant whose node was not made (refused, or the
            # executor did not answer in time) is not kept for nothing.
            self._leave_if_unused(domain)
            if isinstance(exc, MiddlewareError):
                raise
            raise MiddlewareError("cannot create node %r: %s" % (name, exc)) from exc
        finally:
            if started:  # after the node's job: the agent's own entities come after its STATUS
                self._joined(domain_id)
        self._entities[key] = ParticipantRecord(domain, node, naming, rule)
        self._claim_node(key)
        self._graph_changed(domain)

    def create_topic(self, key: EntityKey, participant: EntityKey, topic: TopicSpec) -> None:
        naming = self._record(participant, ("participant",)).naming
        kind, ros_name = dds_topic_to_ros(topic.name)
        if kind not in ("topic", "dds"):
            raise MiddlewareError("%r is a service topic: use a requester or replier" % topic.name)
        # A DDS-level topic keeps the name the board gave it, unless a remap names it.
        ros_name = naming.name(ros_name) if kind == "topic" else naming.dds_name(ros_name)
        self._add(key, TopicRecord(participant, ros_name, raw_message_type(topic.type_name),
                                    kind == "dds", topic))

    def create_publisher(self, key: EntityKey, participant: EntityKey) -> None:
        self._record(participant, ("participant",))
        self._add(key, GroupRecord(participant))

    def create_subscriber(self, key: EntityKey, participant: EntityKey) -> None:
        self._record(participant, ("participant",))
        self._add(key, GroupRecord(participant))

    def create_datawriter(self, key: EntityKey, publisher: EntityKey, topic: EntityKey,
                          qos: EndpointQosSpec) -> None:
        owner, participant = self._participant_of(publisher, ("group",))
        topic_record = self._record(topic, ("topic",))
        if key in self._entities:
            raise MiddlewareError("entity %r already exists" % (key,))
        profile = qos_profile(qos, topic_record.dds_level)
        node = participant.node
        events = PublisherEventCallbacks(**self._watch(key, participant, topic_record, profile,
                                                       True))
        try:
            ros_publisher, _ = self._create_on_executor(
                key, participant, lambda: node.create_publisher(
                    topic_record.msg_class, topic_record.ros_name, profile,
                    event_callbacks=events), node.destroy_publisher)
        except TypeNotReady:
            raise
        except Exception:
            self._unwatch(key)
            raise
        rewrite = writer_rewrite(topic_record.spec, participant.naming, node)
        self._entities[key] = WriterRecord(owner, ros_publisher, rewrite)
        self._graph_changed(participant.domain)

    def create_datareader(self, key: EntityKey, subscriber: EntityKey, topic: EntityKey,
                          qos: EndpointQosSpec, on_data: DataCallback) -> None:
        owner, participant = self._participant_of(subscriber, ("group",))
        topic_record = self._record(topic, ("topic",))
        if key in self._entities:
            raise MiddlewareError("entity %r already exists" % (key,))
        profile = qos_profile(qos, topic_record.dds_level)
        creation = self._pending_creation(key, participant)
        translated = reader_delivery(topic_record.spec, participant.naming, on_data)
        record = creation.context if creation is not None else ReaderRecord(
            owner, ReaderHandoff(self._get_loop(), translated or on_data, self.handoff_depth,
                                 self.engine_lock), translated is not None)
        node = participant.node
        events = SubscriptionEventCallbacks(**self._watch(key, participant, topic_record, profile,
                                                          False))
        try:
            record.subscription, _ = self._create_on_executor(
                key, participant, lambda: node.create_subscription(
                    topic_record.msg_class, topic_record.ros_name, record.handoff.push, profile,
                    raw=True, event_callbacks=events), node.destroy_subscription, record)
        except TypeNotReady:
            raise
        except Exception:
            self._unwatch(key)
            raise
        self._entities[key] = record
        if topic_record.spec == GRAPH_SPEC:
            self._graph_reader_added(key, participant.domain)
        self._graph_changed(participant.domain)

    def _watch(self, key: EntityKey, participant: ParticipantRecord, topic_record, profile,
               board_writes: bool) -> dict:
        """The event callbacks that name the ROS peers a board's endpoint cannot match
        (``xrce.agent.middleware.ros.mismatch``); they replace rclpy's default, which logged
        the topic alone."""
        loop, domain = self._get_loop(), participant.domain

        def retry(job) -> None:  # executor thread: run ``job`` there again a little later
            try:
                loop.call_soon_threadsafe(loop.call_later, MISMATCH_RETRY_S, domain.post, job)
            except RuntimeError:  # the loop has closed: the agent is going
                pass

        def report(entity: EntityKey, text: str) -> None:
            hook = self.on_mismatch
            if hook is not None:
                hook(entity, text)
            else:
                log.warning("%r: %s", entity, text)

        # A parked creation's retry (xrce.agent.middleware.ros.creation) takes the entity made
        # with the first call's callbacks: the same watch.
        watch = self._watches.get(key)
        if watch is None:
            watch = self._watches[key] = MismatchWatch(key, participant.node, topic_record,
                                                       profile, board_writes, report, retry)
            if not topic_record.dds_level and topic_record.spec is not None:
                types = self._type_watches.get(domain.domain_id)
                if types is None or types.domain is not domain:
                    types = self._type_watches[domain.domain_id] = TypeWatch(domain, loop, report)
                types.add(key, topic_record.ros_name, topic_record.spec.type_name, board_writes)
        return watch.callbacks()

    def _unwatch(self, key: EntityKey) -> None:
        watch = self._watches.pop(key, None)
        if watch is not None:
            watch.closed = True  # its events may still come: they find nothing to say
            for types in self._type_watches.values():
                types.discard(key)

    # -- data ---------------------------------------------------------------------------------

    def write(self, writer: EntityKey, sample: bytes) -> bool:
        record = self._entities.get(writer)
        if record is None or record.kind != "datawriter":
            return False
        if record.rewrite is not None:
            sample = record.rewrite(sample)
        try:
            record.publisher.publish(ENCAPSULATION_LE + sample)
        except Exception as exc:
            log.warning("publish on %r failed: %s", writer, exc)
            return False
        return True

    def writer(self, writer: EntityKey):
        """The per-sample publish of one writer. It calls the rcl publisher's ``publish_raw``
        directly: rclpy's ``Publisher.publish`` adds a handle context manager and two isinstance
        checks, a quarter of the agent's own time per best-effort sample. The handle guard is not
        needed here: only the loop thread publishes, and deletion runs from that thread too,
        after the engine has dropped this callable."""
        record = self._record(writer, ("datawriter",))
        publish_raw = getattr(record.publisher, "_Publisher__publisher", None)
        publish_raw = getattr(publish_raw, "publish_raw", None)
        if publish_raw is None:  # another rclpy layout: the public entry point
            publish_raw = record.publisher.publish
        encapsulation = ENCAPSULATION_LE
        if record.rewrite is not None:  # the rare topics that carry names (roundtrip)
            return lambda sample: self.write(writer, sample)

        def write(sample: bytes) -> bool:
            try:
                publish_raw(encapsulation + sample)
            except Exception as exc:
                log.warning("publish on %r failed: %s", writer, exc)
                return False
            return True
        return write

    def sample_check(self, writer: EntityKey, dds_type: str):
        """``check(sample) -> None | why`` for the datawriter's type as this agent has it, or None
        where it cannot tell (a type known by name only): xrce.agent.engine.type_drift."""
        from xrce.agent.middleware.ros import raw_types
        from xrce.agent.middleware.ros.sample_check import checker

        record = self._entities.get(writer)
        if record is None or record.kind != "datawriter" or dds_type in raw_types._named_messages:
            return None
        return checker(dds_type)

    def type_hash(self, dds_type: str) -> str | None:
        """The RIHS01 hash of a message type as this agent's package has it, None for a type it
        carries by name or has no description of: xrce.agent.engine.type_drift.declared_hash."""
        from xrce.agent.middleware.ros import raw_types
        from xrce.agent.middleware.ros.sample_check import package_type_hash

        if dds_type in raw_types._named_messages:
            return None
        return package_type_hash(dds_type)

    def compiled_path_support(self) -> CompiledPathSupport:
        return self

    def count_timed_out_requests(self, count: int) -> None:
        self.requests_timed_out += count

    def publisher_address(self, writer: EntityKey) -> int | None:
        """The address of a datawriter's rcl_publisher_t, for the compiled UDP path
        (xrce.agent.engine.fastpath), which must forget it before ``delete``; None if rclpy hides it,
        or if its samples are rewritten on the way (``roundtrip``): C would publish them as they came."""
        record = self._entities.get(writer)
        if record is None or record.kind != "datawriter" or record.rewrite is not None:
            return None
        return getattr(getattr(record.publisher, "handle", None), "pointer", None)

    def subscription_address(self, reader: EntityKey) -> int | None:
        """The address of a datareader's rcl_subscription_t, for the compiled UDP path
        (xrce.agent.engine.fastpath), which takes its samples from then on and must let go of it
        before ``delete``; None if rclpy hides it, or if its samples are translated for its board
        (``roundtrip``): C would deliver them as they came."""
        record = self._entities.get(reader)
        if record is None or record.kind != "datareader" or record.translated:
            return None
        return getattr(getattr(record.subscription, "handle", None), "pointer", None)

    # -- inspection ---------------------------------------------------------------------------

    def reader_stats(self, reader: EntityKey) -> tuple[int, int]:
        """(samples delivered to on_data, samples dropped because the loop fell behind)."""
        record = self._record(reader, ("datareader",))
        return record.handoff.delivered, record.handoff.dropped

    # -- deletion -----------------------------------------------------------------------------

    def _detach(self, record) -> None:
        """Stop a record's traffic on the loop side; its rclpy entity is destroyed separately."""
        if record.kind == "datareader":
            record.handoff.closed = True
            record.handoff.queue.clear()
            self._graph_reader_gone(record)
        elif record.kind == "requester":
            self._close_requester(record)
        elif record.kind == "replier":
            record.closed = True
            record.pending.clear()  # the reply sweep forgets the record (services.py)

    def delete(self, key: EntityKey) -> None:
        record = self._entities.get(key)
        if record is None:
            return
        self._release_names(key)
        if record.kind == "participant":
            # The engine deletes children first; anything it missed goes with the node anyway.
            for child_key in [k for k, r in self._entities.items()
                              if r.kind != "participant" and r.participant == key]:
                self._detach(self._entities.pop(child_key))
                self._unwatch(child_key)
            domain, node = record.domain, record.node

            def destroy_node():
                domain.remove_client_node(node)

            del self._entities[key]
            self._on_executor(record, destroy_node)
            self._graph_changed(domain)
            self._leave_if_unused(domain)
            return
        del self._entities[key]
        self._detach(record)
        self._unwatch(key)
        participant = self._entities.get(record.participant)
        if participant is None:
            return
        node = participant.node
        if record.kind == "datawriter":
            self._on_executor(participant, lambda: node.destroy_publisher(record.publisher))
        elif record.kind == "datareader":
            self._on_executor(participant, lambda: node.destroy_subscription(record.subscription))
        elif record.kind == "requester":
            self._on_executor(participant, lambda: node.destroy_client(record.client))
        elif record.kind == "replier":
            self._on_executor(participant, lambda: node.destroy_service(record.service))
        self._graph_changed(participant.domain)

    # -- lifecycle ----------------------------------------------------------------------------

    async def start(self) -> None:
        # No ROS domain is joined here, not even the default one: a DDS participant at rest
        # discovers and answers every other participant of the network and its Fast DDS threads
        # wake ~13 times a second. The first client participant of a domain joins it
        # (``membership``); what that does to the discovery figures is in docs/PERFORMANCE.md,
        # "Agent restart and discovery".
        self._loop = asyncio.get_running_loop()

    async def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for lingering in self._lingering.values():
            lingering.cancel()
        self._lingering.clear()
        self._agent_publishers.clear()
        for feed, _readers in self._graph_feeds.values():
            feed.stop()
        self._graph_feeds.clear()
        self._domain_listeners.clear()
        self._leave_listeners.clear()
        for record in self._entities.values():
            if record.kind != "participant":
                self._detach(record)
        self._entities.clear()
        self._watches.clear()
        for types in self._type_watches.values():
            types.stop()
        self._type_watches.clear()
        domains = list(self._domains.values()) + list(self._prepared.values())
        self._domains.clear()
        self._prepared.clear()
        loop = asyncio.get_running_loop()
        started = time.monotonic()
        # Joining executor threads blocks; keep the loop (and other sessions' I/O) running.
        await asyncio.gather(*(loop.run_in_executor(None, domain.stop, self.entity_timeout_s)
                               for domain in domains),
                             *(loop.run_in_executor(None, thread.join, self.entity_timeout_s * 2)
                               for thread in self._leaving))
        log.debug("ROS middleware closed %d domain(s) in %.3f s", len(domains),
                  time.monotonic() - started)
