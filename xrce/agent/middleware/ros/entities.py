"""``-m dds``: XRCE objects backed by rclpy nodes, publishers, subscriptions, service clients/servers.

The threads (one rclpy context and executor thread per domain, its job queue and wake-up, the
bounded hand-off of samples back to the loop) and the measurements behind them are in
``xrce.agent.middleware.ros.domain``; requesters and repliers (the request/reply path) in
``xrce.agent.middleware.ros.services``. This module maps the XRCE entities onto rclpy ones and moves their
data.
"""

from __future__ import annotations

import asyncio
import os
import threading
import time

from rclpy.node import Node

from xrce.agent.middleware import (
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
from xrce.agent.middleware.ros.creation import ParkedCreation
from xrce.agent.middleware.ros.graph import GRAPH_TOPIC, GRAPH_TYPE, GraphFeed
from xrce.agent.middleware.ros.services import RosServices
from xrce.agent.middleware.ros.raw_types import raw_message_type
from xrce.agent.middleware.ros.types import dds_topic_to_ros, node_name_and_namespace, qos_profile


class _ParticipantRecord:
    __slots__ = ("domain", "node")
    kind = "participant"

    def __init__(self, domain: DomainRuntime, node: Node):
        self.domain = domain
        self.node = node


class _TopicRecord:
    __slots__ = ("participant", "ros_name", "msg_class", "dds_level", "spec")
    kind = "topic"

    def __init__(self, participant: EntityKey, ros_name: str, msg_class, dds_level: bool = False,
                 spec: TopicSpec | None = None):
        self.participant = participant
        self.ros_name = ros_name
        self.msg_class = msg_class
        self.dds_level = dds_level  # no ROS prefix: a DDS-level topic (types.dds_topic_to_ros)
        self.spec = spec


class _GroupRecord:
    """XRCE publisher/subscriber: nothing in ROS, only the link to the participant."""

    __slots__ = ("participant",)
    kind = "group"

    def __init__(self, participant: EntityKey):
        self.participant = participant


class _WriterRecord:
    __slots__ = ("participant", "publisher")
    kind = "datawriter"

    def __init__(self, participant: EntityKey, publisher):
        self.participant = participant
        self.publisher = publisher


class _ReaderRecord:
    __slots__ = ("participant", "subscription", "handoff", "graph_domain")
    kind = "datareader"

    def __init__(self, participant: EntityKey, handoff: ReaderHandoff):
        self.participant = participant
        self.subscription = None
        self.handoff = handoff
        self.graph_domain = None  # a reader of micro-ROS' graph topic: its domain id


# What rmw_microxrcedds' graph reader names (xrce.agent.middleware.ros.graph).
GRAPH_SPEC = TopicSpec(GRAPH_TOPIC, GRAPH_TYPE)


class AgentPublisher:
    """A publisher of the agent's own that takes CDR bodies (no encapsulation header), on the
    agent's hidden node (``DomainRuntime.host``, visible). Made by a job the loop does not wait
    for: until then it has no reader and writes nothing."""

    __slots__ = ("publisher", "matched_events", "_make")

    def __init__(self, make, matched_events: bool):
        self._make = make  # node -> (rclpy publisher, matched events or not)
        self.publisher = None
        self.matched_events = matched_events  # as asked for, until the RMW has said

    def attach(self, node) -> None:
        self.publisher, self.matched_events = self._make(node)

    def write(self, body: bytes) -> None:
        publisher = self.publisher
        if publisher is not None:
            publisher.publish(ENCAPSULATION_LE + body)

    def subscriber_count(self) -> int:
        publisher = self.publisher
        return 0 if publisher is None else publisher.get_subscription_count()


def _default_domain_id() -> int:
    try:
        return int(os.environ.get("ROS_DOMAIN_ID", "0") or 0)
    except ValueError:
        return 0


def _leave_domain(domain: DomainRuntime, timeout_s: float) -> None:
    domain.stop(timeout_s)
    from xrce.agent.engine.dispatch import _return_free_heap

    _return_free_heap()  # the domain's DDS buffers, freed, go back to the system


class RosMiddleware(RosServices, ParkedCreation, Middleware):
    """XRCE entities as rclpy entities. All public methods run on the asyncio loop's thread."""

    name = "dds"

    def __init__(self, executor: str | None = None, handoff_depth: int = 1024,
                 request_timeout_s: float = 10.0, entity_timeout_s: float = 5.0,
                 idle_wait_s: float = IDLE_WAIT_S, park_creation: bool = False):
        """``park_creation``: an entity's creation on the executor thread does not hold up the
        loop (``xrce.agent.middleware.ros.creation``); for the engine, which parks the creating client.
        Without it, ``create_*`` wait for the executor (direct callers, tests)."""
        self.executor_kind = executor or os.environ.get("XRCE_ROS_EXECUTOR", EXECUTOR_EVENTS)
        if self.executor_kind not in (EXECUTOR_EVENTS, EXECUTOR_SINGLE):
            raise MiddlewareError("unknown executor %r" % (self.executor_kind,))
        self.handoff_depth = handoff_depth
        self.request_timeout_s = request_timeout_s
        self.entity_timeout_s = entity_timeout_s
        self.idle_wait_s = idle_wait_s
        self.requests_timed_out = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._domains: dict[int, DomainRuntime] = {}
        self._entities: dict[EntityKey, object] = {}
        # 12-byte guidPrefix for generated sample identities: random per agent run so identities
        # from two runs never collide in a client that survived an agent restart.
        self._guid_prefix = os.urandom(12)
        self._replier_counter = 0
        self._closed = False
        # The agent's own node per domain (e.g. for /diagnostics), not tied to any XRCE client.
        self._agent_publishers: dict[tuple, object] = {}
        self._domain_listeners: list = []  # called with each domain id joined (loop thread)
        self._home_domain = _default_domain_id()  # joined at start, kept (_leave_if_unused)
        self._leaving: list = []  # threads stopping domains whose last participant went
        self.park_creation = park_creation
        # key -> Creation: entities being created on an executor thread while their client is
        # parked, taken by the CREATE when the engine retries it (xrce.agent.middleware.ros.creation).
        self._creating: dict = {}
        # domain id -> (GraphFeed, number of client readers of the graph topic there): the graph
        # is published only where a client asked for it (xrce.agent.middleware.ros.graph).
        self._graph_feeds: dict[int, list] = {}

    # -- plumbing -----------------------------------------------------------------------------

    def _get_loop(self) -> asyncio.AbstractEventLoop:
        if self._loop is None:
            self._loop = asyncio.get_running_loop()
        return self._loop

    def _domain(self, domain_id: int) -> tuple[DomainRuntime, bool]:
        """(the runtime of ``domain_id``, whether it was started now). Starting one only starts
        its thread, which makes the rclpy context and executor while the loop goes on: jobs queue
        up behind that (``DomainRuntime``), so a client joining a new domain holds up no other
        (its DDS participant is made with the GIL released too, ``ros.participant``).
        A domain whose context could not start is started again on the next call."""
        if self._closed:
            raise MiddlewareError("middleware is closed")
        domain = self._domains.get(domain_id)
        if domain is not None and domain.failed is None:
            return domain, False
        if domain is not None:
            del self._domains[domain_id]
        try:
            domain = DomainRuntime(domain_id, self.executor_kind, self.idle_wait_s)
        except MiddlewareError:
            raise
        except Exception as exc:
            raise MiddlewareError("cannot start ROS domain %d: %s" % (domain_id, exc)) from exc
        self._domains[domain_id] = domain
        return domain, True

    def _joined(self, domain_id: int) -> None:
        """Tell the listeners (the agent's own publishers there): their jobs queue behind what
        was submitted before, the first client's node in a new domain."""
        for listener in list(self._domain_listeners):
            try:
                listener(domain_id)
            except Exception:
                log.warning("domain %d: a listener failed", domain_id, exc_info=True)

    def add_domain_listener(self, listener) -> None:
        """Call ``listener(domain_id)`` on the loop's thread for every ROS domain the agent has
        joined and joins from now on."""
        self._domain_listeners.append(listener)
        for domain_id in list(self._domains):
            listener(domain_id)

    def _record(self, key: EntityKey, kinds: tuple):
        record = self._entities.get(key)
        if record is None or record.kind not in kinds:
            raise MiddlewareError("no %s %r" % ("/".join(kinds), key))
        return record

    def _participant_of(self, key: EntityKey, kinds: tuple):
        record = self._record(key, kinds)
        owner = key if record.kind == "participant" else record.participant
        return owner, self._record(owner, ("participant",))

    def _on_executor(self, participant: _ParticipantRecord, job):
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

    def create_participant(self, key: EntityKey, domain_id: int, name: str) -> None:
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

        def make_node():
            node = domain.make_node(node_name, namespace)
            domain.add_client_node(node)
            return node

        def destroy_node(node):
            domain.remove_client_node(node)

        try:
            node, _ = self._create_on_executor(key, _ParticipantRecord(domain, None), make_node,
                                               destroy_node)
        except MiddlewareError:
            raise
        except Exception as exc:
            raise MiddlewareError("cannot create node %r: %s" % (name, exc)) from exc
        finally:
            if started:  # after the node's job: the agent's own entities come after its STATUS
                self._joined(domain_id)
        self._entities[key] = _ParticipantRecord(domain, node)
        self._graph_changed(domain)

    def create_topic(self, key: EntityKey, participant: EntityKey, topic: TopicSpec) -> None:
        self._record(participant, ("participant",))
        kind, ros_name = dds_topic_to_ros(topic.name)
        if kind not in ("topic", "dds"):
            raise MiddlewareError("%r is a service topic: use a requester or replier" % topic.name)
        self._add(key, _TopicRecord(participant, ros_name, raw_message_type(topic.type_name),
                                    kind == "dds", topic))

    def create_publisher(self, key: EntityKey, participant: EntityKey) -> None:
        self._record(participant, ("participant",))
        self._add(key, _GroupRecord(participant))

    def create_subscriber(self, key: EntityKey, participant: EntityKey) -> None:
        self._record(participant, ("participant",))
        self._add(key, _GroupRecord(participant))

    def create_datawriter(self, key: EntityKey, publisher: EntityKey, topic: EntityKey,
                          qos: EndpointQosSpec) -> None:
        owner, participant = self._participant_of(publisher, ("group",))
        topic_record = self._record(topic, ("topic",))
        if key in self._entities:
            raise MiddlewareError("entity %r already exists" % (key,))
        profile = qos_profile(qos, topic_record.dds_level)
        node = participant.node
        ros_publisher, _ = self._create_on_executor(key, participant, lambda: node.create_publisher(
            topic_record.msg_class, topic_record.ros_name, profile), node.destroy_publisher)
        self._entities[key] = _WriterRecord(owner, ros_publisher)
        self._graph_changed(participant.domain)

    def create_datareader(self, key: EntityKey, subscriber: EntityKey, topic: EntityKey,
                          qos: EndpointQosSpec, on_data: DataCallback) -> None:
        owner, participant = self._participant_of(subscriber, ("group",))
        topic_record = self._record(topic, ("topic",))
        if key in self._entities:
            raise MiddlewareError("entity %r already exists" % (key,))
        profile = qos_profile(qos, topic_record.dds_level)
        creation = self._creating.get(key)
        record = creation.context if creation is not None else _ReaderRecord(
            owner, ReaderHandoff(self._get_loop(), on_data, self.handoff_depth, self.engine_lock))
        node = participant.node
        record.subscription, _ = self._create_on_executor(
            key, participant, lambda: node.create_subscription(
                topic_record.msg_class, topic_record.ros_name, record.handoff.push, profile,
                raw=True), node.destroy_subscription, record)
        self._entities[key] = record
        if topic_record.spec == GRAPH_SPEC:
            self._graph_reader_added(key, participant.domain)
        self._graph_changed(participant.domain)

    # -- data ---------------------------------------------------------------------------------

    def write(self, writer: EntityKey, sample: bytes) -> bool:
        record = self._entities.get(writer)
        if record is None or record.kind != "datawriter":
            return False
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

        def write(sample: bytes) -> bool:
            try:
                publish_raw(encapsulation + sample)
            except Exception as exc:
                log.warning("publish on %r failed: %s", writer, exc)
                return False
            return True
        return write

    def publisher_address(self, writer: EntityKey) -> int | None:
        """The address of a datawriter's rcl_publisher_t, for the compiled UDP path
        (xrce.agent.engine.fastpath), which must forget it before ``delete``; None if rclpy hides it."""
        record = self._entities.get(writer)
        if record is None or record.kind != "datawriter":
            return None
        return getattr(getattr(record.publisher, "handle", None), "pointer", None)

    # -- inspection ---------------------------------------------------------------------------

    def reader_stats(self, reader: EntityKey) -> tuple[int, int]:
        """(samples delivered to on_data, samples dropped because the loop fell behind)."""
        record = self._record(reader, ("datareader",))
        return record.handoff.delivered, record.handoff.dropped

    def domain_ids(self) -> list[int]:
        """The ROS domains the agent has joined (one per domain its clients asked for), from when
        its DDS participant there exists."""
        return [domain_id for domain_id, domain in self._domains.items() if domain.joined]

    def agent_publisher(self, domain_id: int, message_type, topic: str, depth: int = 10,
                        on_matched=None):
        """An ``AgentPublisher`` of the agent's own (``DomainRuntime.host``) in a domain already
        joined, made on first use and destroyed with the domain; None when the agent has not
        joined ``domain_id``. ``message_type`` is a ``raw_message_type``. Use from the loop thread
        (rcl publish is thread-safe). ``on_matched()``, given when the publisher is made, is
        called on the loop's thread whenever a subscription matches or unmatches it; where the
        RMW has no such event, ``publisher.matched_events`` is False."""
        domain = self._domains.get(domain_id)
        if domain is None or self._closed:
            return None
        publisher = self._agent_publishers.get((domain_id, topic))
        if publisher is not None:
            return publisher

        loop = self._get_loop()

        def matched(_info) -> None:  # on the executor thread
            try:
                loop.call_soon_threadsafe(on_matched)
            except RuntimeError:  # the loop has closed: the agent is gone
                pass

        def make_publisher(node):
            if on_matched is not None:
                from rclpy.event_handler import PublisherEventCallbacks
                try:
                    return node.create_publisher(
                        message_type, topic, depth,
                        event_callbacks=PublisherEventCallbacks(matched=matched)), True
                except Exception as exc:  # an RMW without the matched event
                    log.debug("%s: no matched events (%s)", topic, exc)
            return node.create_publisher(message_type, topic, depth), False

        def attach() -> None:
            domain.host(publisher, visible=True)
            if on_matched is not None:  # it may have readers already, or no matched events
                matched(None)

        # Not waited for: the loop goes on serving, and in a domain a client has just joined it
        # comes after that client's set-up.
        publisher = AgentPublisher(make_publisher, on_matched is not None)
        domain.post_after_start(attach)
        self._agent_publishers[(domain_id, topic)] = publisher
        return publisher

    # -- micro-ROS' graph topic -----------------------------------------------------------------

    def _graph_reader_added(self, key: EntityKey, domain: DomainRuntime) -> None:
        record = self._entities[key]
        if record.graph_domain is not None:
            return
        record.graph_domain = domain.domain_id
        entry = self._graph_feeds.get(domain.domain_id)
        if entry is None or entry[0].domain is not domain:
            feed = GraphFeed(domain, raw_message_type(GRAPH_TYPE), self._get_loop())
            entry = self._graph_feeds[domain.domain_id] = [feed, 0]
            feed.start()
        entry[1] += 1

    def _graph_reader_gone(self, record) -> None:
        domain_id, record.graph_domain = record.graph_domain, None
        entry = self._graph_feeds.get(domain_id)
        if entry is None:
            return
        entry[1] -= 1
        if entry[1] <= 0:
            del self._graph_feeds[domain_id]
            entry[0].stop()

    def _graph_changed(self, domain: DomainRuntime) -> None:
        entry = self._graph_feeds.get(domain.domain_id)
        if entry is not None:
            entry[0].changed()

    def graph_feed(self, domain_id: int) -> GraphFeed | None:
        """The graph publication of a domain, None where no client asked for it."""
        entry = self._graph_feeds.get(domain_id)
        return entry[0] if entry is not None else None

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
        if record.kind == "participant":
            # The engine deletes children first; anything it missed goes with the node anyway.
            for child_key in [k for k, r in self._entities.items()
                              if r.kind != "participant" and r.participant == key]:
                self._detach(self._entities.pop(child_key))
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

    def _leave_if_unused(self, domain: DomainRuntime) -> None:
        """Tear a domain down with its last client participant: its DDS participant, context and
        executor thread (one client joining domains 1..20 and deleting its participants there
        left 32 MB and 180 threads behind; now 3 MB and none, bench/hostile_ros.py). The default
        domain stays joined (see ``start``). The thread is joined off the loop; ``close`` waits
        for it."""
        domain_id = domain.domain_id
        if self._closed or domain_id == self._home_domain or \
                self._domains.get(domain_id) is not domain:
            return
        if any(r.kind == "participant" and r.domain is domain for r in self._entities.values()) \
                or any(c.domain is domain for c in self._creating.values()):
            return
        del self._domains[domain_id]
        feed = self._graph_feeds.pop(domain_id, None)
        if feed is not None:
            feed[0].stop()  # its periodic check; its writer goes with the domain's nodes
        for publisher_key in [k for k in self._agent_publishers if k[0] == domain_id]:
            del self._agent_publishers[publisher_key]
        log.debug("ROS domain %d has no participant left: leaving it", domain_id)
        stopping = threading.Thread(target=_leave_domain, args=(domain, self.entity_timeout_s),
                                    name="xrce-leave-domain-%d" % domain_id, daemon=True)
        stopping.start()
        self._leaving = [thread for thread in self._leaving if thread.is_alive()] + [stopping]

    # -- lifecycle ----------------------------------------------------------------------------

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        # Join the default ROS domain now, with the agent's own node in it (the wake-up's anchor,
        # made by the first job): rmw_fastrtps creates the DDS participant with a context's
        # first node, not with the context. A client that connects (or reconnects after an agent
        # restart) then only adds a node to a participant its peers already discovered, instead
        # of waiting for a new participant to be discovered; one that reconnects the moment the
        # agent is back finds the domain in ``_domains`` and queues behind this (measured with
        # bench/restart_gap.py, a cold start with the client already waiting: 2.4-3.3 s to the
        # first sample in ROS before, 0.4-0.5 s after). The CLI opens its links only after
        # this, so building the node never competes with answering a client (a robot's first
        # time sync over a pty came out up to 2 ms off when it did).
        domain_id = self._home_domain
        runtime = None
        try:
            runtime, _started = self._domain(domain_id)
            await asyncio.wait_for(asyncio.wrap_future(runtime.submit(runtime.make_wake)),
                                   self.entity_timeout_s)
        except (MiddlewareError, asyncio.TimeoutError) as exc:
            # The agent still serves; a domain that failed is started again on first use.
            log.warning("ROS domain %d: the agent node is not up yet: %s", domain_id,
                        exc or "timed out")
            if runtime is None or runtime.failed is not None:
                return
        self._joined(domain_id)
        # The listeners' entities (/diagnostics) too, before any client is served: they would
        # hold up the first client's node (by 3-10 ms, measured, bench/entity_creation.py).
        try:
            await asyncio.wait_for(asyncio.wrap_future(runtime.submit(lambda: None)),
                                   self.entity_timeout_s)
        except (MiddlewareError, asyncio.TimeoutError):
            log.warning("ROS domain %d: the agent's own entities are not up yet", domain_id)

    async def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._agent_publishers.clear()
        for feed, _readers in self._graph_feeds.values():
            feed.stop()
        self._graph_feeds.clear()
        self._domain_listeners.clear()
        for record in self._entities.values():
            if record.kind != "participant":
                self._detach(record)
        self._entities.clear()
        domains = list(self._domains.values())
        self._domains.clear()
        loop = asyncio.get_running_loop()
        started = time.monotonic()
        # Joining executor threads blocks; keep the loop (and other sessions' I/O) running.
        await asyncio.gather(*(loop.run_in_executor(None, domain.stop, self.entity_timeout_s)
                               for domain in domains),
                             *(loop.run_in_executor(None, thread.join, self.entity_timeout_s * 2)
                               for thread in self._leaving))
        log.debug("ROS middleware closed %d domain(s) in %.3f s", len(domains),
                  time.monotonic() - started)
