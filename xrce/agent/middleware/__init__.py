"""The interface between the agent's protocol engine and what its objects map onto.

The engine (``xrce.agent.engine.agent``) owns XRCE semantics: sessions, streams, object trees,
REUSE/REPLACE, STATUS codes, READ_DATA delivery control. A middleware only creates, deletes and moves
data through the backing entities:

- ``CedMiddleware`` (``-m ced``): routes samples between the agent's own clients by topic name, no ROS.
- ``RosMiddleware`` (``-m dds``, ``xrce.agent.middleware.ros.ros_middleware``): rclpy nodes,
  publishers, subscriptions, service clients and servers.

Entity handles are the engine's ``EntityKey`` = ``(client_key: int, object_id: int)``, unique across
the agent. Every ``create_*`` either succeeds or raises ``MiddlewareError`` (the engine answers
``ERR_DDS_ERROR``) or ``UnknownTypeError`` (also ``ERR_DDS_ERROR``, with a log line that names the
interface package to build). All methods are called on the asyncio loop's thread. Data callbacks
given to the middleware are called on the loop's thread, or on any thread that holds
``engine_lock`` (the engine sets it): a middleware whose data arrives on a thread of its own hands it
to the loop (``loop.call_soon_threadsafe``, keeping its queues bounded), or calls the callback right
there when it takes ``engine_lock`` without waiting and nothing of that reader is still queued for
the loop, which saves waking the loop once per sample. It must never wait for that lock: the
engine holds it while it waits for the middleware's own thread (entity creation).

Sample bytes crossing this interface are bare XCDR1 bodies WITHOUT the 4-byte encapsulation header
(XRCE-WIRE.md §14): the ROS middleware prepends ``00 01 00 00`` on publish and strips the first 4
bytes on receive.
"""

from __future__ import annotations

import functools
import threading
from dataclasses import dataclass
from typing import Callable, Optional, Tuple

EntityKey = Tuple[int, int]

# The highest DDS domain id with the default RTPS port mapping: beyond it Fast DDS cannot compute
# its ports (and aborts the process), so no middleware is asked for one.
MAX_DOMAIN_ID = 232

# on_data(sample_bytes)
DataCallback = Callable[[bytes], None]
# on_request(sample_identity_24_bytes, request_bytes)
RequestCallback = Callable[[bytes, bytes], None]
# on_reply(correlation_id, reply_bytes) — correlation_id is what write_request was given
ReplyCallback = Callable[[int, bytes], None]


class MiddlewareError(Exception):
    """Creating or using a backing entity failed (answered with STATUS ERR_DDS_ERROR)."""


class UnknownTypeError(MiddlewareError):
    """The type named by a topic has no importable implementation."""


class TypeNotReady(MiddlewareError):
    """The type is being built (``future`` completes when it is): the engine parks the client's
    processing and retries the CREATE then, instead of stalling every other client meanwhile."""

    def __init__(self, message, future):
        super().__init__(message)
        self.future = future


@dataclass(frozen=True)
class EndpointQosSpec:
    """QoS of a writer/reader after XML/binary/reference have been normalised by the engine."""

    reliable: bool = True
    keep_last: bool = True
    depth: int = 10
    durability: str = "volatile"  # volatile | transient_local | transient | persistent


# Fast DDS defaults when a representation is silent: a DataWriter is RELIABLE + TRANSIENT_LOCAL, a
# DataReader BEST_EFFORT + VOLATILE, and both keep the last sample only. Here, not in
# xrce.agent.engine.xmlrep, because binary endpoints without QoS take them too and must not load the XML
# code for them.
WRITER_DEFAULTS = EndpointQosSpec(reliable=True, keep_last=True, depth=1, durability="transient_local")
READER_DEFAULTS = EndpointQosSpec(reliable=False, keep_last=True, depth=1, durability="volatile")


class XmlRepresentationError(ValueError):
    """The XML does not describe the object kind it was sent for (raised by xrce.agent.engine.xmlrep,
    defined here so that the engine can catch it without loading that module)."""


@dataclass(frozen=True)
class TopicSpec:
    name: str  # DDS topic name as the client sent it, e.g. "rt/chatter"
    type_name: str  # DDS type name, e.g. "std_msgs::msg::dds_::String_"


@dataclass(frozen=True)
class ServiceSpec:
    service_name: str  # e.g. "add_two_ints" or "/add_two_ints" as the client sent it
    request_type: str  # e.g. "example_interfaces::srv::dds_::AddTwoInts_Request_"
    reply_type: str
    request_topic: Optional[str] = None  # e.g. "rq/add_two_intsRequest"
    reply_topic: Optional[str] = None  # e.g. "rr/add_two_intsReply"


@dataclass(frozen=True)
class ClientOrigin:
    """Who is creating a participant, as far as the agent can tell boards apart: what a
    middleware that names boards' entities per board (the ROS middleware's fleet rules) matches
    on. ``address``: the IP address of a UDP or TCP board, ``device``: the serial device path the
    agent opened for a serial one (None where it has none)."""

    client_key: bytes
    address: Optional[object] = None  # an ipaddress.IPv4Address / IPv6Address
    device: Optional[str] = None


