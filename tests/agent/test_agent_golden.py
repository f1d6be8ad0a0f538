"""Replay every golden capture through Agent(ReadingCed()) and compare what it sends.

The captured agent (eProsima v2.4.3 with Fast DDS, rclpy on the DDS side) is replaced by ours with
CED's routing, reading representations as ``-m dds`` does (engine_peer.ReadingCed: the captures'
XML names its topics the Fast DDS way). For each scenario the C->A datagrams are fed in capture order (those marked
``C->A DROPPED`` never reached the agent and are skipped). Where the capture shows a DATA the agent
produced on its own, i.e. a sample that came from a DDS writer, a second CED client on another
endpoint publishes the captured sample bytes at that point; its traffic is ignored.

Matching rule: the agent's output to the client under test and the captured A->C datagrams
(``A->C DROPPED`` included: the agent did send them) are split into acknowledgement traffic (ACKNACK
and HEARTBEAT on stream 0) and everything else; each part must match in order. Between the two parts
the relative order depends on thread timing in the eProsima agent and is not compared. Masked:
TIMESTAMP_REPLY transmit/receive stamps and INFO locator lists (everything else in those messages is
compared). Request ids, client keys and padding need no masking: the agent echoes ids, no capture
uses a keyed session, and the agent never pads.

Heartbeat timing follows the capture clock: whenever it advances by at least the heartbeat period,
``Agent.tick()`` runs once with the agent's clock set to the capture time. The captures contain no
agent HEARTBEAT, so none may appear.
"""

import json
import pathlib

import pytest

from xrce.wire import constants as C
from engine_peer import ReadingCed
from xrce.agent.engine.agent import Agent
from xrce.wire.submessages import (
    Create, CreateClient, Locator, WriteData, decode_message, encode_message,
)
from xrce.wire.objects import DataWriterBin, EndpointQos, ParticipantBin, PubSubBin, TopicBin

CAPTURES = pathlib.Path(__file__).parents[1] / "golden" / "wire_captures.json"
SCENARIOS = json.loads(CAPTURES.read_text())["scenarios"]

CLIENT = ("127.0.0.1", 40001)
INJECTOR = ("127.0.0.1", 40002)
INJECTOR_KEY = b"\x0f\x0e\x0d\x0c"
ACK_KINDS = (C.ACKNACK, C.HEARTBEAT)


class RecordingLink:
    name = "udp4:test"
    sends_from_any_thread = False
    fastpath = None

    def __init__(self, locators=()):
        self.sent = []
        self.info_locators = list(locators)

    def send(self, endpoint, data):
        self.sent.append((endpoint, bytes(data)))


class CaptureClock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


class Injector:
    """A second CED client that publishes what a DDS writer published in the capture."""

    def __init__(self, agent, link, middleware):
        self.agent, self.link, self.middleware = agent, link, middleware
        self.seq = 0
        self.ready = False

    def _send(self, stream_id, payloads):
        seq = 0
        if stream_id:
            seq, self.seq = self.seq, self.seq + 1
        self.agent.receive(self.link, INJECTOR, encode_message(0x81, stream_id, seq, None, payloads))

    def setup(self):
        readers = list(self.middleware.readers.values())
        assert readers, "a capture shows DATA but the client created no datareader"
        topic, domain = readers[0].topic, readers[0].domain
        self.agent.receive(self.link, INJECTOR, encode_message(
            0x80, 0, 0, None, [CreateClient(INJECTOR_KEY)]))
        self._send(1, [
            Create(10, 0x0011, C.OBJK_PARTICIPANT, C.REPRESENTATION_IN_BINARY, ParticipantBin("inj"),
                   domain),
        ])
        self._send(1, [Create(11, 0x0012, C.OBJK_TOPIC, C.REPRESENTATION_IN_BINARY,
                              TopicBin(topic, "injected"), 0x0011)])
        self._send(1, [Create(12, 0x0013, C.OBJK_PUBLISHER, C.REPRESENTATION_IN_BINARY, PubSubBin(),
                              0x0011)])
        self._send(1, [Create(13, 0x0015, C.OBJK_DATAWRITER, C.REPRESENTATION_IN_BINARY,
                              DataWriterBin(0x0012, EndpointQos(C.QOS_KEEP_LAST, 10)), 0x0013)])
        self.ready = True

    def publish(self, sample):
        if not self.ready:
            self.setup()
        self._send(1, [WriteData(0x50, 0x0015, sample)])


def masked(message):
    """Bytes to compare: the message with the legitimately varying parts blanked."""
    sub_id = message[4]
    if sub_id == C.TIMESTAMP_REPLY:
        return message[:8] + b"\x00" * 16 + message[24:]
    if sub_id == C.INFO:
        header, (info,) = decode_message(message)
        info.locators = []
        return encode_message(header.session_id, header.stream_id, header.seq, header.key, [info])
    return message


def split(messages):
    acks = [masked(m) for m in messages if m[1] == 0 and m[4] in ACK_KINDS]
    rest = [masked(m) for m in messages if not (m[1] == 0 and m[4] in ACK_KINDS)]
    return acks, rest


def replay(name):
    datagrams = SCENARIOS[name]
    link = RecordingLink([Locator(C.LOCATOR_MEDIUM, b"\x7f\x00\x00\x01", 8888)])
    middleware = ReadingCed()
    agent = Agent(middleware)
    clock = CaptureClock()
    agent.clock = clock
    injector = Injector(agent, link, middleware)
    expected = []
    data_seen = set()
    start = datagrams[0]["t"]
    last_tick = 0.0
    for datagram in datagrams:
        clock.now = datagram["t"] - start
        if clock.now - last_tick >= agent.heartbeat_period:
            agent.tick()
            last_tick = clock.now
        message = bytes.fromhex(datagram["hex"])
        direction = datagram["dir"]
        if direction.startswith("A->C"):
            expected.append(message)
            if message[4] == C.DATA and (message[1], message[2:4]) not in data_seen:
                data_seen.add((message[1], message[2:4]))
                injector.publish(message[12:])  # payload after the DATA's BaseObjectRequest
        elif direction == "C->A":
            agent.receive(link, CLIENT, message)
        else:
            assert direction == "C->A DROPPED", direction
    actual = [data for endpoint, data in link.sent if endpoint == CLIENT]
    return agent, expected, actual


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_scenario_matches_capture(name):
    agent, expected, actual = replay(name)
    expected_acks, expected_rest = split(expected)
    actual_acks, actual_rest = split(actual)
    assert [m.hex() for m in actual_rest] == [m.hex() for m in expected_rest]
    assert [m.hex() for m in actual_acks] == [m.hex() for m in expected_acks]
    assert agent.stats.decode_errors == 0
    assert agent.stats.handler_errors == 0


def test_loss_scenarios_exercise_recovery():
    agent, _, _ = replay("reliable_loss_a2c")
    assert agent.stats.retransmissions == 1
    agent, _, actual = replay("reliable_loss_c2a")
    nacks = [m for m in actual if m[4] == C.ACKNACK and m[10:12] == b"\x00\x01"]
    assert len(nacks) == 1  # the NACK of the lost seq 1, answering the client's HEARTBEAT


def test_fragment_scenario_reassembles_the_sample():
    agent, _, _ = replay("fragment_reliable")
    assert agent.stats.fragments_in == 4
    assert agent.stats.samples_in == 1  # the inner WRITE_DATA reached the writer
