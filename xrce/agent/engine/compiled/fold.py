"""What the compiled path counted in C, moved into the Python parts' counters (``CounterFold``).

C's receive thread never wakes Python to count: it keeps its own totals of what it took in,
published, acknowledged and sent, per link, per client, per writer and per reader, and the bytes
of the reassemblies it holds. ``CounterFold.fold`` takes them from the receiver and adds them to
the engine's statistics, the link's, the clients' (with when C last heard each, what liveliness
judges) and the entries', charges the reassemblies to the clients' budgets and asks for the
ACKNACKs of reliable streams C moved. ``FastPath`` folds whenever Python runs for the link (a
hand-over, the engine's timed work, a read of the statistics, a client or reader let go of).
"""

from __future__ import annotations

import logging
import time
from typing import Callable, Dict

log = logging.getLogger("xrce.agent")


class CounterFold:
    """Moves C's counters into the engine's, the link's, the clients' and the entries'.

    Collaborators: ``receiver`` (the extension's, whose totals are taken), ``link`` (its name and
    statistics), ``clients`` and ``readers`` (the compiled path's: C's handle -> ClientProxy,
    C's reader token -> (ClientProxy, object id)), ``repliers`` (the tokens of those readers that
    are repliers), ``support`` (the middleware's count of requests that expired in C), ``acks``,
    ``budget``, ``stats`` and ``clock`` (the engine's; ``FastPath.clock`` sets it again).
    """

    def __init__(self, receiver, link, clients: Dict[int, object], readers: Dict[int, tuple],
                 repliers: set, support, acks, budget, stats, clock: Callable[[], float]):
        self.receiver = receiver
        self.link = link
        self.clients = clients
        self.readers = readers
        self.repliers = repliers
        self.support = support
        self.acks = acks
        self.budget = budget
        self.stats = stats
        self.clock = clock

    def fold(self) -> None:
        """Take C's counters and add them where Python keeps them."""
        traffic, clients, writers, acks = self.receiver.fold()
        acknacks = traffic[5]
        self._fold_traffic(traffic)
        reliable = self.receiver.fold_reliable()
        if reliable is not None:
            self._fold_reassembly(*reliable)
        sent = self.receiver.fold_readers()
        if sent is not None:
            self._fold_readers(*sent)
        if self.repliers:
            expired = self.receiver.take_expired()
            if expired:
                self.support.count_timed_out_requests(expired)
                log.warning("%s: %d service requests got no reply from their XRCE client within "
                            "%.1f s", self.link.name, expired, self.support.request_timeout_s)
        self._fold_clients(clients, acknacks)
        for handle, object_id, count, size in writers:
            client = self.clients.get(handle)
            entry = client.objects.get(object_id) if client is not None else None
            if entry is not None:
                entry.samples += count
                entry.sample_bytes += size
        for handle, stream_id in acks:  # as DataPath.fast_write after a reliable sample
            client = self.clients.get(handle)
            stream = client.in_reliable.get(stream_id) if client is not None else None
            if stream is not None and client.alive:
                self.acks.acknack_soon(client, stream)

    def _fold_traffic(self, traffic: tuple) -> None:
        """The messages C took in and sent (ACKNACKs, replies) into the engine's and the link's
        counters; a failed publish is said."""
        (messages, size, samples, stale, publish_errors, acknacks, acknack_bytes, replies,
         reply_bytes) = traffic
        link_stats = self.link.stats
        if acknacks or replies:
            stats = self.stats
            stats.acknacks_out += acknacks
            stats.messages_out += acknacks + replies
            stats.bytes_out += acknack_bytes + reply_bytes
            link_stats.messages_out += acknacks + replies
            link_stats.bytes_out += acknack_bytes + reply_bytes
        if messages:
            stats = self.stats
            stats.messages_in += messages
            stats.bytes_in += size
            stats.samples_in += samples
            stats.samples_compiled += samples
            stats.dropped += stale
            link_stats.messages_in += messages
            link_stats.bytes_in += size
        if publish_errors:
            self.stats.publish_errors += publish_errors
            log.warning("%s: %d samples could not be published", self.link.name, publish_errors)

    def _fold_reassembly(self, fragments: int, charges) -> None:
        """FRAGMENTs C took; the reassembly it holds counts against each client's budget."""
        self.stats.fragments_in += fragments
        for handle, size in charges:
            client = self.clients.get(handle)
            if client is not None:
                self.budget.charge(client, size)

    def _fold_readers(self, totals: tuple, rows) -> None:
        """Samples C sent to boards' readers: the engine's, the link's and each reader's counts."""
        samples, count, size = totals
        stats = self.stats
        stats.samples_out += samples
        stats.samples_out_compiled += samples
        stats.messages_out += count
        stats.bytes_out += size
        self.link.stats.messages_out += count
        self.link.stats.bytes_out += size
        for token, object_id, samples, sample_bytes, _count, _size in rows:
            reader = self.readers.get(token)
            entry = reader[0].objects.get(object_id) if reader is not None else None
            if entry is not None:
                entry.samples += samples
                entry.sample_bytes += sample_bytes

    def _fold_clients(self, clients, acknacks: int) -> None:
        """Each client's traffic through C, and when C last heard it (what liveliness judges)."""
        # C's clock is time.monotonic's; a test's substitute clock never sees compiled traffic.
        clock = self.clock
        offset = clock() - time.monotonic() if clock is not time.monotonic else 0.0
        for handle, count, size, seen_ns, count_out, size_out, skew_ns in clients:
            client = self.clients.get(handle)
            if client is None:
                continue
            client.messages_out += count_out
            client.bytes_out += size_out
            if skew_ns is not None:
                client.timestamp_skew_ns = skew_ns
            if not count:
                continue
            client.messages_in += count
            client.bytes_in += size
            client.probes = 0
            if acknacks and client.acknacks_sent:
                # C acknowledged this client's messages itself: the last ACKNACK Python recorded
                # is no longer the last sent, so its pending repeats are void and the next one
                # Python sends counts from C's (liveliness.Acknowledgments.send_acknack).
                client.acknacks_sent.clear()
            seen = seen_ns / 1e9 + offset
            if seen > client.last_seen:
                client.last_seen = seen

