"""What the live exchanges of test_eprosima_client.py found, held without eProsima's library: the
clients' messages of a run that went wrong (tests/eprosima/regressions/, eProsima's client against
our agent) replayed against ours, and the acknowledgment a lossy link needs.

- A CED reader created by reference (no QoS: KEEP_LAST 1) whose stream was full of retransmissions
  when two fragmented samples completed at once kept only the later: eProsima's CED keeps a topic's
  last 16 for every reader, and so does ours now for a reader given no QoS.
- One ACKNACK for a read batch of several reliable messages, lost, left eProsima's writer with a
  full history of 8 waiting for its own HEARTBEAT, which its library sends only after 100 ms
  without polling (never, for a program polling every few milliseconds), where eProsima's agent
  sends one per message. Ours repeats a batch's ACKNACK while the client stays silent on the
  stream, at most once per message it covered beyond the first.
"""

import asyncio
import json
from pathlib import Path

import eprosima_golden as golden
from xrce.agent.engine import liveliness
from xrce.wire import constants as C
from xrce.wire.submessages import decode_message

REGRESSIONS = Path(__file__).resolve().parent / "regressions"


def _load(name):
    lines = (REGRESSIONS / ("%s.jsonl" % name)).read_text().splitlines()
    return json.loads(lines[0]), [json.loads(line) for line in lines[1:]]


async def test_a_by_reference_reader_behind_retransmissions_loses_no_sample():
    header, rows = _load("ced_reader_blocked_tcp4")
    assert {row["dir"] for row in rows} == {"C->A"}
    count = int(header["argv"][1])
    ours = await golden.replay_exchange(rows)
    indices = [int.from_bytes(sample[:4], "little") for _, sample in golden.delivered(ours[0])]
    assert indices == list(range(1, count + 1))


def _acknacks(link, stream_id=0x80):
    return [(p.first_unacked, p.nack_bitmap) for data in link.sent
            for p in decode_message(data)[1] if p.ID == C.ACKNACK and p.stream_id == stream_id]


async def _writer_session(rows):
    """An agent with ``-m ced``'s middleware on a running loop, the writer's (client 1) messages
    of a recording fed up to its first sample; returns (agent, link, the rest of its messages)."""
    from xrce.agent.engine.agent import Agent
    from xrce.agent.middleware.ced import CedMiddleware

    agent = Agent(CedMiddleware(), loop=asyncio.get_running_loop())
    link = golden.Link()
    messages = [bytes.fromhex(r["hex"]) for r in rows if r["dir"] == "C->A" and r["client"] == 1]
    samples = [m for m in messages if m[1] == 0x80 and any(
        p.ID == C.WRITE_DATA for p in decode_message(m)[1])]
    head = messages[:messages.index(samples[0])]
    for message in head:
        agent.receive(link, ("client", 1), message)
        await asyncio.sleep(0.01)
    return agent, link, samples


async def test_a_batchs_acknack_is_repeated_while_the_client_is_silent():
    _, rows = golden.load("exchange_reliable_10_udp4")
    agent, link, samples = await _writer_session(rows)
    try:
        before = len(_acknacks(link))
        for message in samples[:3]:  # one read batch: no loop turn between them
            agent.receive(link, ("client", 1), message)
        await asyncio.sleep(0)
        sent = _acknacks(link)[before:]
        assert len(sent) == 1  # the batch's one ACKNACK
        await asyncio.sleep(liveliness.ACKNACK_REPEATS_S[-1] + 0.2)
        repeats = _acknacks(link)[before + 1:]
        # Three messages, one ACKNACK: two repeats at most, of that same ACKNACK, so never more
        # than eProsima's one per message.
        assert repeats == [sent[0]] * 2
    finally:
        await agent.close()


async def test_no_repeat_for_one_message_nor_once_the_stream_moved_on():
    _, rows = golden.load("exchange_reliable_10_udp4")
    agent, link, samples = await _writer_session(rows)
    try:
        before = len(_acknacks(link))
        agent.receive(link, ("client", 1), samples[0])
        await asyncio.sleep(liveliness.ACKNACK_REPEATS_S[-1] + 0.2)
        assert len(_acknacks(link)) == before + 1  # one message, one ACKNACK, no repeat
        agent.receive(link, ("client", 1), samples[1])
        agent.receive(link, ("client", 1), samples[2])
        await asyncio.sleep(0)
        agent.receive(link, ("client", 1), samples[3])  # before the first repeat was due
        await asyncio.sleep(0)
        assert len(_acknacks(link)) == before + 3
        await asyncio.sleep(liveliness.ACKNACK_REPEATS_S[-1] + 0.2)
        # The two-message batch's repeat was superseded by the next ACKNACK; that one covered
        # a single message: nothing more.
        assert len(_acknacks(link)) == before + 3
    finally:
        await agent.close()


async def test_a_batch_of_retransmissions_counts_as_messages_answered():
    """After a lost ACKNACK the client sends its unacknowledged messages again: all but the
    missing one are duplicates, and the one ACKNACK that then frees its whole history must not
    be the only one (eProsima's agent answers each)."""
    _, rows = golden.load("exchange_reliable_10_udp4")
    agent, link, samples = await _writer_session(rows)
    try:
        for message in samples[:3]:
            agent.receive(link, ("client", 1), message)
        await asyncio.sleep(liveliness.ACKNACK_REPEATS_S[-1] + 0.2)
        before = len(_acknacks(link))
        for message in samples[:3]:  # all three again, nothing new
            agent.receive(link, ("client", 1), message)
        agent.receive(link, ("client", 1), samples[3])
        await asyncio.sleep(liveliness.ACKNACK_REPEATS_S[-1] + 0.2)
        sent = _acknacks(link)[before:]
        assert len(sent) == 4 and len(set(sent)) == 1  # one and three repeats: four answered
    finally:
        await agent.close()
