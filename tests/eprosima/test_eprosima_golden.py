"""eProsima's client against eProsima's agent, recorded (tests/golden/eprosima/, record_eprosima.py), replayed
against ours, every answer compared; no eProsima library needed.

- CED by XML and by reference, REUSE and REPLACE (``-m ced``, UDP4 and UDP6): every STATUS our
  agent sends equals eProsima's, request by request;
- nine and more reliable creations back to back, and a batch of them: the same STATUS, each
  answered message acknowledged by the time its answer is out (the whole capture fed within one
  read batch of the agent), and no more ACKNACKs or HEARTBEATs than eProsima's agent sent;
- discovery from a UDP4 and a UDP6 agent: our INFO has eProsima's bytes, given the addresses the
  recording host had (127.0.0.1, ::1).
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

    assert set(golden.names()) == set(scenarios.CREATIONS) | set(scenarios.DISCOVERY)


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
