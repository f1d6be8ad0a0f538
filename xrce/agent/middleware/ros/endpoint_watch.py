"""Board endpoints that cannot talk to the ROS endpoints on their topic, named: incompatible QoS
(the classic micro-ROS trap: a best-effort publisher on the board, a reliable subscriber in ROS)
and a different type under the same topic name.

QoS: Fast DDS tells the agent's publisher or subscription of a board's endpoint through an rclpy
event (``incompatible_qos``) when it discovers such a peer; the event does not say which peer, so
the domain's executor thread, where the event's callback runs, reads the ROS graph for the topic
(``get_*_info_by_topic``) and finds the peers that cannot match, each named once (by its endpoint
GID) with both sides' QoS and the fix. Nothing runs unless Fast DDS raises the event.

Types: Fast DDS 2.14 raises no ``incompatible_type`` event (rclpy accepts the callback, it never
comes), so ``TypeWatch`` compares the graph's topic list, one ``get_topic_names_and_types`` every
``TypeWatch.PERIOD_S`` on the domain's thread, only while the domain has board endpoints, and
looks closer only when the list changed and a board's topic carries another type.

What is found goes to the engine (``Middleware.on_mismatch``), which names the board and counts it.
"""

from __future__ import annotations

from rclpy.qos import (
    DurabilityPolicy, QoSCompatibility, ReliabilityPolicy, qos_check_compatible,
)

from xrce.agent.middleware.ros.domain import log
from xrce.agent.observe.names import ros_type_name

_SENSOR_DATA = "best-effort (qos_profile_sensor_data)"


def _policy(value) -> str:
    return getattr(value, "name", str(value)).lower()


def profile_text(profile) -> str:
    """A QoS profile as ``ros2 topic info -v`` users know it: ``reliable, volatile, depth 10``
    (a peer's history is not in what DDS discovery tells: then without it)."""
    text = "%s, %s" % (_policy(profile.reliability), _policy(profile.durability))
    history = _policy(profile.history)
    if history == "keep_all":
        return text + ", keep_all"
    return text + (", depth %d" % profile.depth if history == "keep_last" and profile.depth
                   else "")


def _fix(board_writes: bool, board, peer) -> str:
    """What to change, on either side, for the policy that differs."""
    writer, reader = (board, peer) if board_writes else (peer, board)
    if writer.reliability == ReliabilityPolicy.BEST_EFFORT and \
            reader.reliability == ReliabilityPolicy.RELIABLE:
        if board_writes:
            return ("make the ROS subscription %s or the board's publisher reliable "
                    "(rclc_publisher_init_default)" % _SENSOR_DATA)
        return ("make the ROS publisher reliable or the board's subscription best-effort "
                "(rclc_subscription_init_best_effort)")
    if writer.durability == DurabilityPolicy.VOLATILE and \
            reader.durability == DurabilityPolicy.TRANSIENT_LOCAL:
        if board_writes:
            return "make the ROS subscription volatile or the board's publisher transient_local"
        return "make the ROS publisher transient_local or the board's subscription volatile"
    return "align the QoS of both sides (a reader may not ask for more than the writer offers)"


UNKNOWN_NODE = "(a DDS participant)"


def _node(info) -> str:
    """The peer's node, or UNKNOWN_NODE: a plain DDS participant, or a ROS node whose
    ros_discovery_info has not come yet (rmw says ``_NODE_NAME_UNKNOWN_``)."""
    name = info.node_name
    if not name or name.startswith("_NODE_NAME_UNKNOWN"):
        return UNKNOWN_NODE
    namespace = info.node_namespace.rstrip("/")
    return "%s/%s" % (namespace, name)


def _peers(node, topic: str, board_writes: bool, dds_level: bool):
    if board_writes:
        return node.get_subscriptions_info_by_topic(topic, no_mangle=dds_level)
    return node.get_publishers_info_by_topic(topic, no_mangle=dds_level)


