"""The agent-wide counters (``AgentStats``), as ``xrce.agent.observe`` shows them."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Dict


@dataclass
class AgentStats:
    messages_in: int = 0
    messages_out: int = 0
    bytes_in: int = 0
    bytes_out: int = 0
    decode_errors: int = 0
    dropped: int = 0  # whole input messages not processed (malformed, unknown client, stale)
    handler_errors: int = 0  # unexpected exceptions while handling a message
    duplicates: int = 0
    retransmissions: int = 0
    heartbeats_out: int = 0
    acknacks_out: int = 0
    fragments_in: int = 0
    fragments_out: int = 0
    reassembly_overflows: int = 0
    oversize_dropped: int = 0  # best-effort output larger than the client's mtu
    status_lost: int = 0  # STATUS not sent (none since a reply waits for room in a full window)
    samples_in: int = 0
    samples_compiled: int = 0  # of samples_in, those the compiled UDP read published
    samples_out_compiled: int = 0  # of samples_out, those the compiled path sent to a board
    publish_errors: int = 0  # board samples the middleware refused to publish (either path)
    samples_out: int = 0
    samples_overwritten: int = 0  # reader queue full: oldest sample dropped
    clients_created: int = 0
    clients_deleted: int = 0
    clients_dead: int = 0  # times a client went silent for client_dead_time
    clients_revived: int = 0  # dead clients that spoke again
    clients_expired: int = 0  # silent for client_expire_time: deleted with their entities
    clients_replaced: int = 0  # deleted at once: a new key took over their endpoint
    clients_retired: int = 0  # dead and certainly gone (a newer client on their host, or closed)
    clients_refused: int = 0  # CREATE_CLIENT beyond max_clients with no dead client to evict
    endpoints_closed: int = 0  # TCP connections / serial ports that went away under a session
    quota_objects: int = 0  # CREATE refused with ERR_RESOURCES
    quota_output_dropped: int = 0  # samples dropped because a client's output queue was full
    budget_refused: int = 0  # reliable input left unacknowledged: the memory budget was spent
    clients_evicted: int = 0  # idle sessions (no objects) deleted to admit a new client
    nested_fragments: int = 0  # reassembled messages holding FRAGMENTs again: dropped
    sources_refused: int = 0  # datagrams from outside --allow-from, dropped before any lookup
    mismatches: int = 0  # board/ROS endpoint pairs that cannot talk, each warned once (objects.py)

    def as_dict(self) -> Dict[str, int]:
        return {f.name: getattr(self, f.name) for f in fields(self)}
