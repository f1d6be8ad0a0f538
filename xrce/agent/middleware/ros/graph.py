"""The ROS graph for micro-ROS boards: the DDS topic ``ros_to_microros_graph`` (``-m dds``).

rmw_microxrcedds built with ``RMW_UXRCE_GRAPH=ON`` creates a participant ``microros_graph`` with a
DataReader on the DDS topic ``ros_to_microros_graph`` (``micro_ros_msgs/msg/Graph``, no ``rt/``
prefix) and answers ``rcl_get_topic_names_and_types``, ``rcl_count_publishers/subscribers``,
``rcl_get_node_names`` and the service listings from the last Graph it received. micro_ros_agent's
graph manager (micro-ROS-Agent, ``graph_manager.cpp``) keeps that topic published; this module does
what it does, from what rclpy sees of the graph:

- what: every node of the domain's ROS graph (the agent's hidden anchor node, should another
  agent's be up, left out: micro_ros_agent's graph participant has no node), each with its publishers and
  subscriptions as ROS names and ``pkg/msg/T`` types; and under every node, as micro_ros_agent
  has it, every service of the whole graph twice: as SERVICE_SERVER each service with a request
  topic, as SERVICE_CLIENT each with a reply topic (``pkg/srv/T`` types, action services as
  ``pkg/action/T_SendGoal``).
- how: a DDS-level writer (no ROS prefix, outside the ROS graph like micro_ros_agent's), reliable,
  transient local, keep last 1; the board's reader is a DDS reader of that topic like any other
  (``types.dds_topic_to_ros``, kind "dds"), so other boards of the domain get it too, as they get
  micro_ros_agent's.
- when: on every change of the graph, and whenever a reader has matched the writer (a volatile
  reader that matched after the last change would otherwise wait for the next one). micro_ros_agent is
  told of changes by Fast DDS discovery; rclpy offers no graph-change event (rcl's graph guard
  condition is not reachable from Python), so the domain's thread compares the graph every
  ``CHECK_PERIOD_S`` (a job the loop posts) and publishes only when it differs. That check runs only in a domain where a
  client has a reader on the topic, from its first such reader to its last: a domain where no
  client asked for the graph gets no writer and no check.

A board whose names the agent changed (``naming``, a namespace or a remap) reads the Graph in its
own names: its reader's samples are translated back as they are delivered to it
(``board_graph_reader``), so its ``rcl_get_node_names`` lists its nodes as it created them. Such a
reader stays off the compiled UDP path (``RosCompiledPathSupport.subscription_address``), which
would send the Graph as it came.

Everything here runs on the domain's executor thread (``DomainRuntime.post``); the loop only
counts readers.
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from xrce.agent.middleware import TopicSpec
from xrce.agent.middleware.ros.domain import AGENT_NODE_NAME, ENCAPSULATION_LE, DomainRuntime, log
from xrce.wire.cdr import CdrReader, CdrWriter

GRAPH_TOPIC = "ros_to_microros_graph"  # the DDS name rmw_microxrcedds reads
GRAPH_TYPE = "micro_ros_msgs::msg::dds_::Graph_"
GRAPH_SPEC = TopicSpec(GRAPH_TOPIC, GRAPH_TYPE)  # the board's reader's topic, as the engine says it
CHECK_PERIOD_S = 0.5

PUBLISHER, SUBSCRIBER, SERVICE_SERVER, SERVICE_CLIENT = 0, 1, 2, 3
# micro_ros_msgs bounds every string to 256 characters, and rmw_microxrcedds reads each into a
# 256-byte buffer with its NUL: a longer name would make the board drop the whole Graph.
MAX_NAME = 255

GRAPH_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL,
                       avoid_ros_namespace_conventions=True)


def _service_name(dds_topic: str, prefix: str, suffix: str) -> str | None:
    if dds_topic.startswith(prefix + "/") and dds_topic.endswith(suffix):
        return dds_topic[len(prefix):-len(suffix)] or None
    return None


def _service_type(dds_type: str) -> str | None:
    """``pkg::srv::dds_::X_Request_`` (or ``_Response_``) -> ``pkg/srv/X``."""
    head, found, tail = dds_type.partition("dds_::")
    if not found:
        return None
    for suffix in ("_Request_", "_Response_"):
        if tail.endswith(suffix):
            return head.replace("::", "/") + tail[:-len(suffix)]
    return None


def _services(topics_and_types) -> tuple[list, list]:
    """(servers, clients) as micro_ros_agent lists them: each service with a request topic,
    each with a reply topic, sorted, with their types."""
    found = ({}, {})
    for dds_topic, types in topics_and_types:
        for index, (prefix, suffix) in enumerate((("rq", "Request"), ("rr", "Reply"))):
            name = _service_name(dds_topic, prefix, suffix)
            if name is None:
                continue
            kinds = found[index].setdefault(name, [])
            for dds_type in types:
                service_type = _service_type(dds_type)
                if service_type is not None and service_type not in kinds:
                    kinds.append(service_type)
    return tuple(sorted(by_name.items()) for by_name in found)


def _fits(name: str) -> bool:
    return len(name.encode()) <= MAX_NAME


def graph_sample(node, own: tuple[str, str]) -> bytes:
    """The CDR body of the ``micro_ros_msgs/msg/Graph`` of what ``node`` sees of its domain,
    ``own`` (name, namespace) left out. Executor thread."""
    servers, clients = _services(node.get_topic_names_and_types(no_demangle=True))
    nodes = sorted(set(node.get_node_names_and_namespaces()) - {own},
                   key=lambda entry: (entry[1], entry[0]))
    described = []
    for name, namespace in nodes:
        try:
            publishers = node.get_publisher_names_and_types_by_node(name, namespace)
            subscribers = node.get_subscriber_names_and_types_by_node(name, namespace)
        except Exception:  # gone between the two calls: it is not in this Graph
            continue
        groups = ((PUBLISHER, sorted(publishers)), (SUBSCRIBER, sorted(subscribers)),
                  (SERVICE_SERVER, servers), (SERVICE_CLIENT, clients))
        described.append((namespace, name, [(kind, entity, tuple(types))
                                            for kind, listed in groups
                                            for entity, types in listed]))
    return encode_graph(described)


def encode_graph(nodes) -> bytes:
    """The CDR body of a Graph of [(namespace, name, [(kind, entity, types)])]; a node, entity
    or type whose name does not fit the board's buffers is left out (MAX_NAME)."""
    out = CdrWriter()
    nodes = [node for node in nodes if _fits(node[0]) and _fits(node[1])]
    out.u32(len(nodes))
    for namespace, name, entities in nodes:
        out.string(namespace)
        out.string(name)
        entities = [entity for entity in entities if _fits(entity[1])]
        out.u32(len(entities))
        for kind, entity, types in entities:
            out.u8(kind)
            out.string(entity)
            types = [t for t in types if _fits(t)]
            out.u32(len(types))
            for type_name in types:
                out.string(type_name)
    return out.getvalue()