def incompatible_qos(node, topic: str, board_profile, board_writes: bool, dds_level: bool = False):
    """``(peer GID, description)`` for every endpoint on ``topic`` whose QoS cannot match the
    board's (``board_profile``, the agent's entity for the board). Executor thread."""
    found = []
    for info in _peers(node, topic, board_writes, dds_level):
        peer = info.qos_profile
        writer, reader = (board_profile, peer) if board_writes else (peer, board_profile)
        try:
            compatibility, _reason = qos_check_compatible(writer, reader)
        except Exception:  # a policy rclpy cannot compare: say nothing rather than guess
            continue
        if compatibility != QoSCompatibility.ERROR:
            continue
        mine, theirs = ("publisher", "subscription") if board_writes \
            else ("subscription", "publisher")
        found.append((bytes(info.endpoint_gid), (
            "%s: incompatible QoS, no sample goes from %s to %s: the board's %s is %s, the ROS "
            "%s of node %s is %s; fix: %s" % (
                topic, "the board" if board_writes else "ROS", "ROS" if board_writes
                else "the board", mine, profile_text(board_profile), theirs, _node(info),
                profile_text(peer), _fix(board_writes, board_profile, peer)))))
    return found


def incompatible_types(node, topic: str, board_type: str, board_writes: bool,
                       dds_level: bool = False):
    """``(peer GID, description)`` for every endpoint on ``topic`` with another type than the
    board's DDS type ``board_type``: DDS never matches them. Executor thread."""
    found = []
    for direction in (board_writes, not board_writes):  # same-direction ones clash too
        for info in _peers(node, topic, direction, dds_level):
            if ros_type_name(info.topic_type) == ros_type_name(board_type):
                continue
            found.append((bytes(info.endpoint_gid), (
                "%s: type mismatch, nothing matches: the board's %s has type %s, the ROS %s of "
                "node %s has %s; fix: build the board with the interface the ROS side uses (or "
                "the reverse), the same package, name and version" % (
                    topic, "publisher" if board_writes else "subscription",
                    ros_type_name(board_type), "subscription" if direction else "publisher",
                    _node(info), ros_type_name(info.topic_type)))))
    return found


class MismatchWatch:
    """The event callbacks of one board endpoint's rclpy publisher or subscription
    (``callbacks()``), each peer named once; ``report(key, text)`` is the middleware's
    ``on_mismatch``. A peer Fast DDS has matched before the ROS graph knows its node (it comes with
    ros_discovery_info, a little later) is looked for again: ``retry(job)`` runs ``job`` on the
    executor thread a little later, ``RETRIES`` times at most."""

    RETRIES = 10
    MAX_PEERS = 64  # peers named per endpoint: the rest are counted by Fast DDS, not by name

    def __init__(self, key, node, topic_record, profile, board_writes: bool, report, retry):
        self.key = key
        self.node = node
        self.topic = topic_record.ros_name
        self.dds_level = topic_record.dds_level
        self.type_name = topic_record.spec.type_name if topic_record.spec is not None else ""
        self.profile = profile
        self.board_writes = board_writes
        self.report = report
        self.retry = retry
        self.named = set()
        self.closed = False

    def callbacks(self) -> dict:
        return {"incompatible_qos": lambda _status: self._check(self._qos, 0)}

    def _qos(self):
        return incompatible_qos(self.node, self.topic, self.profile, self.board_writes,
                                self.dds_level)

    def _check(self, find, attempt: int) -> None:
        if self.closed:
            return
        try:
            found = find()
        except Exception as exc:  # the node went with its client meanwhile
            log.debug("%s: cannot look for mismatched peers: %r", self.topic, exc)
            return
        new = [(gid, text) for gid, text in found if gid not in self.named]
        unnamed = [pair for pair in new if UNKNOWN_NODE in pair[1]]
        if (not new or unnamed) and attempt < self.RETRIES:
            self.retry(lambda: self._check(find, attempt + 1))
            new = [pair for pair in new if pair not in unnamed]
        for gid, text in new:
            if len(self.named) >= self.MAX_PEERS:
                break
            self.named.add(gid)
            self.report(self.key, text)


