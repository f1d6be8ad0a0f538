"""eProsima's C client library (programs/, built here against XRCE_EPROSIMA_CLIENT) against our
agent, live: CED entities by XML and by reference and their REUSE/REPLACE answered as eProsima's
agent answered the same programs (tests/golden/eprosima/), over UDP4, UDP6, TCP4 and TCP6;
fifteen reliable creations back to back with a history of 8 never finding it full; discovery
from a udp4 and a udp6 agent giving a locator of that family. Skipped, loudly, where the library
or a compiler is missing (tests/helpers/eprosima_client.py); test_eprosima_golden.py replays the
same exchanges without it."""

import socket
import subprocess

import pytest

import eprosima_client
import eprosima_golden as golden
import eprosima_scenarios as scenarios
from agent_process import AgentProcess
from xrce.agent.links.udp import local_ipv6_addresses

HAS_IPV6 = socket.inet_pton(socket.AF_INET6, "::1") in local_ipv6_addresses()


def _host(transport):
    if transport.endswith("6"):
        if not HAS_IPV6:
            pytest.skip("this host has no IPv6 loopback address")
        return "::1"
    return "127.0.0.1"


@pytest.fixture(scope="module")
def programs(tmp_path_factory):
    eprosima_client.require_library()
    out = tmp_path_factory.mktemp("eprosima-programs")
    return {name: eprosima_client.build(name + ".c", out) for name in ("script", "discover")}


def _run_script(program, transport, port, lines):
    result = subprocess.run([str(program), transport, _host(transport), str(port)],
                            input="\n".join(lines) + "\n", capture_output=True, text=True,
                            timeout=120)
    return result.stdout.splitlines() + ["exit %d" % result.returncode]


@pytest.mark.parametrize("name, transport", [
    ("ced_xml_ref_udp4", "udp4"), ("ced_xml_ref_udp6", "udp6"), ("ced_xml_ref_udp4", "tcp4"),
    ("ced_xml_ref_udp6", "tcp6"), ("ced_reuse_replace_udp4", "udp4"),
    ("ced_reuse_replace_udp4", "tcp4"),
])
def test_ced_entities_answered_as_eprosimas_agent(programs, name, transport):
    header, _ = golden.load(name)
    assert header["script"] == scenarios.CREATIONS[name][1]  # recorded from today's script
    with AgentProcess(transport, "-m", "ced") as agent:
        printed = _run_script(programs["script"], transport, agent.port, header["script"])
    assert printed == header["stdout"]


@pytest.mark.parametrize("transport", ["udp4", "udp6", "tcp4"])
def test_reliable_creations_back_to_back_never_fill_a_history_of_8(programs, transport):
    """Each next CREATE goes the moment the last STATUS came; the ACKNACKs free the history as
    they come. Run a few times: an ACKNACK that came late stalled 1 to 4 of each group of runs."""
    with AgentProcess(transport, "-m", "ced") as agent:
        for _ in range(4):
            printed = _run_script(programs["script"], transport, agent.port, scenarios.BACK_TO_BACK)
            assert printed == ["STATUS %d 0" % n for n in range(1, 16)] + ["exit 0"]


@pytest.mark.parametrize("transport", ["udp4", "udp6"])
def test_discovery_gives_a_locator_of_the_agents_family(programs, transport):
    _host(transport)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        discovery_port = probe.getsockname()[1]
    with AgentProcess(transport, "-m", "ced", "-d", str(discovery_port)) as agent:
        result = subprocess.run([str(programs["discover"]), "127.0.0.1", str(discovery_port)],
                                capture_output=True, text=True, timeout=60)
    found = [line.split() for line in result.stdout.splitlines() if line.startswith("AGENT")]
    family = "ipv6" if transport.endswith("6") else "ipv4"
    loopback = "::1" if transport.endswith("6") else "127.0.0.1"
    assert ["AGENT", family, loopback, str(agent.port)] in found
    assert {row[1] for row in found} == {family}