def decode_graph(body: bytes) -> list:
    """A Graph's CDR body (little endian, as ``encode_graph`` writes it) as ``encode_graph``
    takes it."""
    reader = CdrReader(body)
    nodes = []
    for _ in range(reader.u32()):
        namespace, name = reader.string(), reader.string()
        entities = []
        for _ in range(reader.u32()):
            kind, entity = reader.u8(), reader.string()
            entities.append((kind, entity, tuple(reader.string() for _ in range(reader.u32()))))
        nodes.append((namespace, name, entities))
    return nodes


def graph_for_board(body: bytes, naming) -> bytes:
    """A Graph as the board whose participant has ``naming`` calls what is in it: the names the
    agent gave (its nodes' namespaces, topics, services, actions' hidden topics and services)
    are its own again (``Naming.board_name``, ``board_node_namespace``); a name no board name
    becomes (another robot's ``/robot2/cmd_vel``) stays as it is. Types never change."""
    translated = []
    for namespace, name, entities in decode_graph(body):
        translated.append((naming.board_node_namespace(namespace), name,
                           [(kind, naming.board_name(entity), types)
                            for kind, entity, types in entities]))
    return encode_graph(translated)


def board_graph_reader(on_data, naming):
    """``on_data`` of a board's reader of GRAPH_TOPIC: each Graph as that board calls it
    (``graph_for_board``). Per delivery, not per Graph published: the feed is one writer per
    domain for every board in it, and boards of one domain may be named apart (a fleet file)."""
    def deliver(body: bytes) -> None:
        try:
            body = graph_for_board(body, naming)
        except Exception:  # not a Graph this module wrote (another agent's): as it came
            log.debug("a Graph not translated for its board", exc_info=True)
        on_data(body)
    return deliver


