"""One client (``ClientProxy``) and what it holds: its XRCE objects (``ObjectEntry``), its readers'
READ_DATA state (``ReaderState``, ``ReadRequest``), a restored client's output stream until the board
says where it is (``ResumingStream``), and where it speaks from (``client_host``, ``client_origin``).
"""

from __future__ import annotations

import ipaddress
import logging
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable, Deque, Dict, Hashable, Optional, Set, Tuple

from xrce.wire import constants as C
from xrce.agent.engine.admission import endpoint_address
from xrce.agent.engine.limits import MIN_MTU, QUOTA_LOG_INTERVAL, STREAM_WINDOW
from xrce.agent.engine.link import Link
from xrce.agent.middleware import ClientOrigin, EntityKey, TopicSpec
from xrce.wire.streams import (
    InputBestEffortStream, InputReliableStream, OutputBestEffortStream, OutputReliableStream,
)

log = logging.getLogger("xrce.agent")


class ReadRequest:
    """An active READ_DATA: where to deliver and when to stop."""

    __slots__ = ("request_id", "stream_id", "remaining", "deadline", "rate", "tokens", "refilled",
                 "deadline_until_first")

    def __init__(self, request_id: int, stream_id: int, remaining: Optional[int],
                 deadline: Optional[float], rate: int, now: float,
                 deadline_until_first: bool = False):
        self.request_id = request_id
        self.stream_id = stream_id
        self.remaining = remaining  # None = unlimited
        self.deadline = deadline
        self.deadline_until_first = deadline_until_first  # the first sample lifts the deadline
        self.rate = rate  # bytes per second, 0 = unlimited
        self.tokens = float(rate)
        self.refilled = now


class ReaderState:
    __slots__ = ("queue", "active")

    def __init__(self, bound: int):
        self.queue: Deque[bytes] = deque(maxlen=bound)
        self.active: Optional[ReadRequest] = None


@dataclass
class ObjectEntry:
    object_id: int
    kind: int
    parent: Optional[int]
    signature: Tuple[int, Any, int]  # (format, decoded representation, tail): xrce.agent.engine.reuse
    topic: Optional[int] = None  # the topic object a writer/reader uses
    topic_spec: Optional[TopicSpec] = None
    reader: Optional[ReaderState] = None
    samples: int = 0  # written into the middleware (writers) or delivered to the client (readers)
    sample_bytes: int = 0
    # Writers: the middleware's publish for this entity, looked up once (see DataPath.fast_write).
    write: Optional[Callable[[bytes], bool]] = None
    info: Optional[dict] = None  # what it is in words, for logs and stats (observe/entities.py)


class ClientProxy:
    """One client session: key, destination, streams and XRCE objects."""

    def __init__(self, key: bytes, session_id: int, mtu: int, link: Link, endpoint: Hashable,
                 now: float, hard_liveliness: Optional[float]):
        self.key = key
        self.key_int = int.from_bytes(key, "big")
        self.session_id = session_id
        self.header_key = key if session_id < C.SESSION_ID_WITHOUT_KEY_MASK else None
        self.mtu = max(mtu, MIN_MTU)
        self.link = link
        self.endpoint = endpoint
        self.last_seen = now
        self.hard_liveliness = hard_liveliness
        self.probes = 0
        self.dead = False  # silent for the dead time: no HEARTBEATs until it speaks again
        # The machine or device it speaks from (``client_host``) and whether its TCP connection
        # or serial port went away: what the retirement rule (xrce.agent.engine.liveliness) uses.
        self.host: Hashable = None
        self.closed = False
        self.queued_bytes = 0  # sample bytes waiting in this client's reader queues
        # Bytes of this client's other buffers (see MAX_CLIENT_BYTES); MemoryBudget.charge keeps it.
        self.buffered = 0
        self.quota_logged: Dict[str, float] = {}
        self.objects: Dict[int, ObjectEntry] = {}
        self.in_best_effort: Dict[int, InputBestEffortStream] = {}
        self.in_reliable: Dict[int, InputReliableStream] = {}
        # Per reliable input stream: the first_unacked of the last ACKNACK sent, how many repeats
        # of it are still allowed, and what the stream held and had seen twice then
        # (xrce.agent.engine.liveliness.Acknowledgments).
        self.acknacks_sent: Dict[int, list] = {}
        self.out_best_effort: Dict[int, OutputBestEffortStream] = {}
        self.out_reliable: Dict[int, OutputReliableStream] = {}
        self.reassembly: Dict[int, bytearray] = {}
        # Reliable output not yet sent, per stream: fragments of a sample longer than the window
        # has room for, sent as ACKNACKs free room (xrce.agent.engine.stream_output's
        # StreamOutput.send_pending).
        self.out_pending: Dict[int, Deque[bytes]] = {}
        self.blocked_readers: Set[int] = set()
        self.alive = True  # False once deleted: late middleware callbacks are ignored
        # While a CREATE waits for its type to be built: the messages to process afterwards, in
        # order, starting with the rest of the one that held the CREATE. None when not parked.
        self.parked: Optional[list] = None
        # xrce.agent.engine.compiled.client.CompiledClient while the UDP link's compiled path knows this client.
        self.fast: Any = None
        # Per-client counters for xrce.agent.observe.observability; plain ints so the hot path stays cheap.
        self.created_at = now
        self.messages_in = 0
        self.bytes_in = 0
        self.messages_out = 0
        self.bytes_out = 0
        self.decode_errors = 0
        self.duplicates = 0
        self.retransmissions = 0
        # The agent cannot know the client's clock offset; it can time HEARTBEAT -> ACKNACK and
        # see how far a client's TIMESTAMP is from its own clock on arrival (skew + one-way delay).
        self.heartbeat_sent_at: Optional[float] = None
        self.rtt_s: Optional[float] = None
        self.timestamp_skew_ns: Optional[int] = None
        # Restored from the state store by a restarted agent (xrce.agent.state.recorder): the
        # board does not know the agent went away. ``spoken``: it has sent something since.
        # ``resume_inputs``: its input streams start where the board's first message or
        # HEARTBEAT says (until its next CREATE_CLIENT). ``resuming``: its reliable output
        # streams still wait for the board's ACKNACK to say where they are (ResumingStream).
        self.restored = False
        self.spoken = False
        self.resume_inputs = False
        self.resuming = False
        # ``input_resync``: its own reliable output streams, which the agent must set going
        # again itself (xrce.agent.engine.resync.InputResync), None once they all are.
        self.input_resync: Any = None

    def entity(self, object_id: int) -> EntityKey:
        return (self.key_int, object_id)

    def warn_quota(self, quota: str, now: float, message: str, *args) -> None:
        """A WARNING that one of its quotas was hit, at most once per QUOTA_LOG_INTERVAL."""
        last = self.quota_logged.get(quota)
        if last is None or now - last >= QUOTA_LOG_INTERVAL:
            self.quota_logged[quota] = now
            log.warning("client %s: " + message, self.key.hex(), *args)

    def reset_streams(self) -> None:
        if self.fast is not None:  # its sequence numbers live in the compiled path
            self.fast.drop(self)
        self.in_best_effort.clear()
        self.in_reliable.clear()
        self.out_best_effort.clear()
        self.out_reliable.clear()
        self.reassembly.clear()
        self.out_pending.clear()
        self.blocked_readers.clear()

    def resume_output(self, acknack) -> None:
        """The board's ACKNACK says where a restored reliable output stream goes on
        (``ResumingStream``): a plain stream takes its place there; once none is left, the
        client is like any other (the compiled path may take it)."""
        stream = self.out_reliable.get(acknack.stream_id)
        if stream.__class__ is ResumingStream:
            self.out_reliable[acknack.stream_id] = ResumingStream.resumed_at(
                acknack.stream_id, STREAM_WINDOW, acknack.first_unacked)
            log.debug("client %s: output stream 0x%02X resumes at %d", self.key.hex(),
                      acknack.stream_id, acknack.first_unacked)
        self.resuming = any(s.__class__ is ResumingStream for s in self.out_reliable.values())

    def stream_bytes(self) -> int:
        """Bytes held by its streams (what ``reset_streams`` frees)."""
        return sum(s.stored_bytes for s in self.in_reliable.values()) + \
            sum(s.stored_bytes for s in self.out_reliable.values()) + \
            sum(len(b) for b in self.reassembly.values()) + \
            sum(len(m) for q in self.out_pending.values() for m in q)


