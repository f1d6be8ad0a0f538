"""Agent engine: ACKNACKs for a client's reliable input come as promptly as eProsima's agent sends
them (its Processor sends one after each reliable message): never a round trip late, so a client
sending reliable messages back to back with a history of 8 never finds its history full; and no
more of them than one per reliable message or HEARTBEAT."""

import asyncio

from engine_peer import BIN, Link, Peer, ReadingCed
from xrce.wire import constants as C
from xrce.agent.engine.agent import Agent
from xrce.wire.objects import ParticipantBin, TopicBin
from xrce.wire.submessages import Create, Heartbeat, WriteData

HISTORY = 8  # eProsima's client's default reliable output history (UXR_CONFIG_..._HISTORY)


def _acked_through(messages, stream_id=0x80):
    """The highest client sequence number the ACKNACKs among ``messages`` acknowledge, or -1."""
    acked = -1
    for _, payloads in messages:
        for p in payloads:
            if p.ID == C.ACKNACK and p.stream_id == stream_id:
                acked = max(acked, p.first_unacked - 1)
    return acked


async def test_a_client_answering_each_status_at_once_never_fills_its_history():
    """The client sends its next CREATE the moment a STATUS arrives, all within one read batch
    of the agent (as when its answers reach the socket before the batch ends). The ACKNACKs were
    sent at the batch's end, so after 8 CREATEs the client's history was full and it stalled."""
    agent = Agent(ReadingCed(), loop=asyncio.get_running_loop())
    link = Link()
    peer = Peer(agent, link, ("h", 1))
    assert peer.connect()[1] == C.STATUS_OK
    acked = -1
    statuses = []
    for seq in range(3 * HISTORY):
        assert seq - acked <= HISTORY, "message %d would wait for an ACKNACK: history full" % seq
        object_id = (seq << 4) | C.OBJK_TOPIC if seq else 0x0011
        if seq == 0:
            request = Create(peer.next_request(), 0x0011, C.OBJK_PARTICIPANT, BIN,
                             ParticipantBin("p"), 0, 1)
        else:
            request = Create(peer.next_request(), object_id, C.OBJK_TOPIC, BIN,
                             TopicBin("t%d" % seq, "T"), 0x0011, 1)
        peer.send(0x80, request)
        replies = peer.take()
        acked = max(acked, _acked_through(replies))
        statuses += [p.status for _, ps in replies for p in ps if p.ID == C.STATUS]
        # What this message's STATUS answers, the client has the ACKNACK for already.
        assert acked == seq
        peer.ack_all()  # and it acknowledges the STATUS, as eProsima's client does
    assert statuses == [C.STATUS_OK] * (3 * HISTORY)
    await asyncio.sleep(0)  # the batch's end: nothing was left owed
    assert _acked_through(peer.take()) == -1
    assert agent.stats.acknacks_out == 3 * HISTORY
    await agent.close()


async def test_samples_in_one_batch_share_one_acknack():
    """Samples the agent answers nothing to are acknowledged once, at the batch's end: an ACKNACK
    is cumulative, and the client waits no round trip for it (nothing it could react to came)."""
    agent = Agent(ReadingCed(), loop=asyncio.get_running_loop())
    link = Link()
    peer = Peer(agent, link, ("h", 1))
    peer.connect()
    peer.build_pubsub()
    await asyncio.sleep(0)
    peer.take()
    before = agent.stats.acknacks_out
    for i in range(5):
        peer.send(0x80, WriteData(peer.next_request(), 0x0015, bytes([i, 0, 0, 0])))
    assert _acked_through(peer.take()) == -1  # within the batch: owed
    await asyncio.sleep(0)
    replies = peer.take()
    assert _acked_through(replies) == peer.seqs[0x80] - 1
    assert agent.stats.acknacks_out - before == 1
    # A HEARTBEAT is answered at once, as eProsima's agent answers it.
    peer.send(0, Heartbeat(peer.seqs[0x80] - 1, peer.seqs[0x80] - 1, 0x80))
    assert _acked_through(peer.take()) == peer.seqs[0x80] - 1
    await agent.close()
