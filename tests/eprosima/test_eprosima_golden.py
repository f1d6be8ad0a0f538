"""eProsima's client against eProsima's agent, recorded (tests/golden/eprosima/, record_eprosima.py), replayed
against ours, every answer compared; no eProsima library needed.

- CED by XML and by reference, REUSE and REPLACE (``-m ced``, UDP4 and UDP6): every STATUS our
  agent sends equals eProsima's, request by request;
- nine and more reliable creations back to back, and a batch of them: the same STATUS, each
  answered message acknowledged by the time its answer is out (the whole capture fed within one
  read batch of the agent), and no more ACKNACKs or HEARTBEATs than eProsima's agent sent;
- two clients, a writer and a reader, exchanging 1, 10 and fragmented (1.5 x MTU) samples on
  best-effort and reliable streams with 0, 5 and 10 % of their messages dropped by their own
  transport, over UDP4, UDP6, TCP4, TCP6 and serial: both clients' messages fed as recorded, every
  STATUS each client got and every sample the reader was given equal to eProsima's;
- discovery from a UDP4 and a UDP6 agent: our INFO has eProsima's bytes, given the addresses the
  recording host had (127.0.0.1, ::1);
- TCP's length prefix and serial's frames: ours take eProsima's apart into the recorded messages
  and frame each message into eProsima's very bytes.
"""

import asyncio
import socket

import pytest

import eprosima_golden as golden
from xrce.wire import constants as C
from xrce.agent.links import udp as udp_links
from xrce.wire.submessages import decode_message

CREATIONS = golden.names("ced_") + golden.names("back_to_back_") + golden.names("batch_")


def test_every_scenario_was_recorded():
    import eprosima_scenarios as scenarios

    assert set(golden.names()) == (set(scenarios.CREATIONS) | set(scenarios.DISCOVERY)
                                   | set(scenarios.EXCHANGES) | set(scenarios.DDS_EXCHANGES))


@pytest.mark.parametrize("name", CREATIONS)
async def test_statuses_match_eprosimas(name):
    header, rows = golden.load(name)
    theirs = [bytes.fromhex(r["hex"]) for r in rows if r["dir"] == "A->C"]
    ours, _ = await golden.replay_creations(rows)
    expected = golden.statuses(theirs)
    # The program's STATUS lines, the session's STATUS_AGENT and its DELETE's STATUS.
    assert len(expected) == len([line for line in header["stdout"] if line.startswith("STATUS")]) + 2
    assert golden.statuses(ours) == expected


@pytest.mark.parametrize("name", CREATIONS)
async def test_acknowledgments_as_prompt_and_no_more_than_eprosimas(name):
    _, rows = golden.load(name)
    theirs = [bytes.fromhex(r["hex"]) for r in rows if r["dir"] == "A->C"]
    ours, trail = await golden.replay_creations(rows)
    for seq, answered, acked_through in trail:
        if answered:  # the client may react at once: it knows its message arrived
            assert acked_through >= seq, "message %d answered before it was acknowledged" % seq
    assert golden.count(ours, C.ACKNACK) <= golden.count(theirs, C.ACKNACK)
    assert golden.count(ours, C.HEARTBEAT) <= golden.count(theirs, C.HEARTBEAT)


@pytest.mark.parametrize("name", golden.names("discovery_"))
async def test_discovery_answer_is_eprosimas(name, monkeypatch):
    header, rows = golden.load(name)
    family = socket.AF_INET6 if header["transport"].endswith("6") else socket.AF_INET
    # The recording host's addresses (a private loopback), so the bytes compare whole.
    monkeypatch.setattr(udp_links, "local_ipv4_addresses", lambda: [socket.inet_aton("127.0.0.1")])
    monkeypatch.setattr(udp_links, "local_ipv6_addresses",
                        lambda: [socket.inet_pton(socket.AF_INET6, "::1")])
    server = udp_links.DiscoveryServer(agent_port=header["agent_port"], port=0, family=family)
    await server.start()
    loop = asyncio.get_running_loop()
    requests = [bytes.fromhex(r["hex"]) for r in rows if r["dir"] == "C->A"]
    answers = [bytes.fromhex(r["hex"]) for r in rows if r["dir"] == "A->C"]
    assert len(requests) == len(answers) >= 1
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as client:
            client.setblocking(False)
            client.connect(("127.0.0.1", server.port))
            for request, answer in zip(requests, answers):
                client.send(request)
                assert await asyncio.wait_for(loop.sock_recv(client, 2048), 10) == answer
    finally:
        await server.close()
    (info,) = decode_message(answers[0])[1]
    kinds = {C.LOCATOR_LARGE if family == socket.AF_INET6 else C.LOCATOR_MEDIUM}
    assert {loc.fmt for loc in info.locators} == kinds  # what eProsima's client was told
    assert "AGENT %s" % ("ipv6 ::1" if family == socket.AF_INET6 else "ipv4 127.0.0.1") in \
        " ".join(header["stdout"])


@pytest.mark.parametrize("name", golden.names("exchange_"))
async def test_two_clients_get_eprosimas_answers(name):
    header, rows = golden.load(name)
    import eprosima_scenarios as scenarios

    stream, count, size, _, _ = scenarios.EXCHANGES[name][1]
    assert header["argv"] == scenarios.exchange_argv(scenarios.EXCHANGES[name][1])
    theirs = golden.by_client(rows, "A->C")
    ours = await golden.replay_exchange(rows)
    assert sorted(theirs) == sorted(ours) == [0, 1]  # the reader spoke first
    for client in (0, 1):
        # Each client's session, its four creations and (the reader) its READ_DATA; the DELETE.
        assert golden.statuses(ours[client]) == golden.statuses(theirs[client]), client
    reader_theirs, reader_ours = golden.delivered(theirs[0]), golden.delivered(ours[0])
    assert reader_ours == reader_theirs
    indices = [int.from_bytes(sample[:4], "little") for _, sample in reader_theirs]
    assert all(len(sample) == 8 + size for _, sample in reader_theirs)
    assert indices == sorted(set(indices)) and set(indices) <= set(range(1, count + 1))
    if stream == "reliable":  # eProsima's agent got every sample through: so must ours
        assert indices == list(range(1, count + 1)) and header["stdout"][-1] == "exit 0"
    assert golden.delivered(ours[1]) == []  # the writer reads nothing


# (test_eprosima_dds_golden.py replays the dds_exchange_ recordings against a real -m dds agent.)
FRAMED = [n for n in golden.names() if n.endswith(("_tcp4", "_tcp6", "_serial"))]


@pytest.mark.parametrize("name", FRAMED)
def test_framing_is_eprosimas(name):
    from xrce.transports.framing import encode_frame, encode_length_prefixed

    _, rows = golden.load(name)
    framed = golden.unframe(rows)
    assert len(framed) == len(rows) > 0
    for row, messages in framed:
        message = bytes.fromhex(row["hex"])
        assert messages == [message]
        frame = bytes.fromhex(row["frame"])
        ours = (encode_frame(message, frame[1], frame[2]) if name.endswith("_serial")
                else encode_length_prefixed(message))
        assert ours == frame
