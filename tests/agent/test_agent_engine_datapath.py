"""Agent engine: the data path (XRCE-WIRE.md §6, §7): WRITE_DATA to READ_DATA between clients,
delivery control, request/reply, the best-effort short path and its byte-exact DATA, domains,
the output queue quota, and samples a middleware hands over on its own thread."""

import asyncio
import logging
import threading

import pytest
from hypothesis import given, settings, strategies as st

from engine_peer import BIN, Clock, Link, Peer, data_of, talker_and_listener
from xrce.wire import constants as C
from xrce.agent.middleware.ced import CedMiddleware
from xrce.agent.engine.agent import Agent
from xrce.wire.objects import ParticipantBin, ReplierBin, RequesterBin
from xrce.wire.submessages import DeliveryControl, WriteData, decode_message, encode_message


def test_two_clients_exchange_data_reliable_and_best_effort(ced_agent):
    agent, link = ced_agent
    talker, listener = talker_and_listener(agent, link)
    request = listener.read(0x80, DeliveryControl())
    talker.write(b"\x03\x00\x00\x00hi\x00")
    talker.write(b"\x03\x00\x00\x00be\x00", stream_id=0x01)
    messages = listener.take()
    data = [(h.stream_id, p.request_id, p.object_id, p.data) for h, ps in messages for p in ps
            if p.ID == C.DATA]
    assert data == [(0x80, request, 0x0016, b"\x03\x00\x00\x00hi\x00"),
                    (0x80, request, 0x0016, b"\x03\x00\x00\x00be\x00")]
    listener.ack_all()
    request = listener.read(0x01, DeliveryControl())
    talker.write(b"\x03\x00\x00\x00ok\x00")
    (header, (data,)), = [(h, ps) for h, ps in listener.take() if ps[0].ID == C.DATA]
    assert header.stream_id == 0x01 and data.data == b"\x03\x00\x00\x00ok\x00"


def test_read_data_delivery_control(ced_agent):
    agent, link = ced_agent
    talker, listener = talker_and_listener(agent, link, listener_depth=2)
    # Samples before any READ_DATA wait in a queue bounded by the reader's depth.
    for i in range(5):
        talker.write(bytes([i]))
    listener.read(0x80, DeliveryControl(max_samples=3))
    assert data_of(listener.take()) == [b"\x03", b"\x04"]
    talker.write(b"\x05")
    talker.write(b"\x06")
    assert data_of(listener.take()) == [b"\x05"]  # the third sample ends this READ_DATA
    listener.read(0x80)  # no delivery control: exactly one sample
    talker.write(b"\x07")
    assert data_of(listener.take()) == [b"\x06"]
    talker.write(b"\x08")
    assert data_of(listener.take()) == []
    listener.read(0x80, DeliveryControl())
    assert data_of(listener.take()) == [b"\x07", b"\x08"]


def test_cancel_read_data_is_answered_as_eprosima_answers_it(ced_agent):
    """uxr_buffer_cancel_data (stream none, all limits 0), which rmw_microxrcedds sends and waits
    on before deleting a reader: eProsima's reader sends a sample that is there or arrives within
    its first 100 ms read, on stream none under the cancel's request id, and then every later one
    (max_samples 0 is never reached again); a first read finding nothing ends it."""
    agent, link = ced_agent
    clock = agent.clock
    talker, listener = talker_and_listener(agent, link)

    def answered():
        return [(h.stream_id, p.request_id, p.data) for h, ps in listener.take() for p in ps
                if p.ID == C.DATA]

    talker.write(b"queued")
    cancel = listener.read(0, DeliveryControl(0, 0, 0, 0))
    assert answered() == [(0, cancel, b"queued")]  # at once
    clock.now += 5
    agent.tick()
    talker.write(b"later")
    assert answered() == [(0, cancel, b"later")]  # and on, past the first read's 100 ms
    cancel = listener.read(0, DeliveryControl(0, 0, 0, 0))
    clock.now += 0.05
    talker.write(b"within")
    assert answered() == [(0, cancel, b"within")]
    cancel = listener.read(0, DeliveryControl(0, 0, 0, 0))
    clock.now += 0.15
    agent.tick()
    talker.write(b"too late")
    assert answered() == []  # the first read found nothing: that READ_DATA is over
    listener.read(0x80, DeliveryControl(max_samples=1))
    assert data_of(listener.take()) == [b"too late"]


