"""Two boards given one ROS name where ROS wants one owner (issue 53, "seen by the operator").

Namespaces, remaps and fleet rules decide a board's names and domain
(``xrce.agent.middleware.ros.naming``); a bad one can put two boards' service servers on one
service of one ROS domain (a caller reaches either, at random) or two boards' nodes under one
fully qualified name there (ROS tools cannot tell them apart). One name in two domains is two
names: what giving robots domains of their own is for. Nothing
fails there: the agent says it, one WARNING per collision naming the service or node and both
boards (their keys, as the agent's log names clients, and the rule that named each). Publishers
and subscriptions sharing a topic are what topics are for and are not tracked.

Names are claimed when the entity is created and released when it is deleted (its participant's
deletion releases what is left of it), so a board that comes back does not collide with itself.
"""

from __future__ import annotations

from xrce.agent.middleware import EntityKey
from xrce.agent.middleware.ros.domain import log


def board_words(client_key: int, rule: str | None) -> str:
    """A board in a collision warning: ``client 0badc0de (rule robot1)``."""
    return "client %08x (%s)" % (client_key & 0xFFFFFFFF,
                                 "command-line naming" if rule is None else "rule " + rule)


_WHY = {
    "service": "service %s in ROS domain %d is served by two boards, %s and %s: a caller "
               "reaches either one. A remap or fleet rule gives both the same name",
    "node": "node %s in ROS domain %d is the name of two boards' nodes, %s and %s: ROS tools "
            "cannot tell them apart. A namespace, remap or fleet rule gives both the same name",
}


class NameClaims:
    """Which entities hold each given service and node name, by board."""

    def __init__(self):
        # (what, ROS domain, ROS name) -> {entity key: (participant key, board words)}
        self._holders: dict[tuple, dict] = {}
        self._claimed: dict[EntityKey, tuple] = {}  # entity key -> (what, domain, ROS name)
        self._by_participant: dict[EntityKey, set] = {}
        # (what, domain, name, {client keys}) already warned about: once each, however often
        # boards come and go
        self._warned: set = set()

    def claim(self, what: str, domain_id: int, name: str, key: EntityKey,
              participant: EntityKey, rule: str | None) -> None:
        claimed = (what, domain_id, name)
        holders = self._holders.setdefault(claimed, {})
        client_key = key[0]
        for other_participant, other_words in holders.values():
            other_client = other_participant[0]
            if other_client == client_key:
                continue
            pair = claimed + (frozenset((client_key, other_client)),)
            if pair not in self._warned:
                self._warned.add(pair)
                log.warning(_WHY[what], name, domain_id, other_words,
                            board_words(client_key, rule))
            break
        holders[key] = (participant, board_words(client_key, rule))
        self._claimed[key] = claimed
        self._by_participant.setdefault(participant, set()).add(key)

    def release(self, key: EntityKey) -> None:
        """Forget ``key``'s name, and its children's if it is a participant."""
        for held in [key, *self._by_participant.pop(key, ())]:
            claimed = self._claimed.pop(held, None)
            if claimed is None:
                continue
            holders = self._holders.get(claimed)
            if holders is not None:
                participant, _words = holders.pop(held, (None, None))
                if participant is not None and participant != held:
                    siblings = self._by_participant.get(participant)
                    if siblings is not None:
                        siblings.discard(held)
                if not holders:
                    del self._holders[claimed]


class NameCollisions:
    """The names claimed by the ROS middleware's entities (``records``: its ``EntityRecords``,
    where each claimant's participant is looked up)."""

    def __init__(self, records):
        self._records = records
        self._claims = NameClaims()

    def claim_node(self, key: EntityKey) -> None:
        record = self._records.get(key)
        self._claims.claim("node", record.domain.domain_id,
                           record.node.get_fully_qualified_name(), key, key, record.rule)

    def claim_service(self, key: EntityKey, participant: EntityKey, service_name: str) -> None:
        record = self._records.get(participant)
        self._claims.claim("service", record.domain.domain_id, service_name, key, participant,
                           record.rule)

    def release(self, key: EntityKey) -> None:
        self._claims.release(key)
