"""Agent engine: liveliness (XRCE-WIRE.md §7): the reliable output window, HEARTBEAT and NACK
retransmission, dead clients, and the timer that runs that work only when it is due."""

import asyncio

import pytest

from engine_peer import BIN, Link, Peer, data_of, talker_and_listener
from xrce.wire import constants as C
from xrce.agent.middleware.ced import CedMiddleware
from xrce.agent.engine.agent import Agent
from xrce.wire.objects import ParticipantBin
from xrce.wire.submessages import AckNack, Create, DeliveryControl, GetInfo, WriteData


def test_reliable_window_heartbeat_and_nack(ced_agent):
    agent, link = ced_agent
    clock = agent.clock
    talker, listener = talker_and_listener(agent, link, listener_depth=40)
    listener.read(0x80, DeliveryControl())
    for i in range(20):
        talker.write(bytes([i]))
    sent = listener.take()
    assert data_of(sent) == [bytes([i]) for i in range(16)]  # window of 16, nothing acknowledged
    first_seq = [h.seq for h, ps in sent if ps[0].ID == C.DATA][0]
    clock.now += 0.2
    agent.tick()
    (header, (heartbeat,)), = listener.take()
    assert heartbeat.ID == C.HEARTBEAT and (heartbeat.first_unacked, heartbeat.last_unacked) == (
        first_seq, (first_seq + 15) & 0xFFFF)
    # NACK two of them: exactly those are resent; the acknowledged part frees room for the rest.
    listener.send(0, AckNack(first_seq + 2, 0b101, 0x80))
    resent = listener.take()
    assert [h.seq for h, _ in resent[:2]] == [first_seq + 2, first_seq + 4]
    assert data_of(resent[2:]) == [bytes([i]) for i in range(16, 18)]
    assert agent.stats.retransmissions == 2
    # A dead client gets no heartbeats; any message revives it.
    clock.now += agent.client_dead_time + 1
    agent.tick()
    assert listener.take() == []
    listener.send(0, GetInfo())
    listener.take()
    agent.tick()
    assert [ps[0].ID for _, ps in listener.take()] == [C.HEARTBEAT]


def test_run_sends_heartbeats_and_close_deletes_everything():
    async def scenario():
        link = Link()
        agent = Agent(CedMiddleware(), heartbeat_period=0.02)
        peer = Peer(agent, link, ("h", 1))
        peer.connect()
        peer.build_pubsub()
        peer.send(0x80, Create(0x70, 0x0021, C.OBJK_PARTICIPANT, BIN, ParticipantBin("y"), 0))
        peer.take()
        task = asyncio.ensure_future(agent.run())
        await asyncio.sleep(0.15)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        heartbeats = [ps[0] for _, ps in peer.take() if ps[0].ID == C.HEARTBEAT]
        assert len(heartbeats) >= 3 and all(h.stream_id == 0x80 for h in heartbeats)
        await agent.close()
        assert not agent.clients and not agent.middleware.participants
    asyncio.run(asyncio.wait_for(scenario(), 5))


def test_timed_work_is_scheduled_when_due_and_nothing_runs_when_idle():
    async def scenario():
        link = Link()
        agent = Agent(CedMiddleware(), heartbeat_period=0.02, client_dead_time=0.3)
        ticks = []
        tick = agent.tick
        agent.tick = lambda: (ticks.append(agent.clock()), tick())[1]
        task = asyncio.ensure_future(agent.run())
        await asyncio.sleep(0.2)
        assert len(ticks) == 1 and agent.next_wakeup is None  # no client: no timer at all
        peer = Peer(agent, link, ("h", 1))
        # The wake-up is bracketed by the clock before and after the call that sets it, so a
        # loaded machine that is slow between the two lines cannot fail the check.
        before = agent.clock()
        peer.connect()  # a session: its dead time is due
        assert before + 0.3 <= agent.next_wakeup <= agent.clock() + 0.3
        peer.build_pubsub()  # acknowledged output: still only the dead time
        peer.take()
        peer.read(0x80, DeliveryControl())
        before = agent.clock()
        peer.send(0x80, WriteData(0x60, 0x0015, b"unacknowledged"))
        # The HEARTBEAT period is counted from the scheduler's own stamp, which may precede
        # `before`: what matters is that the wake-up is now a period away, not the dead time.
        assert before - 0.02 < agent.next_wakeup <= agent.clock() + 0.02
        await asyncio.sleep(0.1)
        heartbeats = [ps[0] for _, ps in peer.take() if ps[0].ID == C.HEARTBEAT]
        assert len(heartbeats) >= 2  # sent by the timer, nobody called tick()
        peer.ack_all()
        del ticks[:]
        await asyncio.sleep(0.1)
        assert len(ticks) <= 1 and not [1 for _, ps in peer.take() if ps[0].ID == C.HEARTBEAT]
        await asyncio.sleep(0.3)  # past the dead time: dead, and nothing more to do for it
        assert agent.stats.clients_dead == 1 and agent.next_wakeup is None
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        await agent.close()
    asyncio.run(asyncio.wait_for(scenario(), 5))


def test_a_receive_only_client_past_the_dead_time_is_not_called_dead(ced_agent, caplog):
    """A best-effort subscriber says nothing while its samples arrive: past the dead time the
    agent still pauses HEARTBEATs for it (eProsima's semantics), but the log says that it still
    reads, not "dead"; a client with no READ_DATA in force is reported dead as before."""
    agent, link = ced_agent
    talker, listener = talker_and_listener(agent, link, reliable=False)
    listener.read(0x01, DeliveryControl())
    caplog.set_level("INFO", logger="xrce.agent")
    agent.clock.now += agent.client_dead_time + 1
    talker.write(b"still flowing", stream_id=0x01)  # the talker speaks; the listener only reads
    agent.tick()
    assert data_of(listener.take()) == [b"still flowing"]
    listener_key = listener.key.hex()
    lines = [r.getMessage() for r in caplog.records if listener_key in r.getMessage()]
    assert len(lines) == 1 and "still reads" in lines[0] and "dead" not in lines[0], lines
    agent.clock.now += agent.client_dead_time + 1
    agent.tick()
    talker_lines = [r.getMessage() for r in caplog.records if talker.key.hex() in r.getMessage()]
    assert any("dead (no more HEARTBEATs" in line for line in talker_lines), talker_lines