class CompiledPathSupport:
    """What the engine's compiled receive path (``xrce.agent.engine.compiled.fastpath``: C that publishes
    a board's samples to rcl, takes ROS samples and requests, and answers them, without Python)
    needs of a middleware whose entities are rcl ones: an optional capability, offered by
    ``Middleware.compiled_path_support``. Every answer may be None: that entity stays on the
    Python path."""

    request_timeout_s: float  # how long C keeps a request for its reply (the middleware's own)

    def publisher_address(self, writer: EntityKey) -> Optional[int]:
        """The rcl_publisher_t C publishes ``writer``'s samples with; forgotten before delete."""
        raise NotImplementedError

    def subscription_address(self, reader: EntityKey) -> Optional[int]:
        """The rcl_subscription_t whose samples C takes for ``reader``; let go before delete."""
        raise NotImplementedError

    def replier_service(self, replier: EntityKey) -> Optional[tuple]:
        """(rcl_service_t address, request (type support, create, destroy) capsules, the same of
        the response, identity prefix, first sequence number, request timeout in s or 0)."""
        raise NotImplementedError

    def replier_sequence_from(self, replier: EntityKey,
                              next_sequence: Optional[Callable[[], int]]) -> None:
        """Request identities of ``replier`` come from ``next_sequence()`` (None: its own)."""
        raise NotImplementedError

    def count_timed_out_requests(self, count: int) -> None:
        """``count`` requests C held got no reply within ``request_timeout_s``."""
        raise NotImplementedError


class Middleware:
    """Base class: every method must be implemented by a backend."""

    name = "abstract"
    # The engine's lock (``Agent.lock``), set by the engine; see the module docstring.
    engine_lock: Optional[threading.RLock] = None
    # on_mismatch(entity, text): a client's endpoint cannot talk to a peer outside the agent
    # (incompatible QoS, another type); called once per pair, from any thread. Set by the engine,
    # which names the client and counts it.
    on_mismatch: Optional[Callable[[EntityKey, str], None]] = None

    # The fewest samples the engine queues for one of this middleware's datareaders created
    # without QoS (READER_DEFAULTS: KEEP_LAST 1) while its client's stream has no room: a DDS
    # reader keeps its own history, so 1 here.
    reader_queue_floor = 1

    def create_participant(self, key: EntityKey, domain_id: int, name: str,
                           origin: Optional[ClientOrigin] = None) -> None:
        """``origin``: the board creating it (the engine always gives it; direct callers and
        tests may not)."""
        raise NotImplementedError

    def create_topic(self, key: EntityKey, participant: EntityKey, topic: TopicSpec) -> None:
        raise NotImplementedError

    def create_publisher(self, key: EntityKey, participant: EntityKey) -> None:
        raise NotImplementedError

    def create_subscriber(self, key: EntityKey, participant: EntityKey) -> None:
        raise NotImplementedError

    def create_datawriter(self, key: EntityKey, publisher: EntityKey, topic: EntityKey,
                          qos: EndpointQosSpec) -> None:
        raise NotImplementedError

    def create_datareader(self, key: EntityKey, subscriber: EntityKey, topic: EntityKey,
                          qos: EndpointQosSpec, on_data: DataCallback) -> None:
        raise NotImplementedError

    def create_requester(self, key: EntityKey, participant: EntityKey, service: ServiceSpec,
                         qos: EndpointQosSpec, on_reply: ReplyCallback) -> None:
        raise NotImplementedError

    def create_replier(self, key: EntityKey, participant: EntityKey, service: ServiceSpec,
                       qos: EndpointQosSpec, on_request: RequestCallback) -> None:
        raise NotImplementedError

    def delete(self, key: EntityKey) -> None:
        """Delete one entity. The engine deletes children before parents."""
        raise NotImplementedError

    def routed_name(self, kind: str, text: str) -> Optional[str]:
        """What an XML or reference representation of ``kind`` (``participant``, ``topic``,
        ``datawriter``, ``datareader``) names, for a middleware that routes by the string itself
        (CED, as eProsima's: a participant's string names nothing, ``""``; a topic's string is its
        name, an endpoint's the name of its topic). None, the default: the engine reads the string
        as Fast DDS XML, a reference through the ``-r`` profiles."""
        return None

    def ros_entity(self, key: EntityKey) -> Optional[str]:
        """What the entity became outside the agent, in a user's words (``node /talker``,
        ``publisher /chatter of node /talker``), for logs and stats; None where nothing."""
        return None

    def given_names(self, key: EntityKey) -> Optional[dict]:
        """What the entity was named outside the agent where that may not be what its board
        asked for (a namespace, remaps, another domain: issue 53), for logs and stats; None where
        the board's names are kept. The ROS middleware's: ``xrce.agent.middleware.ros.shown``."""
        return None

    def compiled_path_support(self) -> Optional[CompiledPathSupport]:
        """What the compiled receive path needs of this middleware; None, the default: every
        entity stays on the Python path."""
        return None

    def sample_check(self, writer: EntityKey, dds_type: str) -> Optional[Callable]:
        """``check(sample) -> None | why`` for a datawriter's samples of ``dds_type`` as the
        middleware has the type (xrce.agent.engine.type_drift); None where it cannot tell."""
        return None

    def type_hash(self, dds_type: str) -> Optional[str]:
        """The RIHS01 hash of ``dds_type`` as the middleware has it; None where it has none."""
        return None

    def write(self, writer: EntityKey, sample: bytes) -> bool:
        raise NotImplementedError

    def writer(self, writer: EntityKey) -> Callable[[bytes], bool]:
        """``write`` bound to one writer, taken once when it is created: the engine's per-sample
        path calls it without looking the writer up again. Backends may return something faster;
        it is never called after ``delete(writer)``."""
        return functools.partial(self.write, writer)

    def write_request(self, requester: EntityKey, correlation_id: int, sample: bytes) -> bool:
        raise NotImplementedError

    def write_reply(self, replier: EntityKey, sample_identity: bytes, sample: bytes) -> bool:
        raise NotImplementedError

    async def start(self) -> None:
        """Start background machinery (the ROS executor thread); called once on the loop."""

    async def close(self) -> None:
        """Destroy every entity and stop background machinery."""
