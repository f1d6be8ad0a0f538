"""Samples larger than 64 KiB, both ways (issue 21): a WRITE_DATA whose length is carried by its
FRAGMENTs (length 0 in the submessage header, as the C client writes samples over 64 KiB), FRAGMENT
chains longer than the window, agent output in more fragments than the window holds, and a large
sample that does not hold up the samples behind it.

End to end: our client, a real ``xrce-agent -m dds`` over UDP with MTU 512 and reliable streams, and
rclpy in the test; in process: the engine with CED behind it.
"""

import time

import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String as RosString

from agent_process import AgentProcess
from engine_peer import BIN, Link, Peer, data_of, talker_and_listener
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from xrce.wire import constants as C
from xrce.agent.middleware.ced import CedMiddleware
from xrce.agent.engine.agent import Agent
from xrce.client.session import Session
from xrce.wire.message import iter_submessages
from xrce.msgs.std_msgs import String
from xrce.wire.submessages import (
    AckNack, Create, DeliveryControl, Fragment, Heartbeat, decode_message, encode_message,
)
from xrce.transports.udp import UdpTransport

BIG = 256 * 1024


def _text(size, seed):
    return "".join(chr(ord("a") + (i * seed) % 26) for i in range(size))


def test_256_kib_client_to_ros_and_ros_to_client_over_udp_mtu_512(ros_domain, ros_peer):  # noqa: F811
    got_ros, got_client = [], []
    reliable = QoSProfile(depth=4, reliability=ReliabilityPolicy.RELIABLE)
    ros_peer.node.create_subscription(RosString, "/big_up", got_ros.append, reliable)
    ros_pub = ros_peer.node.create_publisher(RosString, "/big_down", reliable)
    with AgentProcess("udp4", "-m", "dds") as agent:
        session = Session(UdpTransport("127.0.0.1", agent.port, mtu=512), history=16,
                          max_reassembly=BIG + 4096)
        try:
            assert session.create(attempts=5, timeout_ms=1000)
            node = session.create_participant(domain_id=ros_domain, name="big_node")
            up = session.create_writer(node, "/big_up", String, reliable=True, depth=4)
            session.create_reader(node, "/big_down", String, got_client.append, reliable=True,
                                  depth=4)
            assert session.run_until_all_status(5000), session.last_statuses
            assert wait_until(lambda: ros_peer.node.count_subscribers("/big_down") >= 1
                              and ros_peer.node.count_publishers("/big_up") >= 1, 10)

            # Both DDS matches complete (the graph shows an endpoint before its reliable match
            # does, and a volatile sample written meanwhile reaches no one): small samples first.
            deadline = time.monotonic() + 15
            while not (got_ros and got_client) and time.monotonic() < deadline:
                if not got_ros:
                    session.write(up, String(data="warm"))
                if not got_client:
                    ros_pub.publish(RosString(data="warm"))
                session.run_until_timeout(100)
            assert got_ros and got_client
            del got_ros[:], got_client[:]

            text_up = _text(BIG, 7)
            started = time.monotonic()
            assert session.write(up, String(data=text_up))  # > 64 KiB: FRAGMENTs, length 0
            assert session.run_until_confirm_delivery(20000)
            assert wait_until(lambda: any(m.data != "warm" for m in got_ros), 20)
            print("client -> ROS: %d bytes in %.2f s" % (BIG, time.monotonic() - started))
            assert [m.data for m in got_ros if m.data != "warm"] == [text_up]

            text_down = _text(BIG, 11)
            started = time.monotonic()
            ros_pub.publish(RosString(data=text_down))
            ros_pub.publish(RosString(data="small behind it"))
            deadline = time.monotonic() + 30
            while len([m for m in got_client if m.data != "warm"]) < 2 and \
                    time.monotonic() < deadline:
                session.spin_once(20)
            print("ROS -> client: %d bytes in %.2f s" % (BIG, time.monotonic() - started))
            del got_client[:len(got_client) - 2]  # a late warm-up copy, if any
            assert [len(m.data) for m in got_client] == [BIG, len("small behind it")]
            assert got_client[0].data == text_down and got_client[1].data == "small behind it"
        finally:
            session.delete(attempts=2, timeout_ms=500)
            session.close()
        assert agent.stop() == 0


# ------------------------------------------------------------------------------- in process

