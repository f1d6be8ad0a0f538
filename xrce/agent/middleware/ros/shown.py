"""What the operator is shown of the ROS entities behind a board's objects: ``ros_entity``, the
entity in a user's words, and (issue 53, "seen by the operator") ``given_names``, the names the
agent gave a board where they may not be the board's. The engine keeps both in each object's
``info`` for the ``-v 4`` lines, ``xrce-agent stats`` and ``/diagnostics``
(``xrce.agent.observe.entities``).

The board's own names are what the engine already holds (the participant's name and domain, the
topic and service names of its CREATEs); this module adds what ROS was given instead and which
rule gave it, so that observe can show both side by side.
"""

from __future__ import annotations

from xrce.agent.middleware import EntityKey


def board_namespace(naming, given_namespace: str) -> str:
    """The namespace a board gave its node, from the one ``naming`` made of it
    (``Naming.node_namespace``: the agent's namespace followed by the board's)."""
    prefix = naming.namespace
    if prefix == "/":
        return given_namespace
    if given_namespace == prefix:
        return "/"
    if given_namespace.startswith(prefix + "/"):
        return given_namespace[len(prefix):]
    return given_namespace  # not made by this naming: nothing to undo


def _qualified(namespace: str, name: str) -> str:
    return ("" if namespace == "/" else namespace) + "/" + name


def naming_words(naming) -> dict:
    """A ``Naming`` as the stats and /diagnostics show it."""
    return {"namespace": naming.namespace, "remaps": ["%s -> %s" % (source, naming.name(source))
                                                      for source in naming.remaps]}


class ShownEntities:
    """``ros_entity`` and ``given_names`` of the ROS middleware's entities, read from its
    ``EntityRecords`` (``records``)."""

    def __init__(self, records):
        self._records = records

    def ros_entity(self, key: EntityKey) -> str | None:
        record = self._records.get(key)
        if record is None:
            return None
        if record.kind == "participant":
            return "node " + record.node.get_fully_qualified_name()
        participant = self._records.participant_record(record)
        if participant is None:
            return None
        node = participant.node.get_fully_qualified_name()
        if record.kind == "datawriter":
            return "publisher %s of node %s" % (record.publisher.topic_name, node)
        if record.kind == "datareader":
            return "subscription %s of node %s" % (record.subscription.topic_name, node)
        if record.kind == "requester":
            return "service client %s of node %s" % (record.client.srv_name, node)
        if record.kind == "replier":
            return "service server %s of node %s" % (record.service.srv_name, node)
        return None

    def given_names(self, key: EntityKey) -> dict | None:
        """What ROS was given for the entity where it may not be what the board asked for:

        - a participant: ``rule`` (the fleet rule's name, None for the command line's naming),
          ``node`` (its fully qualified name in ROS), ``board_node`` (the one the board asked
          for), ``domain`` (the ROS domain it is in), ``namespace`` and ``remaps`` (``FROM -> TO``);
        - an endpoint: ``rule`` and ``name``, the ROS topic or service name it has.

        None where nothing can differ: a participant left to the board's names and domain by the
        command line, its endpoints, and everything that is not a ROS entity."""
        record = self._records.get(key)
        if record is None:
            return None
        participant = record if record.kind == "participant" else \
            self._records.participant_record(record)
        if participant is None or participant.node is None:
            return None
        naming = participant.naming
        if participant.rule is None and not naming.changes_names and naming.domain is None:
            return None
        if record.kind == "participant":
            node = record.node
            given = dict(rule=record.rule, node=node.get_fully_qualified_name(),
                         board_node=_qualified(board_namespace(naming, node.get_namespace()),
                                               node.get_name()),
                         domain=record.domain.domain_id)
            given.update(naming_words(naming))
            return given
        if record.kind == "datawriter":
            name = record.publisher.topic_name
        elif record.kind == "datareader":
            name = record.subscription.topic_name
        elif record.kind == "requester":
            name = record.client.srv_name
        elif record.kind == "replier":
            name = record.service.srv_name
        else:
            return None
        return {"rule": participant.rule, "name": name}
