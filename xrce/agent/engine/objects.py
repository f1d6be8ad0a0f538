"""The object registry: CREATE, DELETE and the middleware entities behind each XRCE object (XRCE-WIRE.md §5).

Object ids, parents and REUSE/REPLACE signatures are the engine's business; what an object maps
onto (an rclpy node, publisher, subscription, …) is the middleware's. ``ObjectRegistry``, one part
of ``xrce.agent.engine.agent.Agent``, answers CREATE and DELETE of a client's objects with
STATUS and keeps each client's ``objects`` table consistent with the middleware. (DELETE of the
client itself is the session's: the dispatcher hands it to ``Sessions``.)
"""

from __future__ import annotations

import logging
import os
from typing import Dict, Optional

from xrce.wire import constants as C, names as wire_names
from xrce.agent.engine import reuse, type_drift
from xrce.agent.middleware import (
    MAX_DOMAIN_ID, READER_DEFAULTS, WRITER_DEFAULTS, EndpointQosSpec, MiddlewareError, ServiceSpec,
    EntityKey, TopicSpec, TypeNotReady, XmlRepresentationError,
)
from xrce.agent.engine.client import ClientProxy, ObjectEntry, ReaderState, client_origin
from xrce.agent.engine.limits import MAX_OBJECTS_PER_CLIENT
from xrce.agent.observe import entities as words
from xrce.agent.observe.names import object_id_text
from xrce import DecodeError
from xrce.wire.objects import PARENT_KIND, with_kind
from xrce.wire.submessages import Create, Delete

log = logging.getLogger("xrce.agent")

MAX_QUEUE_KEEP_ALL = 1024  # reader queue bound when its QoS is KEEP_ALL
DEFAULT_PARTICIPANT_NAME = "MicroXRCEParticipant"

_GROUP_KINDS = (C.OBJK_PUBLISHER, C.OBJK_SUBSCRIBER)
_ROUTED_KINDS = {C.OBJK_PARTICIPANT: "participant", C.OBJK_TOPIC: "topic",
                 C.OBJK_DATAWRITER: "datawriter", C.OBJK_DATAREADER: "datareader"}
_NO_OP_KINDS = (C.OBJK_TYPE, C.OBJK_QOSPROFILE, C.OBJK_APPLICATION)
_CREATABLE = frozenset(PARENT_KIND) | {C.OBJK_PARTICIPANT}
_DURABILITY_FLAGS = ((C.QOS_PERSISTENT, "persistent"), (C.QOS_TRANSIENT, "transient"),
                     (C.QOS_TRANSIENT_LOCAL, "transient_local"))


class Parked(Exception):
    """A CREATE needs a type that is being built: this client's processing waits for ``future``."""

    def __init__(self, future):
        super().__init__()
        self.future = future


