"""REUSE: whether a CREATE describes the object a client already has (XRCE-WIRE.md §5).

eProsima's agent answers a CREATE with REUSE for an existing object by comparing what the new
representation means with what the object is, never the bytes it came in:

- binary: the decoded representation. Fields and their "present" flags count; CDR alignment
  padding does not (rmw_microxrcedds leaves an XCDR alignment byte of a datawriter's QoS
  uninitialised, so the same firmware sends other bytes after every reset);
- XML and reference: the snippet parsed as the object would be created from it (a reference is
  its profile's XML): participant name and domain, topic name and type, a writer's or reader's
  topic and QoS, a service's names and types. A publisher or subscriber always matches (eProsima's
  groups have no comparison at all).

A representation that no longer parses (a reference whose profile is gone, broken XML) matches
nothing. The parent (or a participant's domain) must be the same too.
"""

from __future__ import annotations

from typing import Any, Dict, Tuple

from xrce.wire import constants as C
from xrce.agent.middleware import XmlRepresentationError

# What an ObjectEntry keeps of its CREATE: (format, representation as decoded, tail).
Representation = Tuple[int, Any, int]

_TEXT_FORMATS = (C.REPRESENTATION_AS_XML_STRING, C.REPRESENTATION_BY_REFERENCE)
_NOTHING = object()  # the meaning of a representation that does not parse: equal to nothing


def representation_of(request) -> Representation:
    return (request.fmt, request.representation, request.tail_id)


def matches(kind: int, stored: Representation, request, refs: Dict[str, str]) -> bool:
    """True when ``request`` (a CREATE of an object of ``kind`` that exists) describes the object
    created from ``stored``."""
    fmt, representation, tail = stored
    if tail != request.tail_id:
        return False
    if fmt == C.REPRESENTATION_IN_BINARY or request.fmt == C.REPRESENTATION_IN_BINARY:
        # Decoded blobs compare field by field (xrce.wire.objects), absent fields as None.
        return fmt == request.fmt and representation == request.representation
    if kind in (C.OBJK_PUBLISHER, C.OBJK_SUBSCRIBER):
        return True
    if fmt == request.fmt == C.REPRESENTATION_AS_XML_STRING and \
            representation == request.representation:
        return True  # the same text means the same (a reference's profile may have changed)
    old = _meaning(kind, fmt, representation, refs)
    return old is not _NOTHING and old == _meaning(kind, request.fmt, request.representation, refs)


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