class TypeWatch:
    """The board endpoints of one domain whose ROS topic may carry another type (module
    docstring). ``add``/``discard`` on the loop's thread; the checks run on the domain's."""

    PERIOD_S = 2.0

    def __init__(self, domain, loop, report):
        self.domain = domain
        self.loop = loop
        self.report = report  # report(entity key, text)
        self.endpoints = {}  # key -> (ROS topic, DDS type, board writes)
        self.named = set()  # (key, peer GID) already reported
        self._last = None  # the topic list of the last check
        self._tick = None

    def add(self, key, topic: str, type_name: str, board_writes: bool) -> None:
        self.endpoints[key] = (topic, type_name, board_writes)
        self._last = None  # look again at once: the ROS side may be there already
        self.domain.post(self._check)
        if self._tick is None:
            self._tick = self.loop.call_later(self.PERIOD_S, self._periodic)

    def discard(self, key) -> None:
        if self.endpoints.pop(key, None) is not None and not self.endpoints:
            self.stop()

    def stop(self) -> None:
        if self._tick is not None:
            self._tick.cancel()
            self._tick = None

    def _periodic(self) -> None:
        self._tick = self.loop.call_later(self.PERIOD_S, self._periodic)
        self.domain.post(self._check)

    def _check(self) -> None:  # executor thread
        node = self.domain.agent_node
        if node is None:
            return
        try:
            listing = node.get_topic_names_and_types()
            if listing == self._last:
                return
            self._last = listing
            types = dict(listing)
            for key, (topic, type_name, writes) in list(self.endpoints.items()):
                seen = types.get(topic, ())
                if all(ros_type_name(t) == ros_type_name(type_name) for t in seen):
                    continue
                for gid, text in incompatible_types(node, topic, type_name, writes):
                    if UNKNOWN_NODE in text:
                        self._last = None  # named once its node is known
                    elif (key, gid) not in self.named:
                        self.named.add((key, gid))
                        self.report(key, text)
        except Exception as exc:  # a node gone meanwhile, the endpoints changed: next time
            log.debug("domain %d: type check: %r", self.domain.domain_id, exc)


# A peer whose node the ROS graph does not know yet is looked for again this much later.
MISMATCH_RETRY_S = 0.3


class EndpointWatches:
    """The ``MismatchWatch`` of each board endpoint and the ``TypeWatch`` of each domain, for
    the ROS middleware; what they find goes to ``run.report_mismatch`` (``RunContext``)."""

    def __init__(self, run):
        self._run = run
        self._watches: dict = {}  # entity key -> MismatchWatch
        self._type_watches: dict = {}  # domain id -> TypeWatch

    def watch(self, key, participant, topic_record, profile, board_writes: bool) -> dict:
        """The event callbacks that name the ROS peers a board's endpoint cannot match; they
        replace rclpy's default, which logged the topic alone."""
        loop, domain = self._run.loop(), participant.domain

        def retry(job) -> None:  # executor thread: run ``job`` there again a little later
            try:
                loop.call_soon_threadsafe(loop.call_later, MISMATCH_RETRY_S, domain.post, job)
            except RuntimeError:  # the loop has closed: the agent is going
                pass

        report = self._run.report_mismatch
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

    def unwatch(self, key) -> None:
        watch = self._watches.pop(key, None)
        if watch is not None:
            watch.closed = True  # its events may still come: they find nothing to say
            for types in self._type_watches.values():
                types.discard(key)

    def close(self) -> None:
        self._watches.clear()
        for types in self._type_watches.values():
            types.stop()
        self._type_watches.clear()