class GraphFeed:
    """``ros_to_microros_graph`` kept published in one domain (module docstring)."""

    def __init__(self, domain: DomainRuntime, message_type, loop,
                 period_s: float = CHECK_PERIOD_S):
        self.domain = domain
        self.message_type = message_type  # raw_types.raw_message_type(GRAPH_TYPE)
        self.loop = loop
        self.period_s = period_s
        self.publisher = None
        self._tick = None  # the loop's timer handle of the next periodic check
        self.last = None  # the last Graph published (CDR body)
        self.published = 0
        self._check_posted = False  # a check is queued on the executor thread: no second one
        self._readers = 0  # the writer's matched readers at the last check

    def start(self) -> None:
        """Loop thread: make the writer on the executor thread; check periodically.

        The period is kept by the loop, which posts each check as a job: an rclpy timer would
        have to move between nodes with the writer (``DomainRuntime.host``)."""
        self.domain.post(self._start)
        self._tick = self.loop.call_later(self.period_s, self._periodic)

    def stop(self) -> None:
        """Loop thread: the writer and its check go (the domain's nodes may be gone already)."""
        if self._tick is not None:
            self._tick.cancel()
            self._tick = None
        self.domain.post(self._stop)

    def _periodic(self) -> None:
        self.changed()
        self._tick = self.loop.call_later(self.period_s, self._periodic)

    def changed(self) -> None:
        """Loop thread: the agent changed the graph (an entity of a client made or deleted):
        check now rather than at the next period, as micro_ros_agent learns it at once."""
        if not self._check_posted:
            self._check_posted = True
            self.domain.post(self._posted_check)

    def _posted_check(self) -> None:
        self._check_posted = False
        self._check()

    def _start(self) -> None:
        if self.domain.agent_node is None or self.publisher is not None:
            return
        self.domain.host(self)
        log.debug("domain %d: publishing %s", self.domain.domain_id, GRAPH_TOPIC)

    def attach(self, node) -> None:
        """Executor thread (DomainRuntime.host): the writer on ``node``, and a Graph for it.

        No matched-event callback: the EventsExecutor crashed (a segfault, the GIL not held)
        dispatching the event of a writer destroyed with its readers, so each check compares
        the writer's reader count instead."""
        # Absolute: the node may be a board's (DomainRuntime.host), in the namespace the agent
        # gave it, where rcl would put a relative name (and no board's reader would match).
        self.publisher = node.create_publisher(self.message_type, "/" + GRAPH_TOPIC, GRAPH_QOS)
        self._readers = 0
        self._check(always=True)

    def move(self, old, new) -> None:
        publisher = self.publisher
        self.attach(new)
        old.destroy_publisher(publisher)

    def _stop(self) -> None:
        node = self.domain.agent_node
        publisher, self.publisher = self.publisher, None
        self.domain.unhost(self)
        if node is not None and publisher is not None:
            node.destroy_publisher(publisher)
        log.debug("domain %d: %s no longer published", self.domain.domain_id, GRAPH_TOPIC)

    def _check(self, always: bool = False) -> None:
        node = self.domain.agent_node
        if self.publisher is None or node is None:
            return
        readers = self.publisher.get_subscription_count()
        if readers > self._readers:  # one matched since the last Graph: it has none yet
            always = True
        self._readers = readers
        try:
            sample = graph_sample(node, (AGENT_NODE_NAME, "/"))
        except Exception:
            log.exception("domain %d: cannot read the ROS graph", self.domain.domain_id)
            return
        if sample == self.last and not always:
            return
        self.last = sample
        self.published += 1
        self.publisher.publish(ENCAPSULATION_LE + sample)