class ObjectRegistry:
    """CREATE/DELETE of XRCE objects and their middleware entities.

    Collaborators: ``middleware`` (the entities), ``datapath`` (the sample callbacks and reply
    writers bound to readers, requesters and repliers), ``stream_output`` (STATUS replies),
    ``fastpaths`` (the compiled receive paths, let go of a deleted object's publisher or
    subscription first) and ``create_failures`` (a rate-limited log:
    xrce.agent.engine.admission.RefusalLog). ``refs``: the profiles a by-reference CREATE names.
    """

    def __init__(self, middleware, datapath, stream_output, fastpaths: list, create_failures,
                 stats, clock, *, refs: Dict[str, str], max_objects_per_client: Optional[int]):
        self.middleware = middleware
        self.datapath = datapath
        self.send_status = stream_output.send_status
        self.fastpaths = fastpaths
        self.create_failures = create_failures
        self.stats = stats
        self.clock = clock
        self.refs = refs
        self.max_objects_per_client = max_objects_per_client

    def create(self, client: ClientProxy, request: Create, stream_id: int) -> None:
        kind = request.kind
        if kind in _NO_OP_KINDS:
            self.send_status(client, request, C.STATUS_OK, stream_id)  # eProsima creates nothing here
            return
        if kind not in _CREATABLE:
            raise DecodeError("CREATE of object kind %d" % kind)
        object_id = with_kind(request.object_id, kind)
        existing = client.objects.get(object_id)
        if existing is not None:
            if not request.reuse and not request.replace:
                self._refused(client, request, object_id, C.STATUS_ERR_ALREADY_EXISTS, stream_id)
                return
            if request.reuse:
                if reuse.matches(kind, existing, request, self.refs, client.objects,
                                 self.middleware.routed_name):
                    if log.isEnabledFor(logging.DEBUG):
                        log.debug("%s", words.object_line("reused", client, existing))
                    self.send_status(client, request, C.STATUS_OK_MATCHED, stream_id)
                    return
                if not request.replace:
                    self._refused(client, request, object_id, C.STATUS_ERR_MISMATCH, stream_id)
                    return
            self.delete_object(client, object_id)
        if len(client.objects) >= (self.max_objects_per_client or MAX_OBJECTS_PER_CLIENT):
            self.stats.quota_objects += 1
            client.warn_quota("objects", self.clock(), "%d objects, quota reached: CREATE of "
                              "0x%04X refused (ERR_RESOURCES)", len(client.objects), object_id)
            self.send_status(client, request, C.STATUS_ERR_RESOURCES, stream_id)
            return
        parent = None if kind == C.OBJK_PARTICIPANT else with_kind(request.tail_id, PARENT_KIND[kind])
        if parent is not None and parent not in client.objects:
            self._refused(client, request, object_id, C.STATUS_ERR_UNKNOWN_REFERENCE, stream_id)
            return
        entry = ObjectEntry(object_id, kind, parent, reuse.representation_of(request), info={})
        try:
            status = self._build(client, request, entry)
        except TypeNotReady as pending:
            raise Parked(pending.future)
        except (MiddlewareError, XmlRepresentationError) as exc:
            self.create_failures.warning("client %s: creating %s %s failed: %s",
                                         client.key.hex(), words.kind_name(kind),
                                         object_id_text(object_id), exc)
            status = C.STATUS_ERR_DDS_ERROR
        if status == C.STATUS_OK:
            client.objects[object_id] = entry
            if kind != C.OBJK_TOPIC:
                key = client.entity(object_id)
                entry.info["ros"] = self.middleware.ros_entity(key)
                given = self.middleware.given_names(key)
                if given is not None:  # the names the agent gave instead (observe.entities)
                    entry.info["given"] = given
            if log.isEnabledFor(logging.INFO):
                log.info("%s", words.object_line("created", client, entry))
        elif status != C.STATUS_ERR_DDS_ERROR:
            _log_refusal(client, kind, object_id, status)
        self.send_status(client, request, status, stream_id)

    def _refused(self, client: ClientProxy, request: Create, object_id: int, status: int,
                 stream_id: int) -> None:
        """A CREATE answered with an error the client caused: at debug level, as eProsima's
        agent logs them (``-v 5``)."""
        _log_refusal(client, request.kind, object_id, status)
        self.send_status(client, request, status, stream_id)

    def _reference(self, request: Create) -> str:
        try:
            return self.refs[request.representation]
        except KeyError:
            raise MiddlewareError("no profile called %r" % request.representation) from None

    def _xml_text(self, request: Create) -> str:
        if request.fmt == C.REPRESENTATION_BY_REFERENCE:
            return self._reference(request)
        return request.representation

    def _build(self, client: ClientProxy, request: Create, entry: ObjectEntry) -> int:
        """Create the middleware entity behind ``entry``; a status other than OK if not possible."""
        kind, fmt, rep = request.kind, request.fmt, request.representation
        key = client.entity(entry.object_id)
        mw = self.middleware
        routed = None if fmt == C.REPRESENTATION_IN_BINARY else \
            mw.routed_name(_ROUTED_KINDS.get(kind, ""), rep)
        if kind == C.OBJK_PARTICIPANT:
            self._build_participant(client, request, entry, key)
        elif kind == C.OBJK_TOPIC:
            self._build_topic(client, request, entry, key, routed)
        elif kind in _GROUP_KINDS:
            return self._build_group(client, request, entry, key)
        elif kind in (C.OBJK_DATAWRITER, C.OBJK_DATAREADER):
            return self._build_endpoint(client, request, entry, key, routed)
        elif kind in (C.OBJK_REQUESTER, C.OBJK_REPLIER):
            self._build_service(client, request, entry, key)
        return C.STATUS_OK

    def _build_participant(self, client: ClientProxy, request: Create, entry: ObjectEntry,
                           key: EntityKey) -> None:
        """A participant: named and in a domain as the board asked (its XML profile's for
        domain 255 by reference), or its strings kept as sent for a middleware that routes by them."""
        fmt, rep = request.fmt, request.representation
        mw = self.middleware
        if mw.routed_name("participant", "") is not None:
            # A middleware that routes by strings (CED) keeps the domain as sent, 255 too.
            name = rep.name if fmt == C.REPRESENTATION_IN_BINARY and rep.name else \
                DEFAULT_PARTICIPANT_NAME
            entry.info.update(name=name, domain=request.tail_id)
            mw.create_participant(key, request.tail_id, name, client_origin(client))
            return
        domain = request.tail_id
        if fmt == C.REPRESENTATION_IN_BINARY:
            name = rep.name or DEFAULT_PARTICIPANT_NAME
            profile_domain = None
        else:
            parsed = _xml().parse_participant(self._xml_text(request))
            name = parsed.name or (rep if fmt == C.REPRESENTATION_BY_REFERENCE else "") \
                or DEFAULT_PARTICIPANT_NAME
            profile_domain = parsed.domain_id
        if domain == 255:
            if fmt == C.REPRESENTATION_BY_REFERENCE:
                domain = profile_domain or 0
            else:
                domain = _domain_override()
        if not 0 <= domain <= MAX_DOMAIN_ID:
            # Fast DDS cannot compute ports beyond it and aborts the whole process (found by
            # bench/hostile/fuzz_live_agent.py): refuse here, as a DDS error, before it gets there.
            raise MiddlewareError("domain id %d is not in 0..%d" % (domain, MAX_DOMAIN_ID))
        entry.info.update(name=name, domain=domain)
        mw.create_participant(key, domain, name, client_origin(client))

    def _build_topic(self, client: ClientProxy, request: Create, entry: ObjectEntry,
                     key: EntityKey, routed: Optional[str]) -> None:
        """A topic: its name and type, from the binary representation, a routed name or XML."""
        fmt, rep = request.fmt, request.representation
        mw = self.middleware
        if fmt == C.REPRESENTATION_IN_BINARY:
            spec = TopicSpec(rep.topic_name, rep.type_name or rep.type_reference or "")
        elif routed is not None:
            spec = TopicSpec(routed, "")
        else:
            spec = _xml().parse_topic(self._xml_text(request))
        entry.topic_spec = spec
        mw.create_topic(key, client.entity(entry.parent), spec)

    def _build_group(self, client: ClientProxy, request: Create, entry: ObjectEntry,
                     key: EntityKey) -> int:
        """A publisher or subscriber (no by-reference representation)."""
        kind, fmt, rep = request.kind, request.fmt, request.representation
        mw = self.middleware
        if fmt == C.REPRESENTATION_BY_REFERENCE:
            return C.STATUS_ERR_INVALID_DATA  # groups have no by-reference representation
        if fmt == C.REPRESENTATION_AS_XML_STRING:
            _xml().check_group(rep, "publisher" if kind == C.OBJK_PUBLISHER else "subscriber")
        if kind == C.OBJK_PUBLISHER:
            mw.create_publisher(key, client.entity(entry.parent))
        else:
            mw.create_subscriber(key, client.entity(entry.parent))
        return C.STATUS_OK

    def _build_endpoint(self, client: ClientProxy, request: Create, entry: ObjectEntry,
                        key: EntityKey, routed: Optional[str]) -> int:
        """A data writer or reader on one of the participant's topics, with its QoS."""
        kind, fmt, rep = request.kind, request.fmt, request.representation
        mw = self.middleware
        writer = kind == C.OBJK_DATAWRITER
        if fmt == C.REPRESENTATION_IN_BINARY:
            topic = with_kind(rep.topic_id, C.OBJK_TOPIC)
            if topic not in client.objects:
                return C.STATUS_ERR_UNKNOWN_REFERENCE
            qos = _binary_qos(rep.qos, writer)
        elif routed is not None:
            topic = self._find_topic(client, entry.parent, routed)
            if topic is None:
                raise MiddlewareError("no topic %r in this participant" % routed)
            qos = WRITER_DEFAULTS if writer else READER_DEFAULTS
        else:
            parsed = _xml().parse_endpoint(self._xml_text(request), writer)
            topic = self._find_topic(client, entry.parent, parsed.topic.name)
            if topic is None:
                raise MiddlewareError("no topic %r in this participant" % parsed.topic.name)
            qos = parsed.qos
        entry.topic = topic
        entry.topic_spec = client.objects[topic].topic_spec
        entry.info["qos"] = qos
        if writer:
            mw.create_datawriter(key, client.entity(entry.parent), client.entity(topic), qos)
            entry.write = mw.writer(key)
            # Its first sample is checked against the agent's type (xrce.agent.engine.type_drift)
            type_drift.arm(mw, self.datapath.mismatches, self.datapath.scheduler, client, entry, key)
        else:
            # A reader given no QoS (CED's names, a binary one without) queues at least what
            # the middleware keeps for it (CedMiddleware: eProsima's 16 per topic).
            floor = mw.reader_queue_floor if qos is READER_DEFAULTS else 1
            entry.reader = ReaderState(max(_queue_bound(qos), floor))
            mw.create_datareader(key, client.entity(entry.parent), client.entity(topic), qos,
                                 self.datapath.sample_callback(client, entry.object_id))
        if fmt == C.REPRESENTATION_IN_BINARY:  # a type hash the board declared, checked at creation
            type_drift.declared_hash(mw, self.datapath.mismatches, client, entry, rep.qos)
        return C.STATUS_OK

    def _build_service(self, client: ClientProxy, request: Create, entry: ObjectEntry,
                       key: EntityKey) -> None:
        """A requester or replier: its service, and the queue of what it has to deliver."""
        kind, fmt, rep = request.kind, request.fmt, request.representation
        mw = self.middleware
        if fmt == C.REPRESENTATION_IN_BINARY:
            spec = ServiceSpec(rep.service_name, rep.request_type, rep.reply_type,
                               rep.request_topic, rep.reply_topic)
        else:
            spec = _xml().parse_service(
                self._xml_text(request), "requester" if kind == C.OBJK_REQUESTER else "replier")
        qos = EndpointQosSpec()
        entry.info.update(service=words.service_info(spec), qos=qos)
        entry.reader = ReaderState(_queue_bound(qos))
        if kind == C.OBJK_REQUESTER:
            mw.create_requester(key, client.entity(entry.parent), spec, qos,
                                self.datapath.reply_callback(client, entry.object_id))
        else:
            mw.create_replier(key, client.entity(entry.parent), spec, qos,
                              self.datapath.request_callback(client, entry.object_id))
            entry.write = self.datapath.reply_writer(client, entry.object_id)

    @staticmethod
    def _find_topic(client: ClientProxy, group: int, name: str) -> Optional[int]:
        participant = client.objects[group].parent
        for object_id, entry in client.objects.items():
            if entry.kind == C.OBJK_TOPIC and entry.parent == participant and \
                    entry.topic_spec is not None and entry.topic_spec.name == name:
                return object_id
        return None

    def delete(self, client: ClientProxy, request: Delete, stream_id: int) -> None:
        """DELETE of one of the client's objects (not of the client: see the module docstring)."""
        if request.object_id not in client.objects:
            if log.isEnabledFor(logging.DEBUG):
                log.debug("client %s: DELETE of unknown object %s", client.key.hex(),
                          object_id_text(request.object_id))
            self.send_status(client, request, C.STATUS_ERR_UNKNOWN_REFERENCE, stream_id)
            return
        self.delete_object(client, request.object_id)
        self.send_status(client, request, C.STATUS_OK, stream_id)

    def delete_object(self, client: ClientProxy, object_id: int) -> None:
        """Delete an object after its own children (a participant's topics and groups, a group's
        writers or readers). Not the writers and readers that use a topic: eProsima's agent
        leaves them, and rmw_microxrcedds deletes a publisher's TOPIC before its DATAWRITER (a
        cascade answered that DELETE DATAWRITER with ERR_UNKNOWN_REFERENCE, and rcl_publisher_fini
        failed). A writer keeps its middleware entity until it is deleted itself."""
        children = [oid for oid, e in client.objects.items()
                    if oid != object_id and e.parent == object_id]
        for child in children:
            if child in client.objects:
                self.delete_object(client, child)
        entry = client.objects.get(object_id)
        if entry is None:
            return
        if log.isEnabledFor(logging.INFO):  # its parents are still there to be named
            log.info("%s", words.object_line("deleted", client, entry))
        del client.objects[object_id]
        client.blocked_readers.discard(object_id)
        if entry.reader is not None:
            client.queued_bytes -= sum(len(sample) for sample in entry.reader.queue)
            entry.reader.queue.clear()
        if client.fast is not None:  # the compiled path lets go of the publisher first
            client.fast.forget_writer(client, object_id)
        for fastpath in self.fastpaths:  # and of the subscription (on whichever link took it)
            fastpath.forget_reader(client, object_id)
        try:
            self.middleware.delete(client.entity(object_id))
        except Exception:
            log.warning("middleware failed to delete %r", client.entity(object_id), exc_info=True)


    def delete_all(self, client: ClientProxy) -> None:
        """Every object of a client being deleted: participants first (with their children),
        then whatever is left."""
        for object_id in [oid for oid, e in client.objects.items() if e.parent is None]:
            if object_id in client.objects:
                self.delete_object(client, object_id)
        for object_id in list(client.objects):
            self.delete_object(client, object_id)


