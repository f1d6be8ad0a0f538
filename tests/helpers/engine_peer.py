"""A scripted XRCE client for driving the agent engine in-process (tests/test_agent_engine_*.py).

``Peer`` encodes what a client would send and feeds it to ``Agent.receive`` through a ``Link`` that
records the agent's replies; ``Clock`` is the engine's clock, moved by hand. The ``ced_agent``
fixture (offered to every test module by conftest.py) is an engine with CED's routing behind it
reading representations as ``-m dds`` does; ``eprosima_ced_agent`` the same with ``-m ced`` as is.
"""

import pytest

from xrce.wire import constants as C
from xrce.agent.middleware import Middleware
from xrce.agent.middleware.ced import CedMiddleware
from xrce.agent.engine.agent import Agent
from xrce.wire.objects import (
    DataReaderBin, DataWriterBin, EndpointQos, ParticipantBin, PubSubBin, TopicBin,
)
from xrce.wire.submessages import (
    AckNack, Create, CreateClient, ReadData, WriteData, decode_message, encode_message,
)

BIN, XML, REF = C.REPRESENTATION_IN_BINARY, C.REPRESENTATION_AS_XML_STRING, C.REPRESENTATION_BY_REFERENCE
REUSE, REPLACE = C.FLAG_REUSE | 1, C.FLAG_REPLACE | 1


class Link:
    name = "test"
    sends_from_any_thread = False
    fastpath = None
    info_locators = ()

    def __init__(self):
        self.sent = []

    def send(self, endpoint, data):
        self.sent.append((endpoint, bytes(data)))


class Clock:
    def __init__(self):
        self.now = 1000.0

    def __call__(self):
        return self.now


class Peer:
    """A scripted client: numbers its streams and reads back what the agent sent it."""

    def __init__(self, agent, link, endpoint, key=b"\x5a\xa5\x3c\xc3", session_id=0x81, mtu=508):
        self.agent, self.link, self.endpoint = agent, link, endpoint
        self.key, self.session_id, self.mtu = key, session_id, mtu
        self.seqs = {}
        self.request_id = 0x40

    @property
    def header_key(self):
        return self.key if self.session_id < 0x80 else None

    def connect(self):
        self.seqs.clear()
        self.raw(encode_message(self.session_id & 0x80, 0, 0, self.header_key,
                                [CreateClient(self.key, self.session_id, self.mtu)]))
        (header, (status,)), = self.take()
        return header, status.status

    def raw(self, data):
        self.agent.receive(self.link, self.endpoint, data)

    def send(self, stream_id, *payloads, seq=None):
        if seq is None:
            seq = self.seqs.get(stream_id, 0) if stream_id else 0
            if stream_id:
                self.seqs[stream_id] = (seq + 1) & 0xFFFF
        self.raw(encode_message(self.session_id, stream_id, seq, self.header_key, list(payloads)))

    def next_request(self):
        self.request_id += 1
        return self.request_id

    def take(self):
        """Decoded messages the agent sent to this peer since the last call."""
        mine = [data for endpoint, data in self.link.sent if endpoint == self.endpoint]
        self.link.sent = [(e, d) for e, d in self.link.sent if e != self.endpoint]
        return [decode_message(data) for data in mine]

    def take_raw(self):
        mine = [data for endpoint, data in self.link.sent if endpoint == self.endpoint]
        self.link.sent = [(e, d) for e, d in self.link.sent if e != self.endpoint]
        return mine

    def statuses(self):
        return [(h.stream_id, p.request_id, p.status) for h, ps in self.take() for p in ps
                if p.ID == C.STATUS]

    def create(self, object_id, kind, fmt, representation, tail=0, flags=1, stream_id=0x80):
        request_id = self.next_request()
        self.send(stream_id, Create(request_id, object_id, kind, fmt, representation, tail, flags))
        found = [s for s in self.statuses() if s[1] == request_id]
        return found[0][2] if found else None

    def build_pubsub(self, topic="rt/chatter", reader_depth=10, reliable=True, domain=0,
                     participant="p"):
        qos_flags = C.QOS_KEEP_LAST | (C.QOS_RELIABLE if reliable else 0)
        assert self.create(0x0011, C.OBJK_PARTICIPANT, BIN, ParticipantBin(participant),
                           domain) == 0
        assert self.create(0x0012, C.OBJK_TOPIC, BIN, TopicBin(topic, "std_msgs::msg::dds_::String_"),
                           0x0011) == 0
        assert self.create(0x0013, C.OBJK_PUBLISHER, BIN, PubSubBin(), 0x0011) == 0
        assert self.create(0x0015, C.OBJK_DATAWRITER, BIN,
                           DataWriterBin(0x0012, EndpointQos(qos_flags, 10)), 0x0013) == 0
        assert self.create(0x0014, C.OBJK_SUBSCRIBER, BIN, PubSubBin(), 0x0011) == 0
        assert self.create(0x0016, C.OBJK_DATAREADER, BIN,
                           DataReaderBin(0x0012, EndpointQos(qos_flags, reader_depth)), 0x0014) == 0
        self.ack_all()

    def ack_all(self):
        """ACKNACK everything the agent has sent on 0x80 (what a well-behaved client does)."""
        stream = self.agent.clients[self.key].out_reliable.get(0x80)
        if stream is not None:
            self.send(0, AckNack((stream.last_sent + 1) & 0xFFFF, 0, 0x80))

    def read(self, stream_id=0x80, delivery=None, object_id=0x0016):
        request_id = self.next_request()
        self.send(0x80, ReadData(request_id, object_id, stream_id, delivery))
        return request_id

    def write(self, sample, stream_id=0x80, object_id=0x0015):
        self.send(stream_id, WriteData(self.next_request(), object_id, sample))


def data_of(messages):
    return [p.data for _, ps in messages for p in ps if p.ID == C.DATA]


def talker_and_listener(agent, link, reliable=True, listener_depth=10, listener_mtu=508):
    """Two connected clients, each with ``build_pubsub``'s entities on one topic: the tests write
    with the first and read with the second."""
    talker = Peer(agent, link, ("h", 1), key=b"\x01\x00\x00\x01")
    listener = Peer(agent, link, ("h", 2), key=b"\x02\x00\x00\x02", mtu=listener_mtu)
    talker.connect()
    talker.build_pubsub(reliable=reliable)
    listener.connect()
    listener.build_pubsub(reader_depth=listener_depth, reliable=reliable)
    return talker, listener


class ReadingCed(CedMiddleware):
    """CED's routing, with representations read as ``-m dds`` reads them (Fast DDS XML, ``-r``
    profiles, REUSE by meaning: ``Middleware.routed_name``'s default), so the engine's own reading
    is tested without ROS. ``-m ced`` itself reads strings as names, as eProsima's CED does."""

    routed_name = Middleware.routed_name


@pytest.fixture
def ced_agent():
    """An engine with CED's routing behind it (``ReadingCed``) on a hand-moved clock, and a link
    that records its replies."""
    link = Link()
    agent = Agent(ReadingCed())
    agent.clock = Clock()
    return agent, link


@pytest.fixture
def eprosima_ced_agent():
    """The same with ``-m ced``'s middleware as it is: strings are names, as eProsima's CED."""
    link = Link()
    agent = Agent(CedMiddleware())
    agent.clock = Clock()
    return agent, link
