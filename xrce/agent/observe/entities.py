"""A client's XRCE objects in words: the ``-v 4`` line for every object created or deleted
(``xrce.agent.engine.objects``, in the spirit of eProsima's ``MicroXRCEAgent -v 4``) and the
participants and endpoints a client shows in the stats (``xrce.agent.observe.observability``).

Each ``ObjectEntry`` carries ``info``, filled when it is created: a participant its name, ROS
domain and node; a topic nothing (its ``topic_spec`` says it); an endpoint its QoS; every entity
the ROS entity it became (``Middleware.ros_entity``). Topics and types are shown as ROS tools
name them, the DDS spelling beside them where it differs.

Where the agent names a board's entities otherwise than the board did (a namespace, remaps,
another domain, a fleet rule: issue 53), ``info["given"]`` holds what ROS was given
(``Middleware.given_names``) and every view shows the board's name beside it and the rule that
gave it: ``topic /cmd_vel (DDS rt/cmd_vel) -> /robot1/cmd_vel_safe (rule robot1)`` at ``-v 4``,
``board_*`` fields beside the ROS ones in the stats. Entities whose names are kept look as before.
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


def rule_text(rule) -> str:
    """Which naming gave a board its names: a fleet rule's name, or the command line's."""
    return "command line" if rule is None else "rule " + rule


def ros_domain(participant) -> int | None:
    """The ROS domain a participant entry's node is in: the agent's ``--domain`` or a rule's
    where one was given, else the one the board asked for."""
    if participant is None:
        return None
    info = participant.info or {}
    given = info.get("given")
    return given["domain"] if given is not None else info.get("domain")


def given_name(entry, board_name: str | None) -> str | None:
    """The ROS name the agent gave an endpoint whose board named it ``board_name``, None where
    it is the board's (a DDS-level topic's name may lack the leading slash ROS shows)."""
    given = (entry.info or {}).get("given")
    if given is None or board_name is None:
        return None
    name = given.get("name")
    if name is None or name == board_name or name == "/" + board_name:
        return None
    return name


def describe(client, entry) -> dict:
    """What the stats show of one participant or endpoint (None for other kinds). ``domain``,
    ``node``, ``topic`` and ``service`` are what ROS has; where the agent named them otherwise
    than the board, the board's are beside them (``board_domain``, ``board_node``,
    ``board_topic``, ``board_service``) with the ``rule`` that did it."""
    info = entry.info or {}
    given = info.get("given")
    row = {"object_id": object_id_text(entry.object_id), "kind": kind_name(entry.kind)}
    if entry.kind == C.OBJK_PARTICIPANT:
        row.update(name=info.get("name"), domain=ros_domain(entry), node=info.get("ros"))
        if given is not None:
            row.update(rule=given["rule"], namespace=given["namespace"],
                       remaps=list(given["remaps"]))
            if given["board_node"] != given["node"]:
                row["board_node"] = "node " + given["board_node"]
            if given["domain"] != info.get("domain"):
                row["board_domain"] = info.get("domain")
        return row
    row["domain"] = ros_domain(participant_of(client, entry))
    service = info.get("service")
    if service is not None:
        row.update(direction=DIRECTIONS[entry.kind], service=service.get("name"),
                   type=service.get("type"))
        renamed = given_name(entry, service.get("name"))
        if renamed is not None:
            row.update(service=renamed, board_service=service.get("name"), rule=given["rule"])
    elif entry.topic_spec is not None:
        spec = entry.topic_spec
        row.update(direction=DIRECTIONS.get(entry.kind), topic=ros_topic_name(spec.name),
                   dds_topic=spec.name, type=ros_type_name(spec.type_name),
                   dds_type=spec.type_name)
        renamed = given_name(entry, row["topic"])
        if renamed is not None:
            row.update(topic=renamed, board_topic=ros_topic_name(spec.name), rule=given["rule"])
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
    given = info.get("given")
    details = []
    if entry.kind == C.OBJK_PARTICIPANT:
        details.append("name %r, ROS domain %s" % (info.get("name"), info.get("domain")))
        if given is not None:
            details[-1] += "" if given["domain"] == info.get("domain") else \
                " -> %s" % given["domain"]
            details.append(_naming_text(given))
    else:
        service = info.get("service")
        if service is not None:
            details.append("service %s%s, type %s" % (
                service["name"], _renamed_text(entry, service["name"]), service["type"]))
        elif entry.topic_spec is not None and entry.kind != C.OBJK_PUBLISHER \
                and entry.kind != C.OBJK_SUBSCRIBER:
            spec = entry.topic_spec
            topic, type_name = ros_topic_name(spec.name), ros_type_name(spec.type_name)
            details.append("topic %s%s%s, type %s%s" % (
                topic, "" if topic == spec.name else " (DDS %s)" % spec.name,
                _renamed_text(entry, topic),
                type_name, "" if type_name == spec.type_name else " (DDS %s)" % spec.type_name))
        if entry.kind in DIRECTIONS:
            participant = participant_of(client, entry)
            if participant is not None:
                details.append("ROS domain %s" % ros_domain(participant))
        if "qos" in info:
            details.append("QoS " + qos_text(info["qos"]))
    line = head + (": " + ", ".join(details) if details else "")
    if info.get("ros"):
        line += " -> " + info["ros"]
    return line


def _renamed_text(entry, board_name: str) -> str:
    """`` -> /robot1/cmd_vel_safe (rule robot1)`` where the agent gave the endpoint another name."""
    renamed = given_name(entry, board_name)
    if renamed is None:
        return ""
    return " -> %s (%s)" % (renamed, rule_text(entry.info["given"]["rule"]))


def _naming_text(given: dict) -> str:
    """A participant's naming on its ``-v 4`` line: ``rule robot1: namespace /robot1, remaps
    /cmd_vel -> /robot1/cmd_vel_safe, board's node /mcu_node``."""
    words = []
    if given["namespace"] != "/":
        words.append("namespace %s" % given["namespace"])
    if given["remaps"]:
        words.append("remaps " + "; ".join(given["remaps"]))
    if given["board_node"] != given["node"]:
        words.append("board's node %s" % given["board_node"])
    return rule_text(given["rule"]) + (": " + ", ".join(words) if words else "")


