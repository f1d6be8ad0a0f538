"""Agent engine: streams (XRCE-WIRE.md §7, §8): reliable input in order with duplicates dropped,
and fragmentation in both directions."""

from engine_peer import BIN, Peer, data_of, talker_and_listener
from xrce.wire import constants as C
from xrce.wire.objects import ParticipantBin
from xrce.wire.submessages import Create, DeliveryControl, Fragment, Heartbeat, WriteData, encode_message


def test_reliable_input_acknack_duplicates_and_heartbeat(ced_agent):
    agent, link = ced_agent
    peer = Peer(agent, link, ("h", 1))
    peer.connect()
    create = Create(0x50, 0x0011, C.OBJK_PARTICIPANT, BIN, ParticipantBin("x"), 0)
    peer.send(0x80, create, seq=1)  # seq 0 lost: stored, not processed
    acks = [ps[0] for _, ps in peer.take() if ps[0].ID == C.ACKNACK]
    assert [(a.first_unacked, a.nack_bitmap) for a in acks] == [(0, 0b1)]
    peer.send(0, Heartbeat(0, 1, 0x80))
    acks = [ps[0] for _, ps in peer.take()]
    assert [(a.ID, a.first_unacked, a.nack_bitmap) for a in acks] == [(C.ACKNACK, 0, 0b1)]
    peer.send(0x80, Create(0x4F, 0x0021, C.OBJK_PARTICIPANT, BIN, ParticipantBin("y"), 0), seq=0)
    assert [s[1] for s in peer.statuses()] == [0x4F, 0x50]
    peer.send(0x80, create, seq=1)  # duplicate: acknowledged again, not processed
    (header, (ack,)), = peer.take()
    assert (ack.ID, ack.first_unacked, ack.nack_bitmap) == (C.ACKNACK, 2, 0)
    assert agent.stats.duplicates == 1


def test_fragmentation_out_at_small_mtu(ced_agent):
    agent, link = ced_agent
    talker, listener = talker_and_listener(agent, link, listener_mtu=64)
    request = listener.read(0x80, DeliveryControl())
    listener.take()
    sample = bytes(range(200))
    talker.write(sample)
    raw = listener.take_raw()
    assert all(len(m) <= 64 for m in raw)
    assert [m[4] for m in raw] == [C.FRAGMENT] * len(raw)
    assert [m[5] for m in raw] == [0x01] * (len(raw) - 1) + [0x03]
    assert all(len(m) == 64 for m in raw[:-1])  # chunk = mtu - header - 4
    inner = b"".join(m[8:] for m in raw)
    assert inner[:4] == bytes((C.DATA, 1, 204, 0)) and inner[4:6] == request.to_bytes(2, "big")
    assert inner[8:] == sample
    # Best-effort output larger than the mtu is dropped and counted.
    listener.ack_all()
    listener.read(0x01, DeliveryControl())
    listener.take()
    talker.write(sample)
    assert listener.take_raw() == [] and agent.stats.oversize_dropped == 1


def test_fragment_reassembly_in(ced_agent):
    agent, link = ced_agent
    talker, listener = talker_and_listener(agent, link, listener_mtu=4096)
    listener.read(0x80, DeliveryControl())
    sample = bytes(range(256)) * 5
    inner = encode_message(0x81, 0x80, 0, None, [WriteData(0x60, 0x0015, sample)])[4:]
    chunks = [inner[i:i + 500] for i in range(0, len(inner), 500)]
    base = talker.seqs[0x80]
    # Delivered out of order: the stream puts them back in sequence before reassembly.
    for index in (2, 0, 1):
        flags = 0x03 if index == len(chunks) - 1 else 0x01
        talker.send(0x80, Fragment(chunks[index], flags), seq=base + index)
    assert data_of(listener.take()) == [sample]
    # A reassembly growing past the bound is abandoned and counted.
    agent.max_reassembly_bytes = 600
    talker.seqs[0x80] = base + 3
    for index, chunk in enumerate(chunks):
        talker.send(0x80, Fragment(chunk, 0x03 if index == len(chunks) - 1 else 0x01))
    assert data_of(listener.take()) == [] and agent.stats.reassembly_overflows >= 1
