"""CED middleware: the agent routes samples between its own clients, with no DDS behind it.

As eProsima's CED, it routes by names only: a topic created by XML or by reference is named by that
string itself (a reference's ``__t`` suffix dropped), a datawriter's or datareader's string names its
topic in the same participant (``__dw``, ``__dr`` dropped), a participant's string is ignored and its
domain is the number the client sent (255 included), and an XML or reference string gives no QoS
(the endpoint has Fast DDS' defaults). REUSE compares those names (and a participant's domain),
whatever representation each came in; groups always match.

A sample written by a datawriter reaches every datareader of the same topic name whose participant
is in the same domain, whichever client owns it. Requests go from a requester to every replier of
the same service in the same domain; a reply finds its way back through the SampleIdentity the
replier received with the request. Transient-local writers keep their last ``depth`` samples for
transient-local readers that join later, like a DDS writer history would.

Everything runs on the agent's loop thread, so callbacks are invoked synchronously from ``write``.
"""

from __future__ import annotations

import logging
import struct
from collections import OrderedDict, deque
from dataclasses import dataclass, field
from typing import Deque, Dict, List, Optional, Tuple

from xrce.agent.middleware import (
    DataCallback, EndpointQosSpec, EntityKey, Middleware, MiddlewareError, ReplyCallback,
    RequestCallback, ServiceSpec, TopicSpec,
)

log = logging.getLogger("xrce.agent.ced")

# Requests whose reply has not come yet; the oldest are forgotten beyond this.
MAX_PENDING_REQUESTS = 1024
_GUID_MAGIC = b"CED\x00"


@dataclass
class _Writer:
    domain: int
    topic: str
    qos: EndpointQosSpec
    history: Deque[bytes] = field(default_factory=deque)


@dataclass
class _Reader:
    domain: int
    topic: str
    qos: EndpointQosSpec
    on_data: DataCallback


@dataclass
class _Requester:
    domain: int
    service: str
    on_reply: ReplyCallback
    next_sequence: int = 1


@dataclass
class _Replier:
    domain: int
    service: str
    on_request: RequestCallback


def _service_key(name: str) -> str:
    # micro-ROS sends "add_two_ints", a hand-written client may send "/add_two_ints": same service.
    return name.lstrip("/")


# eProsima's CED reads no XML: a representation's string, up to the suffix its references carry
# (``chatter__t`` the topic, ``chatter__dw`` a writer of it, ``chatter__dr`` a reader), is the name.
_NAME_SUFFIXES = {"topic": "__t", "datawriter": "__dw", "datareader": "__dr"}