def test_read_data_elapsed_time_and_rate(ced_agent):
    agent, link = ced_agent
    clock = agent.clock
    talker, listener = talker_and_listener(agent, link)
    listener.read(0x01, DeliveryControl(max_elapsed_time=2))
    talker.write(b"a")
    clock.now += 2.5
    talker.write(b"b")
    assert data_of(listener.take()) == [b"a"]
    listener.read(0x01, DeliveryControl(max_bytes_per_second=100))
    talker.write(b"x" * 60)
    talker.write(b"y" * 60)
    assert data_of(listener.take()) == [b"b", b"x" * 60]  # "b" was queued; "y" waits for tokens
    clock.now += 0.5
    agent.tick()
    assert data_of(listener.take()) == [b"y" * 60]


def test_requester_and_replier_through_ced(ced_agent):
    agent, link = ced_agent
    caller = Peer(agent, link, ("h", 1), key=b"\x01\x00\x00\x01")
    server = Peer(agent, link, ("h", 2), key=b"\x02\x00\x00\x02")
    service = ("add_two_ints", "example_interfaces::srv::dds_::AddTwoInts_Request_",
               "example_interfaces::srv::dds_::AddTwoInts_Response_", "rq/add_two_intsRequest",
               "rr/add_two_intsReply")
    for peer, kind, blob in ((caller, C.OBJK_REQUESTER, RequesterBin(*service)),
                             (server, C.OBJK_REPLIER, ReplierBin("/" + service[0], *service[1:]))):
        peer.connect()
        assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, ParticipantBin("p")) == 0
        assert peer.create(0x0010 | kind, kind, BIN, blob, 0x0011) == 0
        peer.ack_all()
    server_read = server.read(0x80, DeliveryControl(), object_id=0x0018)
    caller_read = caller.read(0x80, DeliveryControl(), object_id=0x0017)
    caller.send(0x80, WriteData(0x0123, 0x0017, b"\x02" + b"\x00" * 7 + b"\x03" + b"\x00" * 7))
    (request,), = [ps for _, ps in server.take() if ps[0].ID == C.DATA]
    assert (request.request_id, request.object_id) == (server_read, 0x0018)
    identity, body = request.data[:24], request.data[24:]
    assert body == b"\x02" + b"\x00" * 7 + b"\x03" + b"\x00" * 7
    server.send(0x80, WriteData(0x0200, 0x0018, identity + b"\x05" + b"\x00" * 7))
    (reply,), = [ps for _, ps in caller.take() if ps[0].ID == C.DATA]
    assert (reply.request_id, reply.object_id) == (caller_read, 0x0017)
    # The reply carries the BaseObjectRequest of the WRITE_DATA that asked.
    assert reply.data == b"\x01\x23\x00\x17" + b"\x05" + b"\x00" * 7


def test_best_effort_samples_take_the_short_path_with_the_same_accounting(ced_agent):
    agent, link = ced_agent
    talker, listener = talker_and_listener(agent, link, reliable=False)
    listener.read(0x01, DeliveryControl())
    general = []
    inbound = agent.inbound
    receive = inbound._receive
    inbound._receive = lambda *args: (general.append(args[2]), receive(*args))[1]
    for index in range(3):
        talker.write(bytes([index]), stream_id=0x01)
    talker.send(0x01, WriteData(0x50, 0x0015, b"stale"), seq=1)  # older than the last: dropped
    assert len(general) == 1  # only the stream's first message went the general way
    assert data_of(listener.take()) == [b"\x00", b"\x01", b"\x02"]
    writer = agent.clients[talker.key].objects[0x0015]
    assert (writer.samples, writer.sample_bytes, agent.stats.dropped) == (3, 3, 1)
    client = agent.clients[talker.key]
    assert client.messages_in == len(general) + 3 + 7  # 7 messages built the entities
    # Reliable: the next message in order goes the short way and is acknowledged; a gap does not.
    del general[:]
    base = talker.seqs[0x80]
    talker.write(b"r0")
    talker.take()
    talker.write(b"r1")
    (_, (acknack,)), = talker.take()
    assert acknack.ID == C.ACKNACK and acknack.first_unacked == (base + 2) & 0xFFFF
    talker.send(0x80, WriteData(0x51, 0x0015, b"r3"), seq=base + 3)  # r2 missing
    talker.send(0x80, WriteData(0x52, 0x0015, b"r2"), seq=base + 2)
    assert len(general) == 2 and writer.samples == 7


