"""Hostile input against the agent.

Live: a real agent process gets random and mutated datagrams (golden captures, bit flips, splices,
extreme length fields) from several sockets, or byte soup and mutated frames on a second serial
line, while a good writer/reader pair keeps publishing reliable and best-effort through it: the
agent must not crash or stall, the good clients must keep >= 99 % delivery (reliable: all, in
order), and its decode/drop counters (SIGUSR1 stats line) must have moved. Same code as
``bench/hostile/fuzz_live_agent.py`` at a suite-sized count.

In process (hypothesis): serial byte streams through the agent's frame decoder into the engine, and
session-bound mutations of a good client's own messages (the paths unknown-client fuzzing never
reaches), must leave the engine raising nothing and its handler_errors at zero.
"""

import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ros_helpers import ros_domain  # noqa: F401
from xrce.agent.middleware.ced import CedMiddleware
from xrce.agent.engine.agent import Agent
from xrce.wire.submessages import CreateClient, encode_message
from xrce.transports.framing import FrameDecoder

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from bench.hostile import fuzz_live_agent  # noqa: E402


def _check(result, min_decode_errors, rss_growth_mib=20):
    print(result)
    assert result["crashes"] == 0 and result["exit_code"] == 0, result
    assert result["handler_errors"] == 0, result
    assert result["reliable_in_order"], result
    assert result["received"]["reliable"] == result["sent"]["reliable"], result
    assert result["delivery_percent"] >= 99.0, result
    assert result["decode_errors"] + result["dropped"] + result["link_drops"] >= min_decode_errors
    assert result["rss_after_kib"] - result["rss_before_kib"] < rss_growth_mib * 1024, result


def test_live_ced_agent_over_udp_survives_fuzzed_datagrams():
    result = fuzz_live_agent.run(count=30000, middleware="ced", sockets=8, seed=3)
    assert result["datagrams"] == 30000
    _check(result, 10000)
    assert result["decode_errors"] > 1000  # malformed input was seen and counted as such


def test_live_ced_agent_over_serial_survives_fuzzed_frames():
    result = fuzz_live_agent.run(count=15000, middleware="ced", seed=4, serial=True)
    assert result["datagrams"] == 15000
    _check(result, 5000)
    assert result["link_drops"] > 1000  # CRC / resync / oversize drops on the fuzzed line


def test_live_dds_agent_over_udp_survives_fuzzed_datagrams(ros_domain):  # noqa: F811
    budget_mib = 16
    result = fuzz_live_agent.run(count=8000, middleware="dds", sockets=4, seed=5,
                                 domain_id=ros_domain, publish_every=50,
                                 agent_args=("--max-memory", str(budget_mib << 20)))
    # What the clients' buffers may hold, plus the ROS nodes that mutated CREATEs which happen
    # to be valid make (measured: a few MB; this allowance was 150 MB before the budget).
    _check(result, 2000, rss_growth_mib=budget_mib + 24)


# ------------------------------------------------------------------------------- in process

class _Link:
    name = "fuzz"
    sends_from_any_thread = False
    fastpath = None
    info_locators = ()

    def __init__(self):
        self.sent = 0

    def send(self, endpoint, data):
        self.sent += 1
        return True


def _agent_with_a_session():
    agent = Agent(CedMiddleware(), max_clients=8)
    link = _Link()
    request = encode_message(0x80, 0, 0, None, [CreateClient(b"\x01\x02\x03\x04", 0x81, 508)])
    agent.receive(link, ("fuzzer", 1), request)
    assert b"\x01\x02\x03\x04" in agent.clients
    return agent, link


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.binary(max_size=300), max_size=8))
def test_serial_byte_soup_through_frames_into_the_engine(chunks):
    agent, link = _agent_with_a_session()
    decoder = FrameDecoder(local_addr=0)
    for chunk in chunks:
        for src, _dst, payload in decoder.feed(b"\x7e" + chunk):
            agent.receive(link, ("fuzzer", src), payload)
        agent.tick()
    assert agent.stats.handler_errors == 0


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_mutations_inside_an_established_session(data):
    agent, link = _agent_with_a_session()
    corpus, _ = fuzz_live_agent.golden_corpus()
    # Session 0x81 messages of the captures, sent from the established endpoint, then mutated:
    # these reach stream, fragment and object handling, not only the unknown-client path.
    in_session = [m for m in corpus if m and m[0] == 0x81]
    for _ in range(data.draw(st.integers(1, 6))):
        message = bytearray(data.draw(st.sampled_from(in_session)))
        for _ in range(data.draw(st.integers(0, 3))):
            index = data.draw(st.integers(0, len(message) - 1))
            message[index] = data.draw(st.integers(0, 255))
        if data.draw(st.booleans()):
            del message[data.draw(st.integers(4, len(message))):]
        agent.receive(link, ("fuzzer", 1), bytes(message))
        agent.tick()
    assert agent.stats.handler_errors == 0
    assert len(agent.clients) <= 8


# ------------------------------------------------------------------------------------ quotas

def test_object_quota_answers_err_resources_and_logs():
    from agent_process import AgentProcess
    from xrce.client.session import Session
    from xrce.transports.udp import UdpTransport

    with AgentProcess("udp4", "-m", "ced", "--max-objects", "3", "--max-clients", "1") as agent:
        session = Session(UdpTransport("127.0.0.1", agent.port), auto_recover=False)
        other = Session(UdpTransport("127.0.0.1", agent.port), auto_recover=False)
        try:
            assert session.create(attempts=3, timeout_ms=1000)
            node = session.create_participant(name="greedy")
            topic = session.create_topic(node, "rt/q", "std_msgs::msg::dds_::String_")
            publisher = session.create_publisher(node)
            assert session.run_until_all_status(3000)
            session.create_datawriter(publisher, topic)
            assert not session.run_until_all_status(3000)
            assert list(session.last_statuses.values()) == [0x87]  # ERR_RESOURCES
            # A second client while the only slot is held by a live one: refused, not evicted.
            assert not other.create(attempts=1, timeout_ms=1000)
            assert other.create_status == 0x87
        finally:
            session.close()
            other.close()
        assert agent.stop() == 0
    log = "".join(agent.output)
    assert "quota reached" in log and "refusing client" in log