class ResumingStream(OutputReliableStream):
    """A restored client's reliable output stream until the board says where it is.

    The board's input stream expects the sequence number after the last one the previous agent
    process sent, which this process cannot know (it is not stored per sample). eProsima's client
    ignores a HEARTBEAT's first sequence number, and answers every HEARTBEAT with an ACKNACK whose
    first unacknowledged number is exactly that one. So until that ACKNACK arrives this stream
    sends nothing (its window is "full": samples wait in their readers' queues, replies in
    ``out_pending``) and asks with ``heartbeat``; ``Agent`` then puts a plain stream starting
    there in its place (``resumed_at``).

    The HEARTBEAT names ``last`` (the number stored at the last checkpoint) as its last
    unacknowledged one, never one ahead of the board's: a board raises what it was announced to
    that, and would then count as missing every number up to it."""

    __slots__ = ()

    def __init__(self, stream_id: int, history: int, last: int):
        super().__init__(stream_id, history)
        self.last_sent = self.last_acknowledged = last & 0xFFFF

    def has_room(self):
        return False

    def next_seq(self):
        return None

    def heartbeat(self):
        return (self.last_sent + 1) & 0xFFFF, self.last_sent

    def on_acknack(self, first_unacked, nack_bitmap, now_ms=0, holdoff_ms=0, session=None):
        return ()

    def release(self) -> int:  # (the compiled streams' interface: nothing is held here)
        return 0

    def hold(self, held: bool) -> None:
        pass

    @staticmethod
    def resumed_at(stream_id: int, history: int, first_unacked: int) -> OutputReliableStream:
        """The plain stream that carries on from the board's ``first_unacked``."""
        stream = OutputReliableStream(stream_id, history)
        stream.last_sent = stream.last_acknowledged = (first_unacked - 1) & 0xFFFF
        return stream


def client_host(link: Link, endpoint: Hashable) -> Hashable:
    """Where a client speaks from, as far as the agent can tell boards apart: the IP address of a
    UDP or TCP endpoint (several boards behind one NAT share it), the device of a serial one
    (several boards on one bus share it)."""
    address = endpoint_address(endpoint)
    if address is not None:
        return address
    name = link.name
    if isinstance(endpoint, tuple) and endpoint:
        return (name, endpoint[0])
    return (name, endpoint)


def client_origin(client: ClientProxy) -> ClientOrigin:
    """What a middleware naming boards per board matches a client on (``ClientOrigin``): from
    its host, which a restored client has before its link is known."""
    host = client.host
    if isinstance(host, (ipaddress.IPv4Address, ipaddress.IPv6Address)):
        return ClientOrigin(client.key, address=host)
    if isinstance(host, tuple) and len(host) == 2 and isinstance(host[1], str):
        return ClientOrigin(client.key, device=host[1])
    return ClientOrigin(client.key)


def _hard_liveliness(properties) -> Optional[float]:
    for name, value in properties or ():
        if name == "uxr_hl":
            try:
                return int(value) / 1000.0 or None
            except ValueError:
                return None
    return None
