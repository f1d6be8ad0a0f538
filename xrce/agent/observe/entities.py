"""A client's XRCE objects in words: the ``-v 4`` line for every object created or deleted
(``xrce.agent.engine.objects``, in the spirit of eProsima's ``MicroXRCEAgent -v 4``) and the
participants and endpoints a client shows in the stats (``xrce.agent.observe.observability``).

Each ``ObjectEntry`` carries ``info``, filled when it is created: a participant its name, ROS
domain and node; a topic nothing (its ``topic_spec`` says it); an endpoint its QoS; every entity
the ROS entity it became (``Middleware.ros_entity``). Topics and types are shown as ROS tools
name them, the DDS spelling beside them where it differs.
"""

from __future__ import annotations

from xrce.wire import constants as C
from xrce.wire.names import OBJECT_KIND_NAMES
from xrce.agent.observe.names import object_id_text, qos_text, ros_topic_name, ros_type_name

DIRECTIONS = {C.OBJK_DATAWRITER: "to_ros", C.OBJK_DATAREADER: "from_ros",
              C.OBJK_REQUESTER: "service_client", C.OBJK_REPLIER: "service_server"}
_SERVICE_SUFFIXES = ("_Request", "_Response")


def kind_name(kind: int) -> str:
    return OBJECT_KIND_NAMES.get(kind, "object kind %d" % kind).lower()


def participant_of(client, entry):
    """The participant entry above ``entry`` (itself for a participant), or None."""
    for _ in range(3):  # endpoint -> group -> participant
        if entry is None or entry.kind == C.OBJK_PARTICIPANT:
            break
        entry = client.objects.get(entry.parent) if entry.parent is not None else None
    return entry if entry is not None and entry.kind == C.OBJK_PARTICIPANT else None


def _service_type(dds_type: str) -> str:
    name = ros_type_name(dds_type)
    for suffix in _SERVICE_SUFFIXES:
        if name.endswith(suffix):
            return name[:-len(suffix)]
    return name


def describe(client, entry) -> dict:
    """What the stats show of one participant or endpoint (None for other kinds)."""
    info = entry.info or {}
    row = {"object_id": object_id_text(entry.object_id), "kind": kind_name(entry.kind)}
    if entry.kind == C.OBJK_PARTICIPANT:
        row.update(name=info.get("name"), domain=info.get("domain"), node=info.get("ros"))
        return row
    participant = participant_of(client, entry)
    row["domain"] = (participant.info or {}).get("domain") if participant is not None else None
    service = info.get("service")
    if service is not None:
        row.update(direction=DIRECTIONS[entry.kind], service=service.get("name"),
                   type=service.get("type"))
    elif entry.topic_spec is not None:
        spec = entry.topic_spec
        row.update(direction=DIRECTIONS.get(entry.kind), topic=ros_topic_name(spec.name),
                   dds_topic=spec.name, type=ros_type_name(spec.type_name),
                   dds_type=spec.type_name)
    if "qos" in info:
        row["qos"] = qos_text(info["qos"])
    row["ros"] = info.get("ros")
    row["samples"] = entry.samples
    if info.get("mismatches"):
        row["mismatches"] = list(info["mismatches"])
    return row


def service_info(spec) -> dict:
    """A requester's or replier's ``info["service"]`` from its ``ServiceSpec``."""
    if spec.request_topic:
        name = ros_topic_name(spec.request_topic)
    else:
        name = spec.service_name if spec.service_name.startswith("/") else "/" + spec.service_name
    return {"name": name, "type": _service_type(spec.request_type)}


def object_line(verb: str, client, entry) -> str:
    """``client 446c4acc: created datawriter 0x001(5) in publisher 0x001(3): topic /chatter
    (DDS rt/chatter), type std_msgs/msg/String, ROS domain 0, QoS reliable, volatile,
    keep_last 10 -> publisher /chatter of node /talker``: one object, as the client made it."""
    head = "client %s: %s %s %s" % (client.key.hex(), verb, kind_name(entry.kind),
                                    object_id_text(entry.object_id))
    if entry.parent is not None:
        head += " in %s %s" % (kind_name(entry.parent & 0x0F), object_id_text(entry.parent))
    info = entry.info or {}
    details = []
    if entry.kind == C.OBJK_PARTICIPANT:
        details.append("name %r, ROS domain %s" % (info.get("name"), info.get("domain")))
    else:
        service = info.get("service")
        if service is not None:
            details.append("service %s, type %s" % (service["name"], service["type"]))
        elif entry.topic_spec is not None and entry.kind != C.OBJK_PUBLISHER \
                and entry.kind != C.OBJK_SUBSCRIBER:
            spec = entry.topic_spec
            topic, type_name = ros_topic_name(spec.name), ros_type_name(spec.type_name)
            details.append("topic %s%s, type %s%s" % (
                topic, "" if topic == spec.name else " (DDS %s)" % spec.name,
                type_name, "" if type_name == spec.type_name else " (DDS %s)" % spec.type_name))
        if entry.kind in DIRECTIONS:
            participant = participant_of(client, entry)
            if participant is not None:
                details.append("ROS domain %s" % (participant.info or {}).get("domain"))
        if "qos" in info:
            details.append("QoS " + qos_text(info["qos"]))
    line = head + (": " + ", ".join(details) if details else "")
    if info.get("ros"):
        line += " -> " + info["ros"]
    return line


# ------------------------------------------------------------------ a client's row, as text

def nodes_text(row: dict) -> str:
    """A stats client row's participants: ``/talker (domain 0), /listener (domain 3)``."""
    return ", ".join("%s (domain %s)" % ((p["node"] or "").replace("node ", "", 1) or p["name"],
                                         p["domain"]) for p in row.get("participants", ()))


def endpoints_text(row: dict) -> str:
    """A stats client row's endpoints: ``/chatter std_msgs/msg/String to_ros``, ...."""
    return ", ".join("%s %s %s" % (e.get("topic") or e.get("service"), e.get("type"),
                                   e.get("direction")) for e in row.get("endpoints", ()))