class FragmentReceiver:
    """The client's side of the agent's reliable output on 0x80: in-order reassembly, an ACKNACK
    for every HEARTBEAT (what both eProsima's client and ours do)."""

    def __init__(self, peer):
        self.peer = peer
        self.next_seq = 0
        self.buffer = None
        self.samples = []
        self.fragments = 0

    def pump(self):
        for raw in self.peer.take_raw():
            header, payloads = decode_message(raw)
            if header.stream_id == 0x80 and header.seq == self.next_seq:
                self.next_seq = (self.next_seq + 1) & 0xFFFF
                self._message(raw, header.size)
            for payload in payloads:
                if payload.ID == C.HEARTBEAT and payload.stream_id == 0x80:
                    self.peer.send(0, AckNack(self.next_seq, 0, 0x80))

    def _message(self, raw, start):
        for sub_id, flags, s, e in iter_submessages(raw, start):
            if sub_id == C.FRAGMENT:
                self.fragments += 1
                if self.buffer is None:
                    self.buffer = bytearray(raw[:start])
                self.buffer += raw[s:e]
                if flags & C.FLAG_LAST_FRAGMENT:
                    whole, self.buffer = bytes(self.buffer), None
                    self._message(whole, start)
            elif sub_id == C.DATA:
                self.samples.append(bytes(raw[s + 4:e if e > s else len(raw)]))
                if e == s:
                    return


def _write_in_fragments(peer, sample, object_id=0x0015, chunk=400):
    """A WRITE_DATA of ``sample`` with length 0 cut into FRAGMENTs on 0x80, as the C client does."""
    body = bytes((C.WRITE_DATA, C.FLAG_LITTLE_ENDIAN, 0, 0, 0, 0x77, object_id >> 8,
                  object_id & 0xFF)) + sample
    pieces = [body[i:i + chunk] for i in range(0, len(body), chunk)]
    for index, piece in enumerate(pieces):
        flags = C.FLAG_LITTLE_ENDIAN | (C.FLAG_LAST_FRAGMENT if index == len(pieces) - 1 else 0)
        peer.send(0x80, Fragment(piece, flags))
    return len(pieces)


def test_length_0_write_data_in_a_long_chain_and_output_beyond_the_window(ced_agent):
    agent, link = ced_agent
    talker, listener = talker_and_listener(agent, link)
    listener.read(0x80, DeliveryControl(0xFFFF, 0, 0, 0))
    receiver = FragmentReceiver(listener)
    receiver.next_seq = (agent.clients[listener.key].out_reliable[0x80].last_sent + 1) & 0xFFFF
    listener.take()
    sample = bytes(range(256)) * (300 * 1024 // 256)  # 300 KiB, CDR-opaque to CED
    count = _write_in_fragments(talker, sample)
    assert count > 700  # a chain far longer than the 16-message window
    assert agent.stats.samples_in >= 1 and agent.stats.reassembly_overflows == 0
    talker.write(b"\x05\x00\x00\x00tiny\x00")  # behind the big one, to the same reader
    for _ in range(2000):
        receiver.pump()
        if len(receiver.samples) >= 2:
            break
    assert receiver.samples[0] == sample
    assert receiver.samples[1] == b"\x05\x00\x00\x00tiny\x00"
    assert receiver.fragments > 600  # the agent cut it into many windows of 16
    assert agent.stats.handler_errors == 0
    client = agent.clients[listener.key]
    assert not client.out_pending  # everything went out


def test_a_status_waits_for_room_when_readers_samples_fill_the_window(ced_agent):
    """A board's CREATE while the samples of one of its readers fill its reliable output window
    (micro-ROS' Graph, fragmented, to a graph-enabled board): the CREATE is acknowledged, so its
    STATUS must reach the board once an ACKNACK frees room, ahead of the samples still queued.
    rmw_microxrcedds waits for that STATUS; it was dropped (the graph replay stalled)."""
    from xrce.wire.objects import PubSubBin

    agent, link = ced_agent
    talker, listener = talker_and_listener(agent, link, listener_depth=64)
    listener.read(0x80, DeliveryControl(0xFFFF, 0, 0, 0))
    listener.ack_all()
    listener.take()
    for index in range(24):  # more than the 16-message window
        talker.write(b"\x05\x00\x00\x00s%03d\x00" % index)
    client = agent.clients[listener.key]
    assert not client.out_reliable[0x80].has_room()
    request_id = listener.next_request()
    listener.send(0x80, Create(request_id, 0x0024, C.OBJK_PUBLISHER, BIN, PubSubBin(), 0x0011, 1))
    first = listener.take()
    assert len(data_of(first)) == 16 and not [p for _, ps in first for p in ps
                                               if p.ID == C.STATUS and p.request_id == request_id]
    listener.ack_all()  # what the board's client library sends for what it received
    after = [p for _, ps in listener.take() for p in ps if p.ID in (C.STATUS, C.DATA)]
    assert after[0].ID == C.STATUS and after[0].request_id == request_id, after[:2]
    assert after[0].status == C.STATUS_OK
    assert len([p for p in after if p.ID == C.DATA]) == 8  # the rest follow, none lost
    assert agent.stats.status_lost == 0
