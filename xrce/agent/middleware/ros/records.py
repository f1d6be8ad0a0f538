"""What ``RosMiddleware`` (``xrce.agent.middleware.ros.entities``) keeps for each XRCE entity
it backs, one record class per kind: the rclpy object behind it, if any, and its participant's key.
Requesters and repliers have theirs in ``xrce.agent.middleware.ros.services``.

Every record has a class-level ``kind`` (the XRCE object kind it backs); ``RosMiddleware._record``
checks it when a key is used.
"""

from __future__ import annotations

from rclpy.node import Node

from xrce.agent.middleware import EntityKey, TopicSpec
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