@settings(max_examples=200, deadline=None)
@given(session_id=st.sampled_from([0x01, 0x7F, 0x81, 0xFF]), stream_id=st.integers(0, 255),
       request_id=st.integers(0, 0xFFFF), object_id=st.integers(0, 0xFFFF),
       sample=st.binary(max_size=600))
def test_the_direct_data_encoding_is_byte_exact(session_id, stream_id, request_id, object_id,
                                               sample):
    from xrce.agent.engine.stream_output import data_message
    from xrce.wire.submessages import Data

    class Client:
        pass
    client = Client()
    client.session_id = session_id
    client.header_key = b"\x0a\x0b\x0c\x0d" if session_id < 0x80 else None
    assert data_message(client, stream_id, request_id, object_id, sample) == encode_message(
        session_id, stream_id, 0, client.header_key, [Data(request_id, object_id, sample)])


def test_ced_routes_only_within_a_domain(ced_agent):
    agent, link = ced_agent
    a = Peer(agent, link, ("h", 1), key=b"\x01\x00\x00\x01")
    b = Peer(agent, link, ("h", 2), key=b"\x02\x00\x00\x02")
    a.connect()
    a.build_pubsub(domain=0)
    b.connect()
    b.build_pubsub(domain=1)
    b.read(0x80, DeliveryControl())
    a.write(b"zz")
    assert data_of(b.take()) == []
    logging.getLogger("xrce.agent").debug("domains isolated")


def test_output_queue_quota_keeps_the_newest_samples_within_the_bound():
    link = Link()
    agent = Agent(CedMiddleware(), max_output_queue_bytes=200)
    agent.clock = Clock()
    peer = Peer(agent, link, "q")
    assert peer.connect()[1] == 0
    peer.build_pubsub(reader_depth=100)
    samples = [bytes([i]) * 50 for i in range(10)]  # no READ_DATA yet: they queue for the reader
    for sample in samples:
        peer.write(sample)
    client = agent.clients[peer.key]
    assert client.queued_bytes <= 200
    assert agent.stats.quota_output_dropped == 6
    peer.take()
    peer.read(delivery=DeliveryControl(0xFFFF, 0, 0, 0))
    assert data_of(peer.take()) == samples[-4:]  # the newest that fit, oldest dropped first


class ThreadRecordingLink(Link):
    """Records which thread sent each DATA."""

    def send(self, endpoint, data):
        self.sent.append((endpoint, bytes(data)))
        if data_of([decode_message(data)]):
            self.threads.append(threading.get_ident())


@pytest.mark.parametrize("any_thread", [True, False])
async def test_samples_from_the_middleware_thread(any_thread):
    # A sample a middleware hands over on a thread of its own (RosMiddleware's executor thread)
    # goes out from that thread when the link can send from any thread (UDP), under the engine's
    # lock; otherwise (TCP, serial: asyncio transports) from the loop, in order either way.
    link = ThreadRecordingLink()
    link.threads = []
    link.sends_from_any_thread = any_thread
    agent = Agent(CedMiddleware(), loop=asyncio.get_running_loop())
    listener = Peer(agent, link, ("h", 2), key=b"\x02\x00\x00\x02")
    listener.connect()
    listener.build_pubsub()
    listener.read(0x80, DeliveryControl())
    listener.take()
    link.threads.clear()
    on_data = agent.datapath.sample_callback(agent.clients[listener.key], 0x0016)

    def middleware_thread():
        with agent.lock:  # what RosMiddleware's hand-off takes before it calls on_data
            for i in range(3):
                on_data(bytes([i]))

    thread = threading.Thread(target=middleware_thread)
    thread.start()
    thread.join(5)
    await asyncio.sleep(0.05)  # the loop's turn
    assert data_of(listener.take()) == [b"\x00", b"\x01", b"\x02"]
    loop_thread = threading.get_ident()
    assert all((sender != loop_thread) == any_thread for sender in link.threads)
    assert len(link.threads) == 3
    await agent.close()
