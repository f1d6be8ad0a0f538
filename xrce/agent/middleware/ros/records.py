"""What ``RosMiddleware`` (``xrce.agent.middleware.ros.ros_middleware``) keeps for each XRCE
entity it backs, one record class per kind: the rclpy object behind it, if any, and its
participant's key. Requesters and repliers have theirs in
``xrce.agent.middleware.ros.service_records``. ``EntityRecords``, the part that holds them all by
key, is what the other parts look entities up in.

Every record has a class-level ``kind`` (the XRCE object kind it backs); ``EntityRecords.record``
checks it when a key is used.
"""

from __future__ import annotations

from rclpy.node import Node

from xrce.agent.middleware import EntityKey, MiddlewareError, TopicSpec
from xrce.agent.middleware.ros.domain import DomainRuntime
from xrce.agent.middleware.ros.handoff import ReaderHandoff
from xrce.agent.middleware.ros.naming import Naming


class ParticipantRecord:
    """``naming``: the names and domain given to this participant's board, and ``rule``: which
    rule of the fleet gave them (None: the agent's own), decided once at its creation."""

    __slots__ = ("domain", "node", "naming", "rule")
    kind = "participant"

    def __init__(self, domain: DomainRuntime, node: Node, naming: Naming, rule: str | None = None):
        self.domain = domain
        self.node = node
        self.naming = naming
        self.rule = rule


class TopicRecord:
    __slots__ = ("participant", "ros_name", "msg_class", "dds_level", "spec")
    kind = "topic"

    def __init__(self, participant: EntityKey, ros_name: str, msg_class, dds_level: bool = False,
                 spec: TopicSpec | None = None):
        self.participant = participant
        self.ros_name = ros_name
        self.msg_class = msg_class
        self.dds_level = dds_level  # no ROS prefix: a DDS-level topic (types.dds_topic_to_ros)
        self.spec = spec


class GroupRecord:
    """XRCE publisher/subscriber: nothing in ROS, only the link to the participant."""

    __slots__ = ("participant",)
    kind = "group"

    def __init__(self, participant: EntityKey):
        self.participant = participant


class WriterRecord:
    """``rewrite``: what each sample becomes on its way to ROS (``roundtrip.writer_rewrite``),
    None: nothing."""

    __slots__ = ("participant", "publisher", "rewrite")
    kind = "datawriter"

    def __init__(self, participant: EntityKey, publisher, rewrite=None):
        self.participant = participant
        self.publisher = publisher
        self.rewrite = rewrite


class ReaderRecord:
    __slots__ = ("participant", "subscription", "handoff", "graph_domain", "translated")
    kind = "datareader"

    def __init__(self, participant: EntityKey, handoff: ReaderHandoff, translated: bool = False):
        self.participant = participant
        self.subscription = None
        self.handoff = handoff
        self.graph_domain = None  # a reader of micro-ROS' graph topic: its domain id
        # Its samples are translated back for its board (``roundtrip.reader_delivery``).
        self.translated = translated


class EntityRecords:
    """Every record of the ROS middleware, by entity key (the engine's ``EntityKey``)."""

    def __init__(self):
        self._records: dict[EntityKey, object] = {}

    def get(self, key: EntityKey):
        return self._records.get(key)

    def __contains__(self, key: EntityKey) -> bool:
        return key in self._records

    def values(self):
        return self._records.values()

    def record(self, key: EntityKey, kinds: tuple):
        """The record of ``key`` if it is of one of ``kinds``; MiddlewareError otherwise."""
        record = self._records.get(key)
        if record is None or record.kind not in kinds:
            raise MiddlewareError("no %s %r" % ("/".join(kinds), key))
        return record

    def participant_of(self, key: EntityKey, kinds: tuple):
        """(participant key, participant record) of the entity ``key`` of one of ``kinds``."""
        record = self.record(key, kinds)
        owner = key if record.kind == "participant" else record.participant
        return owner, self.record(owner, ("participant",))

    def participant_record(self, record):
        """The participant record an entity's ``record`` belongs to, None if there is none."""
        participant = self._records.get(getattr(record, "participant", None))
        if participant is None or participant.kind != "participant":
            return None
        return participant

    def refuse_existing(self, key: EntityKey) -> None:
        if key in self._records:
            raise MiddlewareError("entity %r already exists" % (key,))

    def add(self, key: EntityKey, record) -> None:
        self.refuse_existing(key)
        self._records[key] = record

    def put(self, key: EntityKey, record) -> None:
        """Keep ``record`` for ``key``, whose absence the caller checked before its creation."""
        self._records[key] = record

    def pop(self, key: EntityKey):
        return self._records.pop(key)

    def children_of(self, participant: EntityKey) -> list:
        return [key for key, record in self._records.items()
                if record.kind != "participant" and record.participant == participant]

    def has_participant_in(self, domain) -> bool:
        return any(record.kind == "participant" and record.domain is domain
                   for record in self._records.values())

    def clear(self) -> None:
        self._records.clear()
