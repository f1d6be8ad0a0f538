"""``-m dds`` exchanges recorded between eProsima's client and eProsima's agent (record_eprosima.py,
tests/golden/eprosima/dds_exchange_*), replayed against a real ``xrce-agent -m dds`` process over
UDP4: two clients, a reader and a writer of a type name that is no ROS one ("Exchange"), their
entities in binary, by XML and by reference (the recording's profiles file given to our agent
with -r, as it was to eProsima's); each client's messages sent at their recorded times from a
socket of its own, the participants moved to the test's own DDS domain. Every STATUS each client
got and every sample the reader was given must be eProsima's. No eProsima library needed; the
agent's Fast DDS bridge is built on first use (into this run's own cache). Run under unshare -n.
"""

import os

import pytest

import eprosima_golden as golden
import eprosima_scenarios as scenarios
from agent_process import AgentProcess
from ros_helpers import DomainLease, ros_domain  # noqa: F401
from xrce.client.session import Session
from xrce.transports.udp import UdpTransport
from xrce.wire import constants as C


@pytest.fixture(scope="module")
def bridge_cache(tmp_path_factory):
    """XDG_CACHE_HOME with the plain DDS bridge already built in it (this run's own temporary
    directory): an agent builds it on the first plain DDS topic and answers that CREATE seconds
    later, and a replay does not wait for answers, it keeps the recorded times. A board of
    xrce.client makes one such topic first and waits."""
    cache = {"XDG_CACHE_HOME": str(tmp_path_factory.mktemp("xdg-cache"))}
    lease = DomainLease()
    try:
        env = dict(os.environ, ROS_DOMAIN_ID=str(lease.domain_id), **cache)
        with AgentProcess("udp4", "-m", "dds", env=env) as agent:
            session = Session(UdpTransport("127.0.0.1", agent.port), history=8)
            try:
                assert session.create(attempts=5, timeout_ms=1000)
                node = session.create_participant(domain_id=lease.domain_id, name="warmup")
                session.create_topic(node, "WarmupTopic", "Exchange")
                assert session.run_until_all_status(60000), session.last_statuses
                assert all(s == C.STATUS_OK for s in session.last_statuses.values()), \
                    (session.last_statuses, "".join(agent.output))
                session.delete(attempts=2, timeout_ms=500)
            finally:
                session.close()
    finally:
        lease.release()
    return cache


@pytest.mark.parametrize("name", list(scenarios.DDS_EXCHANGES))
def test_dds_exchange_answered_as_eprosimas_agent(name, ros_domain, bridge_cache,  # noqa: F811
                                                  tmp_path):
    transport, cell = scenarios.DDS_EXCHANGES[name]
    header, rows = golden.load(name)
    assert header["argv"] == scenarios.exchange_argv(cell, scenarios.DDS_SETTLE_MS)
    assert header["middleware"] == "dds" and header["transport"] == transport == "udp4"
    args = ["udp4", "-m", "dds"]
    if cell[4] == "ref":
        assert header["profiles"] == scenarios.exchange_profiles(cell[0])
        profiles = tmp_path / "profiles.xml"
        profiles.write_text(header["profiles"])
        args += ["-r", str(profiles)]
    with AgentProcess(*args, env=dict(os.environ, **bridge_cache)) as agent:
        ours = golden.replay_over_udp(rows, "127.0.0.1", agent.port, ros_domain)
        assert agent.stop() == 0
    log = "".join(agent.output)
    theirs = golden.by_client(rows, "A->C")
    assert sorted(theirs) == sorted(ours) == [0, 1]  # the reader spoke first
    for client in (0, 1):
        # Each client's session, its four creations and (the reader) its READ_DATA; the DELETE.
        assert golden.statuses(ours[client]) == golden.statuses(theirs[client]), (client, log)
    reader_theirs, reader_ours = golden.delivered(theirs[0]), golden.delivered(ours[0])
    stream, count, size, _, _ = cell
    indices = [int.from_bytes(sample[:4], "little") for _, sample in reader_theirs]
    assert indices == list(range(1, count + 1)) and header["stdout"][-1] == "exit 0"
    assert all(len(sample) == 8 + size for _, sample in reader_theirs)
    assert reader_ours == reader_theirs, log
    assert golden.delivered(ours[1]) == []  # the writer reads nothing
    assert "Traceback" not in log, log
