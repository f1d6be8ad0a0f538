"""Fast DDS XML snippets and profile files as the agent reads them (XRCE-WIRE.md §4 "Representations").

Only what the engine hands to a middleware is extracted: participant name and domain, topic name and
type, endpoint QoS (reliability, durability, history) and the service description of a requester or
replier. Anything else in the XML is accepted and ignored, as the eProsima agent does for QoS it does
not map.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Dict, Optional

if TYPE_CHECKING:
    import xml.etree.ElementTree as ET

from xrce.agent.middleware import (  # noqa: F401 (the defaults and the error are named from here too)
    READER_DEFAULTS, WRITER_DEFAULTS, EndpointQosSpec, ServiceSpec, TopicSpec, XmlRepresentationError,
)

_DURABILITY = {
    "VOLATILE": "volatile",
    "TRANSIENT_LOCAL": "transient_local",
    "TRANSIENT": "transient",
    "PERSISTENT": "persistent",
}


@dataclass(frozen=True)
class ParticipantXml:
    name: str
    domain_id: Optional[int]


@dataclass(frozen=True)
class EndpointXml:
    topic: TopicSpec
    qos: EndpointQosSpec


def _parse(text: str) -> Optional[ET.Element]:
    # Imported on first use: ElementTree and expat are 0.5 MB of the agent's resident memory,
    # and most clients (micro-ROS among them) create their entities from binary representations.
    import xml.etree.ElementTree as ET

    if not text.strip():
        return None
    try:
        return ET.fromstring(text)
    except ET.ParseError as exc:
        raise XmlRepresentationError("malformed XML: %s" % exc) from None


def _find(root: Optional[ET.Element], tag: str) -> Optional[ET.Element]:
    """The first element called ``tag``: the root itself or any descendant (snippets are wrapped in
    ``<dds>`` and sometimes ``<profiles>``)."""
    if root is None:
        return None
    if root.tag == tag:
        return root
    return root.find(".//" + tag)


def _text(element: Optional[ET.Element], path: str) -> Optional[str]:
    if element is None:
        return None
    found = element.find(path)
    if found is None or found.text is None:
        return None
    return found.text.strip()


def parse_participant(text: str) -> ParticipantXml:
    element = _find(_parse(text), "participant")
    if element is None:
        if text.strip():
            raise XmlRepresentationError("no <participant> element")
        return ParticipantXml(name="", domain_id=None)
    name = _text(element, "rtps/name") or _text(element, "name") or ""
    domain = _text(element, "domainId")
    try:
        domain_id = int(domain) if domain is not None else None
    except ValueError:
        raise XmlRepresentationError("domainId is not a number") from None
    return ParticipantXml(name=name, domain_id=domain_id)


def parse_topic(text: str) -> TopicSpec:
    element = _find(_parse(text), "topic")
    if element is None:
        if text.strip():
            raise XmlRepresentationError("no <topic> element")
        return TopicSpec(name="", type_name="")
    return TopicSpec(name=_text(element, "name") or "", type_name=_text(element, "dataType") or "")


def check_group(text: str, tag: str) -> None:
    """Publisher/subscriber XML carries nothing the engine uses; it only has to be well formed."""
    root = _parse(text)
    if root is not None and root.tag not in ("dds", "profiles", tag):
        raise XmlRepresentationError("no <%s> element" % tag)


def _qos(element: ET.Element, defaults: EndpointQosSpec) -> EndpointQosSpec:
    reliable = defaults.reliable
    durability = defaults.durability
    keep_last = defaults.keep_last
    depth = defaults.depth
    kind = _text(element, "qos/reliability/kind")
    if kind is not None:
        reliable = not kind.upper().startswith("BEST")
    kind = _text(element, "qos/durability/kind")
    if kind is not None:
        key = kind.upper()
        for suffix in ("_DURABILITY_QOS",):
            if key.endswith(suffix):
                key = key[: -len(suffix)]
        if key not in _DURABILITY:
            raise XmlRepresentationError("unknown durability %r" % kind)
        durability = _DURABILITY[key]
    # Fast DDS puts historyQos under <topic>; accept it under <qos> too.
    for base in ("topic/historyQos", "historyQos", "qos/historyQos"):
        history = element.find(base)
        if history is None:
            continue
        kind = _text(history, "kind")
        if kind is not None:
            keep_last = "ALL" not in kind.upper()
        text = _text(history, "depth")
        if text is not None:
            try:
                depth = int(text)
            except ValueError:
                raise XmlRepresentationError("history depth is not a number") from None
        break
    return EndpointQosSpec(reliable=reliable, keep_last=keep_last, depth=max(depth, 1),
                           durability=durability)


def parse_endpoint(text: str, writer: bool) -> EndpointXml:
    tag = "data_writer" if writer else "data_reader"
    element = _find(_parse(text), tag)
    if element is None:
        # Older Fast RTPS profile files call them publisher/subscriber.
        element = _find(_parse(text), "publisher" if writer else "subscriber")
    if element is None:
        raise XmlRepresentationError("no <%s> element" % tag)
    topic = TopicSpec(name=_text(element, "topic/name") or "",
                      type_name=_text(element, "topic/dataType") or "")
    if not topic.name:
        raise XmlRepresentationError("<%s> names no topic" % tag)
    return EndpointXml(topic=topic, qos=_qos(element, WRITER_DEFAULTS if writer else READER_DEFAULTS))


def parse_service(text: str, tag: str) -> ServiceSpec:
    """``tag`` is ``requester`` or ``replier``; fields may be attributes or child elements."""
    element = _find(_parse(text), tag)
    if element is None:
        raise XmlRepresentationError("no <%s> element" % tag)

    def field(name: str) -> Optional[str]:
        value = element.get(name)
        return value if value is not None else _text(element, name)

    service_name = field("service_name")
    request_type = field("request_type")
    reply_type = field("reply_type")
    if not service_name or not request_type or not reply_type:
        raise XmlRepresentationError("<%s> needs service_name, request_type and reply_type" % tag)
    return ServiceSpec(service_name=service_name, request_type=request_type, reply_type=reply_type,
                       request_topic=field("request_topic_name"), reply_topic=field("reply_topic_name"))


def refs_from_profiles(document) -> Dict[str, str]:
    """Profile name → the XML of that element alone, namespaces removed, for every element carrying
    a ``profile_name`` in a Fast DDS profiles file (the CLI's ``-r FILE``; ``document`` its bytes or
    text): what a reference representation names. Raises ``xml.etree.ElementTree.ParseError``
    when it is not XML."""
    import xml.etree.ElementTree as ET

    root = ET.fromstring(document)
    for node in root.iter():
        if isinstance(node.tag, str):
            node.tag = node.tag.rsplit("}", 1)[-1]
    refs: Dict[str, str] = {}
    for element in root.iter():
        name = element.get("profile_name")
        if name:
            element.tail = None
            refs[name] = ET.tostring(element, encoding="unicode")
    return refs