class CedMiddleware(Middleware):
    name = "ced"
    # eProsima's CED keeps each topic's last 16 samples and every reader reads on from where it
    # was: a reader whose client's stream is blocked (retransmissions on a lossy link, a long
    # sample in fragments) loses a sample only once 16 newer came. A reader by XML or reference
    # gets no QoS from CED's strings (KEEP_LAST 1): without this floor two samples arriving while
    # its stream was full lost the first. A binary reader's own depth is kept.
    reader_queue_floor = 16

    def routed_name(self, kind: str, text: str) -> Optional[str]:
        suffix = _NAME_SUFFIXES.get(kind)
        if suffix is None:
            return ""  # a participant's string: eProsima's CED keeps only the domain
        end = text.find(suffix)
        return text if end < 0 else text[:end]

    def __init__(self) -> None:
        self.participants: Dict[EntityKey, int] = {}
        self.groups: Dict[EntityKey, EntityKey] = {}  # publisher/subscriber → participant
        self.topics: Dict[EntityKey, Tuple[EntityKey, TopicSpec]] = {}
        self.writers: Dict[EntityKey, _Writer] = {}
        self.readers: Dict[EntityKey, _Reader] = {}
        self.requesters: Dict[EntityKey, _Requester] = {}
        self.repliers: Dict[EntityKey, _Replier] = {}
        self.pending: "OrderedDict[bytes, Tuple[EntityKey, int]]" = OrderedDict()
        self.samples_routed = 0

    # -- creation -------------------------------------------------------------------------------

    def _domain_of(self, participant: EntityKey) -> int:
        try:
            return self.participants[participant]
        except KeyError:
            raise MiddlewareError("unknown participant %r" % (participant,)) from None

    def _domain_of_group(self, group: EntityKey) -> int:
        try:
            return self._domain_of(self.groups[group])
        except KeyError:
            raise MiddlewareError("unknown publisher/subscriber %r" % (group,)) from None

    def _topic_name(self, topic: EntityKey) -> str:
        try:
            return self.topics[topic][1].name
        except KeyError:
            raise MiddlewareError("unknown topic %r" % (topic,)) from None

    def create_participant(self, key: EntityKey, domain_id: int, name: str,
                           origin=None) -> None:
        self.participants[key] = domain_id

    def create_topic(self, key: EntityKey, participant: EntityKey, topic: TopicSpec) -> None:
        self._domain_of(participant)
        self.topics[key] = (participant, topic)

    def create_publisher(self, key: EntityKey, participant: EntityKey) -> None:
        self._domain_of(participant)
        self.groups[key] = participant

    def create_subscriber(self, key: EntityKey, participant: EntityKey) -> None:
        self._domain_of(participant)
        self.groups[key] = participant

    def create_datawriter(self, key: EntityKey, publisher: EntityKey, topic: EntityKey,
                          qos: EndpointQosSpec) -> None:
        self.writers[key] = _Writer(self._domain_of_group(publisher), self._topic_name(topic), qos)

    def create_datareader(self, key: EntityKey, subscriber: EntityKey, topic: EntityKey,
                          qos: EndpointQosSpec, on_data: DataCallback) -> None:
        reader = _Reader(self._domain_of_group(subscriber), self._topic_name(topic), qos, on_data)
        self.readers[key] = reader
        if qos.durability != "volatile":
            for writer in list(self.writers.values()):
                if writer.domain == reader.domain and writer.topic == reader.topic:
                    for sample in list(writer.history):
                        reader.on_data(sample)

    def create_requester(self, key: EntityKey, participant: EntityKey, service: ServiceSpec,
                         qos: EndpointQosSpec, on_reply: ReplyCallback) -> None:
        self.requesters[key] = _Requester(self._domain_of(participant),
                                          _service_key(service.service_name), on_reply)

    def create_replier(self, key: EntityKey, participant: EntityKey, service: ServiceSpec,
                       qos: EndpointQosSpec, on_request: RequestCallback) -> None:
        self.repliers[key] = _Replier(self._domain_of(participant),
                                      _service_key(service.service_name), on_request)

    def delete(self, key: EntityKey) -> None:
        for table in (self.participants, self.groups, self.topics, self.writers, self.readers,
                      self.repliers):
            table.pop(key, None)
        if self.requesters.pop(key, None) is not None:
            for identity in [i for i, (owner, _) in self.pending.items() if owner == key]:
                del self.pending[identity]

    # -- data -----------------------------------------------------------------------------------

    def write(self, writer: EntityKey, sample: bytes) -> bool:
        entry = self.writers.get(writer)
        if entry is None:
            return False
        sample = bytes(sample)
        if entry.qos.durability != "volatile":
            entry.history.append(sample)
            while len(entry.history) > max(entry.qos.depth, 1):
                entry.history.popleft()
        # Copy: a callback may create or delete readers (a client reacting to the data).
        for reader in [r for r in self.readers.values()
                       if r.domain == entry.domain and r.topic == entry.topic]:
            reader.on_data(sample)
            self.samples_routed += 1
        return True

    @staticmethod
    def _identity(requester: EntityKey, sequence: int) -> bytes:
        client_key, object_id = requester
        prefix = _GUID_MAGIC + struct.pack(">IH", client_key & 0xFFFFFFFF, object_id) + b"\x00\x00"
        entity = struct.pack(">I", (object_id << 8) | 0xC3)[1:] + b"\x03"
        return prefix + entity + struct.pack("<iI", 0, sequence & 0xFFFFFFFF)

    def write_request(self, requester: EntityKey, correlation_id: int, sample: bytes) -> bool:
        entry = self.requesters.get(requester)
        if entry is None:
            return False
        identity = self._identity(requester, entry.next_sequence)
        entry.next_sequence += 1
        self.pending[identity] = (requester, correlation_id)
        while len(self.pending) > MAX_PENDING_REQUESTS:
            self.pending.popitem(last=False)
        sample = bytes(sample)
        for replier in [r for r in self.repliers.values()
                        if r.domain == entry.domain and r.service == entry.service]:
            replier.on_request(identity, sample)
        return True

    def write_reply(self, replier: EntityKey, sample_identity: bytes, sample: bytes) -> bool:
        if replier not in self.repliers or len(sample_identity) != 24:
            return False
        target = self.pending.pop(bytes(sample_identity), None)
        if target is None:
            log.debug("reply for an unknown or answered request %s", bytes(sample_identity).hex())
            return True  # a DDS replier's write succeeds whether or not anyone still waits
        requester, correlation_id = target
        entry: Optional[_Requester] = self.requesters.get(requester)
        if entry is not None:
            entry.on_reply(correlation_id, bytes(sample))
        return True

    async def close(self) -> None:
        for table in (self.participants, self.groups, self.topics, self.writers, self.readers,
                      self.requesters, self.repliers, self.pending):
            table.clear()


__all__: List[str] = ["CedMiddleware"]
