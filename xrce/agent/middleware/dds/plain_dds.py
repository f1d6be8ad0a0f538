"""Plain DDS topics of ``-m dds``: a topic whose type is not a ROS interface type name.

eProsima's agent makes a client's topic on the DDS domain under exactly the topic and type names
the client gave, whatever they are, and carries its CDR: a ``HelloWorld`` topic of a board then
talks to any DDS application of that type (a Fast DDS or Cyclone DDS program, ShapesDemo, a
system that is not ROS). The ROS middleware (``xrce.agent.middleware.ros.ros_middleware``) maps a
ROS type name onto rclpy, which can only make ROS types; every other name comes here
(``PlainDds``, a part of ``DdsMiddleware`` in ``xrce.agent.middleware.dds.dds_middleware``, what
``-m dds`` runs) and is made through the compiled bridge
(``_plaindds.cpp``, built by ``build``) on the DomainParticipant rmw_fastrtps made for that
domain's rclpy context: the same domain, Fast DDS profile and discovery as the ROS side.

An XRCE publisher or subscriber stays the ROS middleware's group record (nothing in DDS); a
datawriter or datareader of a plain topic is a DDS DataWriter / DataReader with the client's
QoS, on one DDS Publisher / Subscriber per domain that the bridge keeps while it has endpoints.
Topics are counted in the bridge: two clients' topics of one name share the DDS Topic, and an
XRCE topic deleted before its writers (rmw_microxrcedds does that) keeps it until they go.

Per sample: a board's sample is one call into the bridge (``writer_write``: the 4-byte
encapsulation prepended, the GIL released for Fast DDS's write), not through the compiled UDP
path, which knows only rcl publishers; a DDS peer's sample goes from the reader's listener
thread, GIL taken once per batch, to the same bounded ``ReaderHandoff`` ROS readers use.
"""

from __future__ import annotations

import functools

from xrce.agent.middleware import (
    DataCallback,
    EndpointQosSpec,
    EntityKey,
    MiddlewareError,
    TopicSpec,
)
from xrce.agent.middleware.dds import build
from xrce.agent.middleware.ros.handoff import ReaderHandoff


class PlainTopic:
    __slots__ = ("participant", "handle", "spec", "domain_id")
    kind = "topic"

    def __init__(self, participant: EntityKey, handle: int, spec: TopicSpec, domain_id: int):
        self.participant = participant
        self.handle = handle
        self.spec = spec
        self.domain_id = domain_id


class PlainWriter:
    __slots__ = ("participant", "handle", "spec", "domain_id")
    kind = "datawriter"

    def __init__(self, participant: EntityKey, handle: int, spec: TopicSpec, domain_id: int):
        self.participant = participant
        self.handle = handle
        self.spec = spec
        self.domain_id = domain_id


class PlainReader:
    __slots__ = ("participant", "handle", "spec", "domain_id", "handoff")
    kind = "datareader"

    def __init__(self, participant: EntityKey, spec: TopicSpec, domain_id: int,
                 handoff: ReaderHandoff):
        self.participant = participant
        self.handle = None
        self.spec = spec
        self.domain_id = domain_id
        self.handoff = handoff


def _qos_arguments(qos: EndpointQosSpec) -> tuple:
    return bool(qos.reliable), bool(qos.keep_last), qos.durability != "volatile", int(qos.depth)


