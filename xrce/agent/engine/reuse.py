"""REUSE: whether a CREATE describes the object a client already has (XRCE-WIRE.md §5).

eProsima's agent answers a CREATE with REUSE for an existing object by comparing what the new
representation means with what the object is, never the bytes it came in:

- a publisher or subscriber always matches (eProsima's groups have no comparison at all);
- binary: the decoded representation. Fields and their "present" flags count; CDR alignment
  padding does not (rmw_microxrcedds leaves an XCDR alignment byte of a datawriter's QoS
  uninitialised, so the same firmware sends other bytes after every reset);
- XML and reference: the snippet parsed as the object would be created from it (a reference is
  its profile's XML): participant name and domain, topic name and type, a writer's or reader's
  topic and QoS, a service's names and types.

A representation that no longer parses (a reference whose profile is gone, broken XML) matches
nothing. The parent (or a participant's domain) must be the same too.

Behind a middleware that routes by the strings themselves (CED, ``Middleware.routed_name``), only
names count, as eProsima's CED compares: a participant's domain, a topic's name, the name of a
writer's or reader's topic, in any representation, whatever the parent.
"""

from __future__ import annotations

from typing import Any, Dict, Tuple

from xrce.wire import constants as C
from xrce.agent.middleware import XmlRepresentationError
from xrce.wire.objects import with_kind

# What an ObjectEntry keeps of its CREATE: (format, representation as decoded, tail).
Representation = Tuple[int, Any, int]

_TEXT_FORMATS = (C.REPRESENTATION_AS_XML_STRING, C.REPRESENTATION_BY_REFERENCE)
_NOTHING = object()  # the meaning of a representation that does not parse: equal to nothing


def representation_of(request) -> Representation:
    return (request.fmt, request.representation, request.tail_id)


def matches(kind: int, existing, request, refs: Dict[str, str], objects=None,
            routed_name=None) -> bool:
    """True when ``request`` (a CREATE of an object of ``kind`` that exists) describes
    ``existing`` (its ObjectEntry). ``routed_name``: the middleware's (Middleware.routed_name);
    where it reads strings as names (CED), names are compared, as eProsima's CED compares them."""
    if kind in (C.OBJK_PUBLISHER, C.OBJK_SUBSCRIBER):
        return True
    if routed_name is not None and routed_name("participant", "") is not None:
        return _same_routed_name(kind, existing, request, objects or {}, routed_name)
    fmt, representation, tail = existing.signature
    if tail != request.tail_id:
        return False
    if fmt == C.REPRESENTATION_IN_BINARY or request.fmt == C.REPRESENTATION_IN_BINARY:
        # Decoded blobs compare field by field (xrce.wire.objects), absent fields as None.
        return fmt == request.fmt and representation == request.representation
    if fmt == request.fmt == C.REPRESENTATION_AS_XML_STRING and \
            representation == request.representation:
        return True  # the same text means the same (a reference's profile may have changed)
    old = _meaning(kind, fmt, representation, refs)
    return old is not _NOTHING and old == _meaning(kind, request.fmt, request.representation, refs)


def _same_routed_name(kind: int, existing, request, objects, routed_name) -> bool:
    """eProsima's CED: a participant matches by its domain alone; a topic by its name, a writer or
    reader by its topic's name, whichever representation either came in and whatever the parent."""
    if kind == C.OBJK_PARTICIPANT:
        return existing.signature[2] == request.tail_id
    old_name = existing.topic_spec.name if existing.topic_spec is not None else None
    rep = request.representation
    if request.fmt != C.REPRESENTATION_IN_BINARY:
        word = {C.OBJK_TOPIC: "topic", C.OBJK_DATAWRITER: "datawriter",
                C.OBJK_DATAREADER: "datareader"}.get(kind)
        return word is not None and routed_name(word, rep) == old_name
    if kind == C.OBJK_TOPIC:
        return rep.topic_name == old_name
    if kind in (C.OBJK_DATAWRITER, C.OBJK_DATAREADER):
        topic = objects.get(with_kind(rep.topic_id, C.OBJK_TOPIC))
        return topic is not None and topic.topic_spec is not None and \
            topic.topic_spec.name == old_name
    # Requesters and repliers (eProsima's CED has none): the representation as decoded.
    fmt, representation, tail = existing.signature
    return (fmt, representation, tail) == (request.fmt, rep, request.tail_id)


def _meaning(kind: int, fmt: int, text: str, refs: Dict[str, str]):
    from xrce.agent.engine import xmlrep  # loaded with the first XML request only (see objects._xml)

    if fmt == C.REPRESENTATION_BY_REFERENCE:
        name, text = text, refs.get(text)
        if text is None:
            return _NOTHING
    try:
        if kind == C.OBJK_PARTICIPANT:
            parsed = xmlrep.parse_participant(text)
            # Named as the registry names it: the profile name stands in for a missing name.
            name = parsed.name or (name if fmt == C.REPRESENTATION_BY_REFERENCE else "")
            return (name, parsed.domain_id)
        if kind == C.OBJK_TOPIC:
            return xmlrep.parse_topic(text)
        if kind in (C.OBJK_DATAWRITER, C.OBJK_DATAREADER):
            parsed = xmlrep.parse_endpoint(text, kind == C.OBJK_DATAWRITER)
            return (parsed.topic.name, parsed.qos)
        if kind in (C.OBJK_REQUESTER, C.OBJK_REPLIER):
            return xmlrep.parse_service(
                text, "requester" if kind == C.OBJK_REQUESTER else "replier")
    except XmlRepresentationError:
        return _NOTHING
    return _NOTHING
