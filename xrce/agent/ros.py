"""``-m dds``: XRCE objects backed by rclpy nodes, publishers, subscriptions, service clients/servers.

Threading model (measured on the 2-core dev machine, Twist, peer in another process):

- EventsExecutor (default, ``XRCE_ROS_EXECUTOR=single`` to switch): publisher -> on_data 47-75k
  msg/s, SingleThreadedExecutor 5-6k msg/s; write() -> rclpy subscriber 74-95k calls/s either way;
  200 clients (node + writer + reader) created in 3.9 s (5.5 ms median per create) vs 7.0 s.

- One rclpy ``Context`` per ROS domain, created when the first participant of that domain appears,
  each with one executor thread.
- Every call that touches the executor's entity set (creating/destroying nodes, publishers,
  subscriptions, clients, services; ``call_async``) runs ON that executor thread: the engine's
  thread submits a job and, for creation, waits for its result. The reason is the rclpy 7.1
  ``EventsExecutor``: calling ``wake()``/``add_node()`` on it from another thread while it spins
  deadlocks (observed: every time, within milliseconds), and node/entity creation wakes the executor.
  SingleThreadedExecutor tolerates cross-thread creation, but it delivers raw subscriptions about
  an order of magnitude slower (ros-from-wheels.md), so both go through the same job queue.
- Nothing polls. The events executor cannot be woken from another thread (``wake()`` deadlocks,
  rclpy guard conditions are "not supported" by it, and a future completed from another thread
  never ends its spin), so each domain's agent node subscribes to a private wake topic and
  ``post``/``call`` publish one empty sample to it: its callback runs the queued jobs on the
  executor thread (measured 29 µs p50, 67 µs p99 from post to job). Between events the thread
  waits in rclpy with a long timeout: 0.0 % of a core idle, where the former 2 ms spin slices
  cost about 2 % (and ``spin()`` without a timeout busy-loops in this rclpy). The
  SingleThreadedExecutor is woken with ``wake()``, which it supports.
- Publishing and sending service responses need no executor and happen directly on the engine's
  thread: rcl publish/send_response are thread-safe.
- Data from ROS reaches the engine through a bounded per-reader hand-off drained on the asyncio
  loop (``call_soon_threadsafe`` once per batch, drop-oldest when the loop falls behind).
"""

from __future__ import annotations

import asyncio
import collections
import concurrent.futures
import logging
import os
import queue
import struct
import threading
import time

import rclpy
import rclpy.task
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from rclpy.service import Service
from rclpy.signals import SignalHandlerOptions

