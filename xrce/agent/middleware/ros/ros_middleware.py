"""``-m dds``: XRCE objects backed by rclpy nodes, publishers, subscriptions, service clients/servers.

``RosMiddleware`` is composed of parts, each owning its state and handed its collaborators:
``EntityRecords`` (``records``: what is kept per entity), ``RosDomains`` (``membership``: joining
and leaving domains, the agent's own publishers, micro-ROS' graph feed), ``ParkedCreation``
(``creation``: entities made on an executor thread while their client is parked),
``RosServices`` (``services``: requesters and repliers), ``EndpointWatches``
(``endpoint_watch``: the peers a board's endpoint cannot match), ``NameCollisions``
(``collisions``: two boards given one name), ``ShownEntities`` (``shown``: what logs and stats
are told) and ``RosCompiledPathSupport`` (``compiled_path_support``: what the compiled path
needs), with ``RunContext`` (``run_context``) for the loop and what the engine sets. The threads
(one rclpy context and executor thread per domain, the bounded hand-off of samples back to the
loop) are in ``xrce.agent.middleware.ros.domain``; names translated back where a board reads
them in ``roundtrip``. This module maps the XRCE participants, topics, groups, datawriters and
datareaders onto rclpy ones, moves their data, and wires the parts.
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
    ReplyCallback,
    RequestCallback,
    ServiceSpec,
    TopicSpec,
    TypeNotReady,
)
from xrce.agent.middleware.ros import REQUEST_TIMEOUT_S
from xrce.agent.middleware.ros.collisions import NameCollisions
from xrce.agent.middleware.ros.compiled_path_support import RosCompiledPathSupport
from xrce.agent.middleware.ros.creation import ParkedCreation, on_executor
from xrce.agent.middleware.ros.domain import (
    ENCAPSULATION_LE,
    EXECUTOR_EVENTS,
    EXECUTOR_SINGLE,
    IDLE_WAIT_S,
    log,
)
from xrce.agent.middleware.ros.endpoint_watch import EndpointWatches
from xrce.agent.middleware.ros.graph import GRAPH_SPEC
from xrce.agent.middleware.ros.handoff import ReaderHandoff
from xrce.agent.middleware.ros.membership import DOMAIN_LINGER_S, RosDomains
from xrce.agent.middleware.ros.naming import Naming
from xrce.agent.middleware.ros.raw_types import raw_message_type
from xrce.agent.middleware.ros.records import (
    EntityRecords,
    GroupRecord,
    ParticipantRecord,
    ReaderRecord,
    TopicRecord,
    WriterRecord,
)
from xrce.agent.middleware.ros.roundtrip import reader_delivery, writer_rewrite
from xrce.agent.middleware.ros.run_context import RunContext
from xrce.agent.middleware.ros.services import RosServices
from xrce.agent.middleware.ros.shown import ShownEntities
from xrce.agent.middleware.ros.types import dds_topic_to_ros, node_name_and_namespace, qos_profile
from xrce.agent.observe.names import client_tag


class RosMiddleware(Middleware):
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
        executor_kind = executor or os.environ.get("XRCE_ROS_EXECUTOR", EXECUTOR_EVENTS)
        if executor_kind not in (EXECUTOR_EVENTS, EXECUTOR_SINGLE):
            raise MiddlewareError("unknown executor %r" % (executor_kind,))
        self.handoff_depth = handoff_depth
        self.entity_timeout_s = entity_timeout_s
        self._closed = False
        self.run = RunContext()
        self.records = EntityRecords()
        self.domains = RosDomains(self.run, self.naming, fleet, self._in_use, executor_kind,
                                  idle_wait_s, entity_timeout_s, linger_s)
        self.creation = ParkedCreation(self.run, park_creation, entity_timeout_s,
                                       self.domains.leave_if_unused)
        self.collisions = NameCollisions(self.records)
        self.services = RosServices(self.run, self.records, self.creation, self.collisions,
                                    request_timeout_s)
        self.watches = EndpointWatches(self.run)
        self.shown = ShownEntities(self.records)
        self.compiled = RosCompiledPathSupport(self.records, self.services, request_timeout_s)

    def _in_use(self, domain) -> bool:
        """Whether a client participant is in ``domain`` or being made there (``RosDomains``)."""
        return self.records.has_participant_in(domain) or self.creation.in_domain(domain)

    # -- what the engine sets -------------------------------------------------------------------

    @property
    def engine_lock(self):
        return self.run.engine_lock

    @engine_lock.setter
    def engine_lock(self, lock) -> None:
        self.run.engine_lock = lock

    @property
    def on_mismatch(self):
        return self.run.on_mismatch

    @on_mismatch.setter
    def on_mismatch(self, hook) -> None:
        self.run.on_mismatch = hook

    # -- domains (RosDomains) ---------------------------------------------------------------------

    def prepare_default(self, environ=None) -> None:
        self.domains.prepare_default(environ)

    def prepare(self, domain_ids, join: bool = False) -> None:
        self.domains.prepare(domain_ids, join)

    def add_domain_listener(self, listener, left=None) -> None:
        self.domains.add_domain_listener(listener, left)

    def domain_ids(self) -> list[int]:
        return self.domains.domain_ids()

    def agent_publisher(self, domain_id: int, message_type, topic: str, depth: int = 10,
                        on_matched=None):
        return self.domains.agent_publisher(domain_id, message_type, topic, depth, on_matched)

    def graph_feed(self, domain_id: int):
        return self.domains.graph_feed(domain_id)

    # -- requesters and repliers (RosServices) ----------------------------------------------------

    def create_requester(self, key: EntityKey, participant: EntityKey, service: ServiceSpec,
                         qos: EndpointQosSpec, on_reply: ReplyCallback) -> None:
        self.services.create_requester(key, participant, service, qos, on_reply)

    def create_replier(self, key: EntityKey, participant: EntityKey, service: ServiceSpec,
                       qos: EndpointQosSpec, on_request: RequestCallback) -> None:
        self.services.create_replier(key, participant, service, qos, on_request)

    def write_request(self, requester: EntityKey, correlation_id: int, sample: bytes) -> bool:
        return self.services.write_request(requester, correlation_id, sample)

    def write_reply(self, replier: EntityKey, sample_identity: bytes, sample: bytes) -> bool:
        return self.services.write_reply(replier, sample_identity, sample)

    @property
    def requests_timed_out(self) -> int:
        """Service requests that got no reply in time, wherever they were held (the compiled
        path's count through ``compiled_path_support().count_timed_out_requests``)."""
        return self.services.requests_timed_out

    # -- what the operator is shown (ShownEntities) ------------------------------------------------

    def ros_entity(self, key: EntityKey) -> str | None:
        return self.shown.ros_entity(key)

    def given_names(self, key: EntityKey) -> dict | None:
        return self.shown.given_names(key)

    # -- creation -----------------------------------------------------------------------------

    def _assign(self, origin: ClientOrigin | None) -> tuple:
        if self.fleet is None or origin is None:
            return self.naming, None
        return self.fleet.assign(origin)

    def create_participant(self, key: EntityKey, domain_id: int, name: str,
                           origin: ClientOrigin | None = None) -> None:
        naming, rule = self._assign(origin)
        domain_id = naming.domain_id(domain_id)  # --domain: the board's ask is overridden
        self.records.refuse_existing(key)
        self.run.loop()
        creation = self.creation.creation_of(key)
        # A retry takes its node from the domain it was submitted to.
        domain, started = (creation.domain, False) if creation is not None else \
            self.domains.domain(domain_id)
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
            node, _ = self.creation.create_on_executor(
                key, ParticipantRecord(domain, None, naming, rule), make_node, destroy_node)
        except TypeNotReady:
            raise
        except Exception as exc:
            # A domain joined for a participant whose node was not made (refused, or the
            # executor did not answer in time) is not kept for nothing.
            self.domains.leave_if_unused(domain)
            if isinstance(exc, MiddlewareError):
                raise
            raise MiddlewareError("cannot create node %r: %s" % (name, exc)) from exc
        finally:
            if started:  # after the node's job: the agent's own entities come after its STATUS
                self.domains.joined(domain_id)
        self.records.put(key, ParticipantRecord(domain, node, naming, rule))
        self.collisions.claim_node(key)
        self.domains.graph_changed(domain)

    def create_topic(self, key: EntityKey, participant: EntityKey, topic: TopicSpec) -> None:
        naming = self.records.record(participant, ("participant",)).naming
        kind, ros_name = dds_topic_to_ros(topic.name)
        if kind not in ("topic", "dds"):
            raise MiddlewareError("%r is a service topic: use a requester or replier" % topic.name)
        # A DDS-level topic keeps the name the board gave it, unless a remap names it.
        ros_name = naming.name(ros_name) if kind == "topic" else naming.dds_name(ros_name)
        self.records.add(key, TopicRecord(participant, ros_name,
                                          raw_message_type(topic.type_name), kind == "dds", topic))

    def create_publisher(self, key: EntityKey, participant: EntityKey) -> None:
        self.records.record(participant, ("participant",))
        self.records.add(key, GroupRecord(participant))

    def create_subscriber(self, key: EntityKey, participant: EntityKey) -> None:
        self.records.record(participant, ("participant",))
        self.records.add(key, GroupRecord(participant))

    def create_datawriter(self, key: EntityKey, publisher: EntityKey, topic: EntityKey,
                          qos: EndpointQosSpec) -> None:
        owner, participant = self.records.participant_of(publisher, ("group",))
        topic_record = self.records.record(topic, ("topic",))
        self.records.refuse_existing(key)
        profile = qos_profile(qos, topic_record.dds_level)
        node = participant.node
        events = PublisherEventCallbacks(**self.watches.watch(key, participant, topic_record,
                                                              profile, True))
        try:
            ros_publisher, _ = self.creation.create_on_executor(
                key, participant, lambda: node.create_publisher(
                    topic_record.msg_class, topic_record.ros_name, profile,
                    event_callbacks=events), node.destroy_publisher)
        except TypeNotReady:
            raise
        except Exception:
            self.watches.unwatch(key)
            raise
        rewrite = writer_rewrite(topic_record.spec, participant.naming, node)
        self.records.put(key, WriterRecord(owner, ros_publisher, rewrite))
        self.domains.graph_changed(participant.domain)

    def create_datareader(self, key: EntityKey, subscriber: EntityKey, topic: EntityKey,
                          qos: EndpointQosSpec, on_data: DataCallback) -> None:
        owner, participant = self.records.participant_of(subscriber, ("group",))
        topic_record = self.records.record(topic, ("topic",))
        self.records.refuse_existing(key)
        profile = qos_profile(qos, topic_record.dds_level)
        creation = self.creation.pending_creation(key, participant)
        translated = reader_delivery(topic_record.spec, participant.naming, on_data)
        record = creation.context if creation is not None else ReaderRecord(
            owner, ReaderHandoff(self.run.loop(), translated or on_data, self.handoff_depth,
                                 self.run.engine_lock), translated is not None)
        node = participant.node
        events = SubscriptionEventCallbacks(**self.watches.watch(key, participant, topic_record,
                                                                 profile, False))
        try:
            record.subscription, _ = self.creation.create_on_executor(
                key, participant, lambda: node.create_subscription(
                    topic_record.msg_class, topic_record.ros_name, record.handoff.push, profile,
                    raw=True, event_callbacks=events), node.destroy_subscription, record)
        except TypeNotReady:
            raise
        except Exception:
            self.watches.unwatch(key)
            raise
        self.records.put(key, record)
        if topic_record.spec == GRAPH_SPEC:
            self.domains.graph_reader_added(record, participant.domain)
        self.domains.graph_changed(participant.domain)

    # -- data ---------------------------------------------------------------------------------

    def write(self, writer: EntityKey, sample: bytes) -> bool:
        record = self.records.get(writer)
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
        record = self.records.record(writer, ("datawriter",))
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

        record = self.records.get(writer)
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
        return self.compiled

    # -- inspection ---------------------------------------------------------------------------

    def reader_stats(self, reader: EntityKey) -> tuple[int, int]:
        """(samples delivered to on_data, samples dropped because the loop fell behind)."""
        record = self.records.record(reader, ("datareader",))
        return record.handoff.delivered, record.handoff.dropped

    # -- deletion -----------------------------------------------------------------------------

    def _detach(self, record) -> None:
        """Stop a record's traffic on the loop side; its rclpy entity is destroyed separately."""
        if record.kind == "datareader":
            record.handoff.closed = True
            record.handoff.queue.clear()
            self.domains.graph_reader_gone(record)
        elif record.kind == "requester":
            self.services.close_requester(record)
        elif record.kind == "replier":
            record.closed = True
            record.pending.clear()  # the reply sweep forgets the record (services.py)

    def delete(self, key: EntityKey) -> None:
        record = self.records.get(key)
        if record is None:
            return
        self.collisions.release(key)
        if record.kind == "participant":
            # The engine deletes children first; anything it missed goes with the node anyway.
            for child_key in self.records.children_of(key):
                self._detach(self.records.pop(child_key))
                self.watches.unwatch(child_key)
            domain, node = record.domain, record.node

            def destroy_node():
                domain.remove_client_node(node)

            self.records.pop(key)
            on_executor(record, destroy_node, self.entity_timeout_s)
            self.domains.graph_changed(domain)
            self.domains.leave_if_unused(domain)
            return
        self.records.pop(key)
        self._detach(record)
        self.watches.unwatch(key)
        participant = self.records.get(record.participant)
        if participant is None:
            return
        node = participant.node
        timeout_s = self.entity_timeout_s
        if record.kind == "datawriter":
            on_executor(participant, lambda: node.destroy_publisher(record.publisher), timeout_s)
        elif record.kind == "datareader":
            on_executor(participant, lambda: node.destroy_subscription(record.subscription),
                        timeout_s)
        elif record.kind == "requester":
            on_executor(participant, lambda: node.destroy_client(record.client), timeout_s)
        elif record.kind == "replier":
            on_executor(participant, lambda: node.destroy_service(record.service), timeout_s)
        self.domains.graph_changed(participant.domain)

    # -- lifecycle ----------------------------------------------------------------------------

    async def start(self) -> None:
        # No ROS domain is joined here, not even the default one: a DDS participant at rest
        # discovers and answers every other participant of the network and its Fast DDS threads
        # wake ~13 times a second. The first client participant of a domain joins it
        # (``membership``); what that does to the discovery figures is in docs/PERFORMANCE.md,
        # "Agent restart and discovery".
        self.run.start()

    async def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        domains, leaving = self.domains.close()
        for record in self.records.values():
            if record.kind != "participant":
                self._detach(record)
        self.records.clear()
        self.watches.close()
        loop = asyncio.get_running_loop()
        started = time.monotonic()
        # Joining executor threads blocks; keep the loop (and other sessions' I/O) running.
        await asyncio.gather(*(loop.run_in_executor(None, domain.stop, self.entity_timeout_s)
                               for domain in domains),
                             *(loop.run_in_executor(None, thread.join, self.entity_timeout_s * 2)
                               for thread in leaving))
        log.debug("ROS middleware closed %d domain(s) in %.3f s", len(domains),
                  time.monotonic() - started)