def _log_refusal(client: ClientProxy, kind: int, object_id: int, status: int) -> None:
    if log.isEnabledFor(logging.DEBUG):
        log.debug("client %s: %s %s not created: %s", client.key.hex(), words.kind_name(kind),
                  object_id_text(object_id), wire_names.STATUS_NAMES.get(status, status))


def _xml():
    # XML representations load with the first XML request: clients creating their entities in
    # binary (eProsima's C client with binary creation, xrce.client) never pay for it (~0.1 MB).
    from xrce.agent.engine import xmlrep

    return xmlrep


def _binary_qos(qos, writer: bool) -> EndpointQosSpec:
    if qos is None:
        return WRITER_DEFAULTS if writer else READER_DEFAULTS
    durability = "volatile"
    for flag, name in _DURABILITY_FLAGS:
        if qos.flags & flag:
            durability = name
            break
    return EndpointQosSpec(reliable=qos.reliable, keep_last=qos.keep_last,
                           depth=qos.history_depth or 1, durability=durability)


def _queue_bound(qos: EndpointQosSpec) -> int:
    return max(1, qos.depth) if qos.keep_last else MAX_QUEUE_KEEP_ALL


def _domain_override() -> int:
    value = os.environ.get("XRCE_DOMAIN_ID_OVERRIDE")
    try:
        return int(value) if value is not None else 0
    except ValueError:
        log.warning("XRCE_DOMAIN_ID_OVERRIDE=%r is not a number, using domain 0", value)
        return 0
