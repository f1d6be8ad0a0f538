"""All the clients: who they are (``ClientTable``, with the clients of each host in a ``HostRecord``)
and the bytes their buffers hold (``MemoryBudget``)."""

from __future__ import annotations

import math
from typing import Any, Dict, Hashable, Optional, Set, Tuple

from xrce.agent.engine.client import ClientProxy
from xrce.agent.engine.link import Link


class ClientTable:
    """Who the clients are: ``clients`` (key → ClientProxy), ``endpoints`` ((link, endpoint) →
    key, for sessions without a key in their headers, ≥ 0x81), the endpoints closed under such a
    session (``closed_endpoints``: the next CREATE there replaces it) and the clients of each
    host (``hosts``: ``client_host`` → HostRecord, what the retirement rule looks at).

    ``Sessions`` changes it; the dispatcher and the data path look clients up in it (the dicts
    stay the same objects for the agent's life, so a hot path binds them once)."""

    def __init__(self):
        self.clients: Dict[bytes, ClientProxy] = {}
        self.endpoints: Dict[Tuple[Any, Hashable], bytes] = {}
        self.closed_endpoints: Dict[Tuple[Any, Hashable], bytes] = {}
        self.hosts: Dict[Hashable, HostRecord] = {}

    def at(self, link: Link, endpoint: Hashable) -> Optional[ClientProxy]:
        """The session without a key bound to ``endpoint`` on ``link``, if any."""
        key = self.endpoints.get((link, endpoint))
        return self.clients.get(key) if key is not None else None


class MemoryBudget:
    """The bytes the clients' buffers hold, per client (``ClientProxy.buffered`` and
    ``queued_bytes``) and in all (``buffered_total``, ``queued_total``), against
    ``max_client_bytes`` and ``max_total_bytes`` (see MAX_CLIENT_BYTES)."""

    def __init__(self, max_client_bytes: int, max_total_bytes: int):
        self.max_client_bytes = max_client_bytes
        self.max_total_bytes = max_total_bytes
        self.buffered_total = 0  # the clients' ClientProxy.buffered, summed
        self.queued_total = 0  # the clients' ClientProxy.queued_bytes, summed
        self.trim_due = False  # clients holding buffers were deleted (see Agent._tick_locked)

    def charge(self, client: ClientProxy, delta: int) -> None:
        if client.alive:  # a deleted client gave all its bytes back at once
            client.buffered += delta
            self.buffered_total += delta

    def over(self, client: ClientProxy, extra: int) -> bool:
        """True if ``extra`` more bytes for ``client`` would exceed its budget or the agent's."""
        return client.buffered + client.queued_bytes + extra > self.max_client_bytes or \
            self.buffered_total + self.queued_total + extra > self.max_total_bytes


class HostRecord:
    """The clients of one host (``client_host``), and when the latest new one was created."""

    __slots__ = ("members", "born_at")

    def __init__(self):
        self.members: Set[ClientProxy] = set()
        self.born_at = -math.inf