from xrce.agent.middleware import (
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
from xrce.agent.rostypes import (
    dds_topic_to_ros,
    node_name_and_namespace,
    qos_profile,
    raw_message_type,
    service_class,
    service_ros_name,
)

log = logging.getLogger("xrce.agent.ros")

# CDR_LE, options 0: what the XRCE agent always puts in front of a sample going into DDS (§14).
ENCAPSULATION_LE = b"\x00\x01\x00\x00"
_ENCAPSULATION_SIZE = 4
_WAKE_TYPE = "builtin_interfaces::msg::dds_::Time_"
_WAKE_SAMPLE = ENCAPSULATION_LE + bytes(8)  # builtin_interfaces/Time zero; the content is unused

_NO_TYPE_DESCRIPTION = Parameter("start_type_description_service", value=False)
# How long the executor thread waits in rclpy when nothing happens; it only bounds how late a
# stop request is seen if its wake-up sample were lost, nothing else runs on this period.
IDLE_WAIT_S = 5.0

EXECUTOR_EVENTS = "events"
EXECUTOR_SINGLE = "single"


class _DomainRuntime:
    """One rclpy context and its executor thread; runs entity jobs on that thread."""

    def __init__(self, domain_id: int, executor_kind: str, idle_wait_s: float = IDLE_WAIT_S):
        self.domain_id = domain_id
        self.context = Context()
        rclpy.init(args=[], context=self.context, domain_id=domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        if executor_kind == EXECUTOR_EVENTS:
            from rclpy.experimental import EventsExecutor
            self.executor = EventsExecutor(context=self.context)
        elif executor_kind == EXECUTOR_SINGLE:
            self.executor = SingleThreadedExecutor(context=self.context)
        else:
            raise MiddlewareError("unknown executor %r" % (executor_kind,))
        # SingleThreadedExecutor may be woken from any thread; the events executor only through
        # the wake topic (see module docstring).
        self._wakeable = executor_kind == EXECUTOR_SINGLE
        self._events = executor_kind == EXECUTOR_EVENTS
        self._idle_wait_s = idle_wait_s
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._running = True
        self._stopped = rclpy.task.Future()  # completed on the executor thread by stop()
        self._wake_publisher = None
        self._wake_pending = False  # a wake-up sample is on its way: later posts need none
        self.nodes: set[Node] = set()
        # The agent's own node ``xrce_agent``: hosts the wake topic and RosMiddleware.agent_publisher.
        self.agent_node: Node | None = None
        self.thread = threading.Thread(target=self._run, name="xrce-ros-domain-%d" % domain_id,
                                       daemon=True)
        self.thread.start()

    def _make_agent_node(self) -> None:
        node = Node("xrce_agent", context=self.context, start_parameter_services=False,
                    enable_rosout=False, use_global_arguments=False,
                    parameter_overrides=[_NO_TYPE_DESCRIPTION])
        self.executor.add_node(node)
        self.nodes.add(node)
        self.agent_node = node
        if self._events:
            # Hidden (leading underscore) and unique per process and domain, so that no other
            # agent's wake-ups reach this one; reliable depth 1: one pending wake-up is enough.
            topic = "/_xrce_agent/wake_%d_%s" % (os.getpid(), os.urandom(4).hex())
            profile = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                 history=HistoryPolicy.KEEP_LAST)
            wake_type = raw_message_type(_WAKE_TYPE)
            node.create_subscription(wake_type, topic, self._on_wake, profile, raw=True)
            publisher = node.create_publisher(wake_type, topic, profile)
            publish = publisher.publish
            self._wake_publisher = lambda: publish(_WAKE_SAMPLE)

    def _on_wake(self, _sample) -> None:
        """Wake topic callback (executor thread)."""
        self._wake_pending = False  # before draining: a job posted from now on wakes us again
        self._run_jobs()

    def _wake(self) -> None:
        if self._wakeable:
            self.executor.wake()
        elif self._wake_publisher is not None:
            if not self._wake_pending:
                self._wake_pending = True
                self._wake_publisher()
        # Before the first job the thread blocks on the queue itself: no wake-up needed.

    def _run_jobs(self) -> None:
        while True:
            try:
                item = self._jobs.get_nowait()
            except queue.Empty:
                return
            self._run_job(*item)

    def _run_job(self, result, job) -> None:
        if result is not None and not result.set_running_or_notify_cancel():
            return
        try:
            value = job()
        except BaseException as exc:  # handed to the submitter, never lost
            if result is not None:
                result.set_exception(exc)
            else:
                log.exception("ROS job failed in domain %d", self.domain_id)
        else:
            if result is not None:
                result.set_result(value)

    def _stop_spinning(self) -> None:
        self._running = False
        if not self._stopped.done():
            self._stopped.set_result(True)

    def _run(self) -> None:
        # Until the first job there is nothing to spin for: wait on the queue. The agent node and
        # its wake topic are made then; RosMiddleware.start gives the default domain that job
        # before the agent serves anyone, other domains get it with their first client's CREATE.
        result, job = self._jobs.get()
        if job != self._finish:
            try:
                self._make_agent_node()
            except Exception:  # jobs are then only seen when each wait times out
                log.exception("cannot create the agent node of ROS domain %d", self.domain_id)
        self._run_job(result, job)
        while self._running:
            self._run_jobs()
            try:
                if self._events:
                    self.executor.spin_until_future_complete(self._stopped,
                                                             timeout_sec=self._idle_wait_s)
                else:
                    self.executor.spin_once(timeout_sec=self._idle_wait_s)
            except ExternalShutdownException:
                break
            except Exception:
                # A failing callback must not take the whole domain down with it.
                log.exception("ROS executor callback failed in domain %d", self.domain_id)
        self._run_jobs()

    def post(self, job) -> None:
        """Run ``job`` on the executor thread, not waiting for it."""
        self._jobs.put((None, job))
        self._wake()

    def call(self, job, timeout_s: float):
        """Run ``job`` on the executor thread and return its result (or raise its exception)."""
        if not self.thread.is_alive():
            raise MiddlewareError("ROS executor of domain %d is not running" % self.domain_id)
        result: concurrent.futures.Future = concurrent.futures.Future()
        self._jobs.put((result, job))
        self._wake()
        try:
            return result.result(timeout_s)
        except concurrent.futures.TimeoutError:
            result.cancel()
            raise MiddlewareError("ROS executor of domain %d did not answer within %.1f s"
                                  % (self.domain_id, timeout_s)) from None

    def _destroy_all_nodes(self) -> None:
        self._wake_publisher = None  # its node goes too
        for node in list(self.nodes):
            self.executor.remove_node(node)
            node.destroy_node()
        self.nodes.clear()
        self.agent_node = None

    def _finish(self) -> None:
        try:
            self._destroy_all_nodes()
        finally:
            self._stop_spinning()

    def stop(self, timeout_s: float) -> None:
        """Destroy every node, stop and join the thread, shut the context down. Blocking."""
        if self.thread.is_alive():
            try:
                self.call(self._finish, timeout_s)
            except Exception:
                log.exception("destroying the nodes of domain %d failed", self.domain_id)
                self._running = False
            self.thread.join(timeout_s)
        if self.thread.is_alive():
            log.error("ROS executor thread of domain %d did not stop", self.domain_id)
            return
        self._destroy_all_nodes()
        self.executor.shutdown()
        self.context.try_shutdown()


class _ReaderHandoff:
    """Samples from the executor thread to ``on_data`` on the loop, bounded, drop-oldest."""

    __slots__ = ("loop", "on_data", "queue", "scheduled", "closed", "delivered", "dropped")

    def __init__(self, loop: asyncio.AbstractEventLoop, on_data: DataCallback, depth: int):
        self.loop = loop
        self.on_data = on_data
        self.queue: collections.deque = collections.deque(maxlen=depth)
        self.scheduled = False
        self.closed = False
        self.delivered = 0
        self.dropped = 0

    def push(self, raw: bytes) -> None:
        """Subscription callback (executor thread)."""
        if self.closed:
            return
        pending = self.queue
        if len(pending) == pending.maxlen:
            self.dropped += 1
        pending.append(raw[_ENCAPSULATION_SIZE:])
        # Ordering with drain(): drain clears the flag before popping, so a sample appended
        # while it runs is either popped by it or schedules a new drain.
        if not self.scheduled:
            self.scheduled = True
            try:
                self.loop.call_soon_threadsafe(self.drain)
            except RuntimeError:  # loop closed: the agent is going away
                self.closed = True

    def drain(self) -> None:
        """Loop thread: deliver at most one queue's worth, then yield to other loop work."""
        self.scheduled = False
        pending = self.queue
        budget = pending.maxlen
        while pending and not self.closed:
            if budget == 0:
                self.scheduled = True
                self.loop.call_soon(self.drain)
                return
            budget -= 1
            body = pending.popleft()
            self.delivered += 1
            try:
                self.on_data(body)
            except Exception:
                log.exception("on_data failed")


class _TakenRequest:
    """What the replier's service callback returns instead of a response (see _ReplierRecord)."""

    __slots__ = ("identity", "body")

    def __init__(self, identity: bytes, body: bytes):
        self.identity = identity
        self.body = body


class _ParticipantRecord:
    __slots__ = ("domain", "node")
    kind = "participant"

    def __init__(self, domain: _DomainRuntime, node: Node):
        self.domain = domain
        self.node = node


class _TopicRecord:
    __slots__ = ("participant", "ros_name", "msg_class")
    kind = "topic"

    def __init__(self, participant: EntityKey, ros_name: str, msg_class):
        self.participant = participant
        self.ros_name = ros_name
        self.msg_class = msg_class


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
    __slots__ = ("participant", "subscription", "handoff")
    kind = "datareader"

    def __init__(self, participant: EntityKey, handoff: _ReaderHandoff):
        self.participant = participant
        self.subscription = None
        self.handoff = handoff


class _RequesterRecord:
    __slots__ = ("participant", "client", "srv", "on_reply", "pending", "waiting", "closed")
    kind = "requester"

    def __init__(self, participant: EntityKey, srv, on_reply: ReplyCallback):
        self.participant = participant
        self.client = None
        self.srv = srv
        self.on_reply = on_reply
        # correlation id -> [rclpy Future or None until sent, expiry TimerHandle]
        self.pending: dict[int, list] = {}
        # tasks waiting for the service server to be discovered
        self.waiting: set[asyncio.Task] = set()
        self.closed = False


class _ReplierRecord:
    """rclpy service whose responses are sent later, when the XRCE client writes its reply.

    rclpy calls ``service.callback(request, response)`` and then ``service.send_response(result,
    header)``. The events executor runs that synchronously and has no coroutine support, and
    blocking in the callback would stall every other entity of the domain for the client's
    round trip. So the callback only records the request and returns a ``_TakenRequest``, and the
    instance's ``send_response`` is replaced by ``capture`` which keeps the request header; the
    real ``Service.send_response`` runs from ``write_reply`` on the loop thread.
    """

    __slots__ = ("participant", "service", "srv", "on_request", "pending", "closed",
                 "identity_prefix", "sequence", "loop", "middleware")
    kind = "replier"

    def __init__(self, participant: EntityKey, srv, on_request: RequestCallback,
                 identity_prefix: bytes, loop: asyncio.AbstractEventLoop, middleware: "RosMiddleware"):
        self.participant = participant
        self.service = None
        self.srv = srv
        self.on_request = on_request
        self.pending: dict[bytes, tuple] = {}  # identity -> (request header, expiry TimerHandle)
        self.closed = False
        self.identity_prefix = identity_prefix  # guidPrefix(12) + entityKey(3) + entityKind(1)
        self.sequence = 0
        self.loop = loop
        self.middleware = middleware

    def take(self, request, _unused_response) -> _TakenRequest:
        """Service callback (executor thread)."""
        self.sequence += 1
        identity = self.identity_prefix + struct.pack("<iI", self.sequence >> 32,
                                                      self.sequence & 0xFFFFFFFF)
        return _TakenRequest(identity, serialize_message(request)[_ENCAPSULATION_SIZE:])

    def capture(self, taken, header) -> None:
        """Stands in for ``service.send_response`` (executor thread)."""
        if not isinstance(taken, _TakenRequest):
            Service.send_response(self.service, taken, header)
            return
        if self.closed:
            return
        try:
            self.loop.call_soon_threadsafe(self.middleware._deliver_request, self,
                                           taken.identity, taken.body, header)
        except RuntimeError:
            self.closed = True


class AgentPublisher:
    """A publisher of the agent's own node that takes CDR bodies (no encapsulation header)."""

    __slots__ = ("publisher",)

    def __init__(self, publisher):
        self.publisher = publisher

    def write(self, body: bytes) -> None:
        self.publisher.publish(ENCAPSULATION_LE + body)

    def subscriber_count(self) -> int:
        return self.publisher.get_subscription_count()


def _in_thread(loop: asyncio.AbstractEventLoop, function, *args) -> asyncio.Future:
    """``function(*args)`` on a thread of its own that ends with it. For the blocking start-up
    steps: ``run_in_executor`` would leave the loop's default pool thread behind for the agent's
    whole life (its stack and malloc arena stay resident)."""
    future = loop.create_future()

    def settle(value, error) -> None:
        if future.cancelled():
            return
        if error is not None:
            future.set_exception(error)
        else:
            future.set_result(value)

    def run() -> None:
        try:
            value, error = function(*args), None
        except BaseException as exc:  # handed to the awaiting coroutine
            value, error = None, exc
        try:
            loop.call_soon_threadsafe(settle, value, error)
        except RuntimeError:  # the loop is closed: nobody waits any more
            pass

    threading.Thread(target=run, name="xrce-start", daemon=True).start()
    return future


def _default_domain_id() -> int:
    try:
        return int(os.environ.get("ROS_DOMAIN_ID", "0") or 0)
    except ValueError:
        return 0


class RosMiddleware(Middleware):
    """XRCE entities as rclpy entities. All public methods run on the asyncio loop's thread."""

    name = "dds"

    def __init__(self, executor: str | None = None, handoff_depth: int = 1024,
                 request_timeout_s: float = 10.0, entity_timeout_s: float = 5.0,
                 idle_wait_s: float = IDLE_WAIT_S):
        self.executor_kind = executor or os.environ.get("XRCE_ROS_EXECUTOR", EXECUTOR_EVENTS)
        if self.executor_kind not in (EXECUTOR_EVENTS, EXECUTOR_SINGLE):
            raise MiddlewareError("unknown executor %r" % (self.executor_kind,))
        self.handoff_depth = handoff_depth
        self.request_timeout_s = request_timeout_s
        self.entity_timeout_s = entity_timeout_s
        self.idle_wait_s = idle_wait_s
        self.requests_timed_out = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._domains: dict[int, _DomainRuntime] = {}
        self._entities: dict[EntityKey, object] = {}
        # 12-byte guidPrefix for generated sample identities: random per agent run so identities
        # from two runs never collide in a client that survived an agent restart.
        self._guid_prefix = os.urandom(12)
        self._replier_counter = 0
        self._closed = False
        # The agent's own node per domain (e.g. for /diagnostics), not tied to any XRCE client.
        self._agent_publishers: dict[tuple, object] = {}
        # Domains being joined at start-up (asyncio futures of their _DomainRuntime).
        self._joining: dict[int, asyncio.Future] = {}

    # -- plumbing -----------------------------------------------------------------------------

    def _get_loop(self) -> asyncio.AbstractEventLoop:
        if self._loop is None:
            self._loop = asyncio.get_running_loop()
        return self._loop

    def _domain(self, domain_id: int) -> _DomainRuntime:
        if self._closed:
            raise MiddlewareError("middleware is closed")
        domain = self._domains.get(domain_id)
        if domain is None:
            try:
                domain = _DomainRuntime(domain_id, self.executor_kind, self.idle_wait_s)
            except MiddlewareError:
                raise
            except Exception as exc:
                raise MiddlewareError("cannot start ROS domain %d: %s" % (domain_id, exc)) from exc
            self._domains[domain_id] = domain
        return domain

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
        joining = self._joining.get(domain_id)
        if joining is not None and not joining.done():
            raise TypeNotReady("ROS domain %d is being joined" % domain_id, joining)
        domain = self._domain(domain_id)
        fallback = "xrce_%08x_%04x" % (key[0] & 0xFFFFFFFF, key[1] & 0xFFFF)
        node_name, namespace = node_name_and_namespace(name or "", fallback)

        def make_node():
            # No parameter services, /rosout publisher or type description service: each costs
            # DDS endpoints and discovery traffic, and an agent may host hundreds of nodes.
            node = Node(node_name, namespace=namespace, context=domain.context,
                        start_parameter_services=False, enable_rosout=False,
                        use_global_arguments=False, parameter_overrides=[_NO_TYPE_DESCRIPTION])
            domain.executor.add_node(node)
            domain.nodes.add(node)
            return node

        try:
            node = domain.call(make_node, self.entity_timeout_s)
        except MiddlewareError:
            raise
        except Exception as exc:
            raise MiddlewareError("cannot create node %r: %s" % (name, exc)) from exc
        self._entities[key] = _ParticipantRecord(domain, node)

    def create_topic(self, key: EntityKey, participant: EntityKey, topic: TopicSpec) -> None:
        self._record(participant, ("participant",))
        kind, ros_name = dds_topic_to_ros(topic.name)
        if kind != "topic":
            raise MiddlewareError("%r is a service topic: use a requester or replier" % topic.name)
        self._add(key, _TopicRecord(participant, ros_name, raw_message_type(topic.type_name)))

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
        profile = qos_profile(qos)
        node = participant.node
        ros_publisher = self._on_executor(participant, lambda: node.create_publisher(
            topic_record.msg_class, topic_record.ros_name, profile))
        self._entities[key] = _WriterRecord(owner, ros_publisher)

    def create_datareader(self, key: EntityKey, subscriber: EntityKey, topic: EntityKey,
                          qos: EndpointQosSpec, on_data: DataCallback) -> None:
        owner, participant = self._participant_of(subscriber, ("group",))
        topic_record = self._record(topic, ("topic",))
        if key in self._entities:
            raise MiddlewareError("entity %r already exists" % (key,))
        profile = qos_profile(qos)
        record = _ReaderRecord(owner, _ReaderHandoff(self._get_loop(), on_data, self.handoff_depth))
        node = participant.node
        record.subscription = self._on_executor(participant, lambda: node.create_subscription(
            topic_record.msg_class, topic_record.ros_name, record.handoff.push, profile, raw=True))
        self._entities[key] = record

    def create_requester(self, key: EntityKey, participant: EntityKey, service: ServiceSpec,
                         qos: EndpointQosSpec, on_reply: ReplyCallback) -> None:
        owner, participant_record = self._participant_of(participant, ("participant",))
        if key in self._entities:
            raise MiddlewareError("entity %r already exists" % (key,))
        srv = service_class(service.request_type)
        service_name = service_ros_name(service.service_name, service.request_topic)
        profile = qos_profile(qos)
        self._get_loop()
        record = _RequesterRecord(owner, srv, on_reply)
        node = participant_record.node
        record.client = self._on_executor(participant_record, lambda: node.create_client(
            srv, service_name, qos_profile=profile))
        self._entities[key] = record

    def create_replier(self, key: EntityKey, participant: EntityKey, service: ServiceSpec,
                       qos: EndpointQosSpec, on_request: RequestCallback) -> None:
        owner, participant_record = self._participant_of(participant, ("participant",))
        if key in self._entities:
            raise MiddlewareError("entity %r already exists" % (key,))
        srv = service_class(service.request_type)
        service_name = service_ros_name(service.service_name, service.request_topic)
        profile = qos_profile(qos)
        self._replier_counter += 1
        # entityKey: 3 bytes of a per-agent replier counter; entityKind 0x02 = user writer with key
        # (the reply writer a DDS replier would own).
        prefix = self._guid_prefix + struct.pack(">I", self._replier_counter & 0xFFFFFF)[1:] + b"\x02"
        record = _ReplierRecord(owner, srv, on_request, prefix, self._get_loop(), self)
        node = participant_record.node

        def make_service():
            ros_service = node.create_service(srv, service_name, record.take, qos_profile=profile)
            ros_service.send_response = record.capture
            return ros_service

        record.service = self._on_executor(participant_record, make_service)
        self._entities[key] = record

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

    def write_request(self, requester: EntityKey, correlation_id: int, sample: bytes) -> bool:
        record = self._entities.get(requester)
        if record is None or record.kind != "requester":
            return False
        try:
            request = deserialize_message(ENCAPSULATION_LE + bytes(sample), record.srv.Request)
        except Exception as exc:
            log.warning("request for %r does not decode as %s: %s", requester,
                        record.srv.__name__, exc)
            return False
        loop = self._get_loop()
        previous = record.pending.pop(correlation_id, None)
        if previous is not None:
            self._forget_request(record, previous)
        entry = [None, loop.call_later(self.request_timeout_s, self._expire_request, record,
                                       correlation_id)]
        record.pending[correlation_id] = entry
        if record.client.service_is_ready():
            self._send_request(record, correlation_id, entry, request)
        else:
            # A request sent before the server is discovered is lost in DDS; the XRCE client
            # cannot know that, so hold it here until the server shows up (or it expires).
            task = loop.create_task(self._send_when_ready(record, correlation_id, entry, request))
            record.waiting.add(task)
            task.add_done_callback(record.waiting.discard)
        return True

    async def _send_when_ready(self, record: _RequesterRecord, correlation_id: int, entry: list,
                               request) -> None:
        while not record.closed and record.pending.get(correlation_id) is entry:
            if record.client.service_is_ready():
                self._send_request(record, correlation_id, entry, request)
                return
            await asyncio.sleep(0.01)

    def _send_request(self, record: _RequesterRecord, correlation_id: int, entry: list,
                      request) -> None:
        participant = self._entities.get(record.participant)
        if participant is None:
            return
        loop = self._loop

        def reply_arrived(future) -> None:  # executor thread
            try:
                body = serialize_message(future.result())[_ENCAPSULATION_SIZE:]
            except Exception:
                log.exception("service reply could not be serialized")
                return
            try:
                loop.call_soon_threadsafe(self._deliver_reply, record, correlation_id, entry, body)
            except RuntimeError:
                pass

        def send() -> None:  # executor thread: call_async may schedule on the executor
            if record.closed:
                return
            future = record.client.call_async(request)
            entry[0] = future
            future.add_done_callback(reply_arrived)

        participant.domain.post(send)

    def _deliver_reply(self, record: _RequesterRecord, correlation_id: int, entry: list,
                       body: bytes) -> None:
        if record.closed or record.pending.get(correlation_id) is not entry:
            return
        del record.pending[correlation_id]
        entry[1].cancel()
        try:
            record.on_reply(correlation_id, body)
        except Exception:
            log.exception("on_reply failed")

    def _forget_request(self, record: _RequesterRecord, entry: list) -> None:
        entry[1].cancel()
        if entry[0] is not None and record.client is not None:
            record.client.remove_pending_request(entry[0])

    def _expire_request(self, record: _RequesterRecord, correlation_id: int) -> None:
        entry = record.pending.pop(correlation_id, None)
        if entry is not None:
            self.requests_timed_out += 1
            log.warning("service request %d got no reply within %.1f s", correlation_id,
                        self.request_timeout_s)
            self._forget_request(record, entry)

    def _deliver_request(self, record: _ReplierRecord, identity: bytes, body: bytes,
                         header) -> None:
        if record.closed:
            return
        expiry = self._loop.call_later(self.request_timeout_s, self._expire_reply, record, identity)
        record.pending[identity] = (header, expiry)
        try:
            record.on_request(identity, body)
        except Exception:
            log.exception("on_request failed")

    def _expire_reply(self, record: _ReplierRecord, identity: bytes) -> None:
        if record.pending.pop(identity, None) is not None:
            self.requests_timed_out += 1
            log.warning("replier got no reply from its XRCE client within %.1f s",
                        self.request_timeout_s)

    def write_reply(self, replier: EntityKey, sample_identity: bytes, sample: bytes) -> bool:
        record = self._entities.get(replier)
        if record is None or record.kind != "replier":
            return False
        entry = record.pending.pop(bytes(sample_identity), None)
        if entry is None:
            return False
        header, expiry = entry
        expiry.cancel()
        try:
            response = deserialize_message(ENCAPSULATION_LE + bytes(sample), record.srv.Response)
            Service.send_response(record.service, response, header)
        except Exception as exc:
            log.warning("reply on %r failed: %s", replier, exc)
            return False
        return True

    # -- inspection ---------------------------------------------------------------------------

    def reader_stats(self, reader: EntityKey) -> tuple[int, int]:
        """(samples delivered to on_data, samples dropped because the loop fell behind)."""
        record = self._record(reader, ("datareader",))
        return record.handoff.delivered, record.handoff.dropped

    def domain_ids(self) -> list[int]:
        """The ROS domains the agent has joined (one per domain its clients asked for)."""
        return list(self._domains)

    def agent_publisher(self, domain_id: int, message_type, topic: str, depth: int = 10):
        """An ``AgentPublisher`` of the agent's own node ``xrce_agent`` in a domain already
        joined, made on first use and destroyed with the domain; None when the agent has not
        joined ``domain_id``. ``message_type`` is a ``raw_message_type``. Use from the loop thread
        (rcl publish is thread-safe)."""
        domain = self._domains.get(domain_id)
        if domain is None or self._closed:
            return None
        publisher = self._agent_publishers.get((domain_id, topic))
        if publisher is not None:
            return publisher

        def make_publisher():
            return domain.agent_node.create_publisher(message_type, topic, depth)

        publisher = AgentPublisher(domain.call(make_publisher, self.entity_timeout_s))
        self._agent_publishers[(domain_id, topic)] = publisher
        return publisher

    # -- deletion -----------------------------------------------------------------------------

    def _detach(self, record) -> None:
        """Stop a record's traffic on the loop side; its rclpy entity is destroyed separately."""
        if record.kind == "datareader":
            record.handoff.closed = True
            record.handoff.queue.clear()
        elif record.kind == "requester":
            record.closed = True
            for entry in record.pending.values():
                self._forget_request(record, entry)
            record.pending.clear()
            for task in list(record.waiting):
                task.cancel()
        elif record.kind == "replier":
            record.closed = True
            for _header, expiry in record.pending.values():
                expiry.cancel()
            record.pending.clear()

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
                domain.executor.remove_node(node)
                domain.nodes.discard(node)
                node.destroy_node()

            del self._entities[key]
            self._on_executor(record, destroy_node)
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

    # -- lifecycle ----------------------------------------------------------------------------

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        # Join the default ROS domain now, with the agent's own node in it (_DomainRuntime makes
        # it): rmw_fastrtps creates the DDS participant with a context's first node, not with the
        # context. A client that connects (or reconnects after an agent restart) then only adds a
        # node to a participant its peers already discovered, instead of waiting for a new
        # participant to be discovered.
        domain_id = _default_domain_id()
        joining = _in_thread(self._loop, _DomainRuntime, domain_id, self.executor_kind,
                             self.idle_wait_s)
        # A client that reconnects the moment the agent is back must not start a second context
        # for this domain meanwhile: create_participant parks it until this join is done
        # (measured with bench/restart_gap.py, a cold start with the client already waiting:
        # 2.4-3.3 s to the first sample in ROS before, 0.4-0.5 s after).
        self._joining[domain_id] = joining
        try:
            runtime = await joining
        except Exception as exc:  # the agent still serves; the domain starts on first use
            log.warning("could not join ROS domain %d at start-up: %s", domain_id, exc)
            return
        finally:
            self._joining.pop(domain_id, None)
        if self._closed or domain_id in self._domains:
            await self._loop.run_in_executor(None, runtime.stop, self.entity_timeout_s)
            return
        self._domains[domain_id] = runtime
        # The runtime makes its agent node with its first job; make it now, so the DDS
        # participant exists (and is being discovered) before any client is served. The CLI opens
        # its links only after this, so building the node never competes with answering a
        # client (a robot's first time sync over a pty came out up to 2 ms off when it did).
        try:
            await _in_thread(self._loop, runtime.call, lambda: None, self.entity_timeout_s)
        except MiddlewareError as exc:
            log.warning("ROS domain %d: the agent node is not up yet: %s", domain_id, exc)

    async def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._agent_publishers.clear()
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
                               for domain in domains))
        log.debug("ROS middleware closed %d domain(s) in %.3f s", len(domains),
                  time.monotonic() - started)