class PlainDds:
    """The plain DDS topics, writers and readers of ``DdsMiddleware``. ``run``: the
    middleware's ``RunContext`` (the loop, the engine's lock); ``records``: its ``EntityRecords``,
    where participants and groups are looked up and the ROS entities' keys are."""

    def __init__(self, run, records):
        self._run = run
        self._records = records
        self._plain: dict = {}  # key -> PlainTopic / PlainWriter / PlainReader

    def __contains__(self, key: EntityKey) -> bool:
        return key in self._plain

    # -- creation -----------------------------------------------------------------------------

    def create_topic(self, key: EntityKey, participant: EntityKey, topic: TopicSpec) -> None:
        record = self._records.record(participant, ("participant",))
        self._refuse_existing(key)
        if not topic.name or not topic.type_name:
            raise MiddlewareError("a DDS topic needs a name and a type name (got %r of type %r)"
                                  % (topic.name, topic.type_name))
        given = record.naming.dds_name(topic.name)  # a remap may name a plain topic too
        if given != topic.name:
            topic = TopicSpec(given, topic.type_name)
        bridge = build.bridge()  # TypeNotReady while it is built: the CREATE waits for it
        try:
            dds_participant = bridge.participant_of(record.node.handle.pointer)
            handle = bridge.topic_open(dds_participant, topic.name, topic.type_name)
        except (RuntimeError, ValueError) as exc:
            raise MiddlewareError("DDS topic %r of type %r: %s" % (topic.name, topic.type_name,
                                                                  exc)) from None
        self._plain[key] = PlainTopic(participant, handle, topic, record.domain.domain_id)

    def create_datawriter(self, key: EntityKey, publisher: EntityKey, topic: EntityKey,
                          qos: EndpointQosSpec) -> None:
        plain_topic = self._plain[topic]
        owner, _ = self._records.participant_of(publisher, ("group",))
        self._refuse_existing(key)
        try:
            handle = build.bridge().writer_create(plain_topic.handle, *_qos_arguments(qos))
        except RuntimeError as exc:
            raise MiddlewareError(str(exc)) from None
        self._plain[key] = PlainWriter(owner, handle, plain_topic.spec, plain_topic.domain_id)

    def create_datareader(self, key: EntityKey, subscriber: EntityKey, topic: EntityKey,
                          qos: EndpointQosSpec, on_data: DataCallback, handoff_depth: int) -> None:
        plain_topic = self._plain[topic]
        owner, _ = self._records.participant_of(subscriber, ("group",))
        self._refuse_existing(key)
        handoff = ReaderHandoff(self._run.loop(), on_data, handoff_depth, self._run.engine_lock)
        record = PlainReader(owner, plain_topic.spec, plain_topic.domain_id, handoff)
        try:
            record.handle = build.bridge().reader_create(plain_topic.handle,
                                                         *_qos_arguments(qos), handoff.push)
        except RuntimeError as exc:
            raise MiddlewareError(str(exc)) from None
        self._plain[key] = record

    def _refuse_existing(self, key: EntityKey) -> None:
        if key in self._records or key in self._plain:
            raise MiddlewareError("entity %r already exists" % (key,))

    # -- data ---------------------------------------------------------------------------------

    def write(self, writer: EntityKey, sample: bytes) -> bool:
        record = self._plain[writer]
        if record.kind != "datawriter":
            return False
        return build.bridge().writer_write(record.handle, sample)

    def writer(self, writer: EntityKey):
        record = self._plain[writer]
        if record.kind != "datawriter":
            raise MiddlewareError("no datawriter %r" % (writer,))
        return functools.partial(build.bridge().writer_write, record.handle)

    def reader_stats(self, reader: EntityKey) -> tuple[int, int]:
        record = self._plain[reader]
        if record.kind != "datareader":
            raise MiddlewareError("no datareader %r" % (reader,))
        return record.handoff.delivered, record.handoff.dropped

    def matched(self, writer: EntityKey) -> int:
        """How many DDS readers a plain datawriter has matched."""
        record = self._plain.get(writer)
        if record is None or record.kind != "datawriter":
            raise MiddlewareError("no plain datawriter %r" % (writer,))
        return build.bridge().writer_matched(record.handle)

    def ros_entity(self, key: EntityKey) -> str:
        record = self._plain[key]
        what = {"datawriter": "DDS writer", "datareader": "DDS reader"}.get(record.kind, "DDS topic")
        return "%s %s of type %s in domain %d" % (what, record.spec.name, record.spec.type_name,
                                                   record.domain_id)

    # -- deletion -----------------------------------------------------------------------------

    def delete(self, key: EntityKey) -> None:
        record = self._plain.pop(key)
        bridge = build.bridge()
        if record.kind == "datareader":
            record.handoff.closed = True
            record.handoff.queue.clear()
            bridge.reader_delete(record.handle)
        elif record.kind == "datawriter":
            bridge.writer_delete(record.handle)
        else:
            bridge.topic_close(record.handle)

    def delete_children(self, key: EntityKey) -> None:
        """A participant's plain entities go before its node (and with it, maybe, the domain's
        DDS participant they live on): endpoints first, then topics."""
        if not self._plain:
            return
        record = self._records.get(key)
        if record is None or record.kind != "participant":
            return
        for kinds in (("datareader", "datawriter"), ("topic",)):
            for child in [k for k, r in self._plain.items()
                          if r.participant == key and r.kind in kinds]:
                self.delete(child)

    def close(self) -> None:
        for kinds in (("datareader", "datawriter"), ("topic",)):
            for key in [k for k, r in self._plain.items() if r.kind in kinds]:
                self.delete(key)
