"""Reading tests/golden/eprosima/ (recorded by record_eprosima.py) and replaying it against our engine.

``load(name)``: (header, rows). ``replay_creations(rows)`` feeds the client's datagrams to an
in-process agent with ``-m ced``'s middleware on a running loop, the loop's turns only those the
agent itself asks for (after each CREATE it serves the loop before the rest of that client's
input), so one read batch spans every round trip, the worst case for acknowledgments; it
returns what the agent sent.
"""

from __future__ import annotations

import json
from pathlib import Path

from xrce.wire import constants as C
from xrce.wire.submessages import decode_message

GOLDEN = Path(__file__).resolve().parents[1] / "golden" / "eprosima"


def names(prefix=""):
    return sorted(p.stem for p in GOLDEN.glob("%s*.jsonl" % prefix))


def load(name):
    lines = (GOLDEN / ("%s.jsonl" % name)).read_text().splitlines()
    header = json.loads(lines[0])
    return header, [json.loads(line) for line in lines[1:]]


def statuses(messages):
    """{(request id, object id): status} of every STATUS (and STATUS_AGENT) among ``messages``
    (raw bytes), in the order first sent: a retransmission repeats one, it adds none."""
    found = {}
    for data in messages:
        _, payloads = decode_message(data)
        for p in payloads:
            if p.ID == C.STATUS:
                found.setdefault((p.request_id, p.object_id), p.status)
            elif p.ID == C.STATUS_AGENT:
                found.setdefault("client", p.status)
    return found


def count(messages, sub_id):
    return sum(1 for data in messages for p in decode_message(data)[1] if p.ID == sub_id)


class Link:
    name = "replay"

    def __init__(self):
        self.sent = []

    def send(self, endpoint, data):
        self.sent.append(bytes(data))


async def replay_creations(rows):
    """Our agent's answers to the recorded client, and for each reliable message the client sent
    whether, once it was answered, the client had been told it arrived: [(seq, answered, acked
    through)] with ``acked through`` the highest sequence number the agent's ACKNACKs named
    received by the end of its answer."""
    import asyncio

    from xrce.agent.engine.dispatch import Agent
    from xrce.agent.middleware.ced import CedMiddleware

    agent = Agent(CedMiddleware(), loop=asyncio.get_running_loop())
    link = Link()
    endpoint = ("client", 1)
    acked = -1
    trail = []
    for row in rows:
        if row["dir"] != "C->A":
            continue
        data = bytes.fromhex(row["hex"])
        before = len(link.sent)
        agent.receive(link, endpoint, data)
        for _ in range(64):  # the agent yields to the loop after each CREATE: let it go on
            if not any(c.parked for c in agent.clients.values()):
                break
            await asyncio.sleep(0)
        answer = link.sent[before:]
        for message in answer:
            _, payloads = decode_message(message)
            for p in payloads:
                if p.ID == C.ACKNACK and p.stream_id == data[1]:
                    acked = max(acked, p.first_unacked - 1)
        if data[1] & 0x80:
            seq = data[2] | (data[3] << 8)
            trail.append((seq, any(m[4] == C.STATUS for m in answer), acked))
    await asyncio.sleep(0)  # the batch's end
    await agent.close()
    return link.sent, trail