# ------------------------------------------------------------------ a client's row, as text

def _node_word(node) -> str:
    return (node or "").replace("node ", "", 1)


def nodes_text(row: dict) -> str:
    """A stats client row's participants: ``/talker (domain 0), /listener (domain 3)``; a node
    the agent named otherwise with the board's name and domain beside it:
    ``/robot1/talker (domain 7; board's /talker, domain 0)``."""
    texts = []
    for p in row.get("participants", ()):
        board = []
        if p.get("board_node"):
            board.append("board's " + _node_word(p["board_node"]))
        if "board_domain" in p:
            board.append("board's domain %s" % p["board_domain"] if not board
                         else "domain %s" % p["board_domain"])
        texts.append("%s (domain %s%s)" % (_node_word(p["node"]) or p["name"], p["domain"],
                                           "; " + ", ".join(board) if board else ""))
    return ", ".join(texts)


def endpoint_name_text(endpoint: dict) -> str:
    """An endpoint's topic or service as ROS has it, the board's beside it where it differs:
    ``/robot1/cmd_vel_safe (board's /cmd_vel)``."""
    name = endpoint.get("topic") or endpoint.get("service")
    board = endpoint.get("board_topic") or endpoint.get("board_service")
    return name if board is None else "%s (board's %s)" % (name, board)


def endpoints_text(row: dict) -> str:
    """A stats client row's endpoints: ``/chatter std_msgs/msg/String to_ros``, ...."""
    return ", ".join("%s %s %s" % (endpoint_name_text(e), e.get("type"), e.get("direction"))
                     for e in row.get("endpoints", ()))


def client_rule(row: dict) -> str | None:
    """The rule that named a stats client row's board (the first participant's that has one)."""
    for p in row.get("participants", ()):
        if p.get("rule") is not None:
            return p["rule"]
    return None


def client_naming(row: dict) -> list:
    """What /diagnostics says of a board's naming: (key, value) pairs ``rule``, ``namespace``,
    ``domain`` and ``remaps``; none for a board whose names and domain are its own."""
    named = [p for p in row.get("participants", ()) if "namespace" in p]
    if not named:
        return []
    return [("rule", rule_text(client_rule(row))),
            ("namespace", ", ".join(sorted({p["namespace"] for p in named}))),
            ("domain", ", ".join(str(d) for d in sorted({p["domain"] for p in named}))),
            ("remaps", "; ".join(sorted({r for p in named for r in p["remaps"]})))]
