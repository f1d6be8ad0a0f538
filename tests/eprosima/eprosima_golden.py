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
    sends_from_any_thread = False
    fastpath = None
    info_locators = ()

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

    from xrce.agent.engine.agent import Agent
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


def by_client(rows, direction):
    """{client: [message bytes]} of the rows going ``direction`` (a one-client recording: 0)."""
    found = {}
    for row in rows:
        if row["dir"] == direction:
            found.setdefault(row.get("client", 0), []).append(bytes.fromhex(row["hex"]))
    return found


def delivered(messages):
    """The samples a client was given among ``messages`` (what an agent sent it), in the order its
    streams deliver them: a reliable stream's messages once each, by sequence number, FRAGMENTs
    joined into the submessages they carry; a best-effort stream's as they came. [(object id,
    sample bytes)]."""
    from xrce.wire.message import iter_submessages
    from xrce.wire.submessages import decode_payload

    reliable, samples = {}, []
    for data in messages:
        if data[1] & 0x80:
            reliable.setdefault(data[1], {}).setdefault(data[2] | (data[3] << 8), data)
        else:
            samples += [(p.object_id, bytes(p.data)) for p in decode_message(data)[1] if p.ID == C.DATA]
    for stream in reliable.values():
        pending = b""
        for seq in sorted(stream):
            for p in decode_message(stream[seq])[1]:
                if p.ID == C.DATA:
                    samples.append((p.object_id, bytes(p.data)))
                elif p.ID == C.FRAGMENT:
                    pending += bytes(p.data)
                    if p.last:
                        # The joined bytes are submessages as a message would hold them; CDR
                        # alignment counts from the message start, the header's 4 bytes (session
                        # without key) ahead: pad so offsets stay as on the wire.
                        whole = bytes(4) + pending
                        for sub_id, flags, start, end in iter_submessages(whole, 4):
                            inner = decode_payload(sub_id, flags, whole, start, end)
                            if inner.ID == C.DATA:
                                samples.append((inner.object_id, bytes(inner.data)))
                        pending = b""
    return samples


def unframe(rows):
    """Each TCP or serial row's framed bytes taken apart by our framing: [(row, message)]."""
    from xrce.transports.framing import FrameDecoder, LengthPrefixDecoder

    out = []
    for row in rows:
        if "frame" not in row:
            continue
        frame = bytes.fromhex(row["frame"])
        if frame[:1] == b"\x7e":
            messages = [payload for _, _, payload in FrameDecoder().feed(frame)]
        else:
            messages = LengthPrefixDecoder().feed(frame)
        out.append((row, messages))
    return out


async def replay_exchange(rows):
    """Every client's recorded messages fed, in the recorded order, to an in-process agent with
    ``-m ced``'s middleware, each client from an endpoint of its own, the loop turned after each
    as the agent asks; {client: [what the agent sent it]}."""
    import asyncio

    from xrce.agent.engine.agent import Agent
    from xrce.agent.middleware.ced import CedMiddleware

    agent = Agent(CedMiddleware(), loop=asyncio.get_running_loop())
    links = {}
    for row in rows:
        if row["dir"] != "C->A":
            continue
        client = row.get("client", 0)
        link = links.setdefault(client, Link())
        agent.receive(link, ("client", client), bytes.fromhex(row["hex"]))
        for _ in range(64):
            if not any(c.parked for c in agent.clients.values()):
                break
            await asyncio.sleep(0)
        await asyncio.sleep(0)  # what the middleware hands on through the loop (a reader's data)
    await asyncio.sleep(0)
    await agent.close()
    return {client: link.sent for client, link in links.items()}


def move_domain(message, domain):
    """``message`` (a client's, raw) with each participant it CREATEs moved to DDS domain
    ``domain``: a recording's participants are in the recorder's domain, a replay's in the one it
    leased. The domain id is the participant's last field, its length fixed: nothing else moves."""
    from xrce.wire.message import iter_submessages

    out = bytearray(message)
    for sub_id, flags, start, end in iter_submessages(out, 4 if out[0] & 0x80 else 8):
        if sub_id == C.CREATE and out[start + 3] & 0x0F == C.OBJK_PARTICIPANT:
            out[end - 2:end] = domain.to_bytes(2, "little" if flags & 1 else "big")
    return bytes(out)


def replay_over_udp(rows, host, port, domain, family=None, linger_s=1.0):
    """Every client's recorded messages sent to a real agent at ``host``/``port`` over UDP, each
    client from a socket of its own, at the recorded times (the recorded program waited on DDS
    matching between creating and writing; the replay keeps those waits), participants moved to
    ``domain``; what the agent sent each client until ``linger_s`` after the last. {client:
    [messages]}."""
    import select
    import socket
    import time

    family = family or (socket.AF_INET6 if ":" in host else socket.AF_INET)
    sends = [(row["t"], row.get("client", 0), move_domain(bytes.fromhex(row["hex"]), domain))
             for row in rows if row["dir"] == "C->A"]
    first = sends[0][0]
    sockets, got = {}, {}
    try:
        for _, client, _ in sends:
            if client not in sockets:
                sock = socket.socket(family, socket.SOCK_DGRAM)
                sock.connect((host, port))
                sockets[client] = sock
                got[client] = []
        start = time.monotonic()
        pending = list(sends)
        end = None
        while end is None or time.monotonic() < end:
            now = time.monotonic() - start
            while pending and pending[0][0] - first <= now:
                _, client, data = pending.pop(0)
                sockets[client].send(data)
            if not pending and end is None:
                end = time.monotonic() + linger_s
            wait = (pending[0][0] - first - now) if pending else 0.05
            ready, _, _ = select.select(list(sockets.values()), [], [], max(0.0, min(wait, 0.05)))
            for client, sock in sockets.items():
                if sock in ready:
                    got[client].append(sock.recv(65536))
    finally:
        for sock in sockets.values():
            sock.close()
    return got
