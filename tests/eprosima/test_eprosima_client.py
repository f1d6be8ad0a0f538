"""eProsima's C client library (programs/, built here against XRCE_EPROSIMA_CLIENT) against our
agent, live: CED entities by XML and by reference and their REUSE/REPLACE answered as eProsima's
agent answered the same programs (tests/golden/eprosima/), over UDP4, UDP6, TCP4 and TCP6;
fifteen reliable creations back to back with a history of 8 never finding it full; discovery
from a udp4 and a udp6 agent giving a locator of that family; two clients (programs/exchange.c)
exchanging 1, 10 and fragmented samples on best-effort and reliable streams with 5 and 10 % of
their messages dropped by their own transport, over UDP4, UDP6, TCP4, TCP6 and serial (two
pseudo-terminal pairs, ``multiserial``) in ``-m ced``, and with entities by XML, in binary and by
reference (a profiles file given to the agent with -r) in ``-m dds`` over the same five (a type
name that is no ROS one, on the agent's Fast DDS). Skipped, loudly, where the library
or a compiler is missing (tests/helpers/eprosima_client.py); test_eprosima_golden.py replays the
same exchanges without it."""

import os
import socket
import subprocess
import tty
from contextlib import contextmanager

import pytest

import eprosima_client
import eprosima_golden as golden
import eprosima_scenarios as scenarios
from agent_process import AgentProcess
from ros_helpers import ros_domain  # noqa: F401
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
    return {name: eprosima_client.build(name + ".c", out)
            for name in ("script", "discover", "exchange")}


def _run_script(program, transport, where, fds, lines):
    argv = where + ["0"] if transport == "serial" else where  # serial: the descriptor, no port
    result = subprocess.run([str(program), transport, *argv], pass_fds=fds,
                            input="\n".join(lines) + "\n", capture_output=True, text=True,
                            timeout=120)
    return result.stdout.splitlines() + ["exit %d" % result.returncode]


@pytest.mark.parametrize("name, transport", [
    ("ced_xml_ref_udp4", "udp4"), ("ced_xml_ref_udp6", "udp6"), ("ced_xml_ref_tcp4", "tcp4"),
    ("ced_xml_ref_tcp6", "tcp6"), ("ced_xml_ref_serial", "serial"),
    ("ced_reuse_replace_udp4", "udp4"), ("ced_reuse_replace_tcp4", "tcp4"),
    ("ced_reuse_replace_serial", "serial"),
])
def test_ced_entities_answered_as_eprosimas_agent(programs, name, transport):
    header, _ = golden.load(name)
    assert header["script"] == scenarios.CREATIONS[name][1]  # recorded from today's script
    assert header["transport"] == transport
    with _agent_for(transport, 1, "-m", "ced") as (where, fds):
        printed = _run_script(programs["script"], transport, where, fds, header["script"])
    assert printed == header["stdout"]


@pytest.mark.parametrize("transport", ["udp4", "udp6", "tcp4", "tcp6", "serial"])
def test_reliable_creations_back_to_back_never_fill_a_history_of_8(programs, transport):
    """Each next CREATE goes the moment the last STATUS came; the ACKNACKs free the history as
    they come. Run a few times: an ACKNACK that came late stalled 1 to 4 of each group of runs."""
    with _agent_for(transport, 1, "-m", "ced") as (where, fds):
        for _ in range(4):
            printed = _run_script(programs["script"], transport, where, fds, scenarios.BACK_TO_BACK)
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


@contextmanager
def _agent_for(transport, clients, *args, env=None):
    """Our agent on ``transport`` and what a program takes after the transport's name: host and
    port, or (serial) one pseudo-terminal per client, the agent as ``multiserial`` on the other
    ends; and the descriptors to pass."""
    if transport != "serial":
        host = _host(transport)
        with AgentProcess(transport, *args, env=env) as agent:
            yield [host, str(agent.port)], ()
        return
    ends, devices = [], []
    try:
        for _ in range(clients):
            master, slave = os.openpty()
            tty.setraw(master)
            tty.setraw(slave)
            ends += [master, slave]
            devices.append(os.ttyname(slave))
        with AgentProcess("multiserial", "--devs", " ".join(devices), *args, env=env):
            yield [str(fd) for fd in ends[::2]], tuple(ends[::2])
    finally:
        for fd in ends:
            os.close(fd)


def _exchange(programs, transport, cell, *agent_args, settle_ms=0, env=None):
    with _agent_for(transport, 2, *agent_args, env=env) as (where, fds):
        result = subprocess.run([str(programs["exchange"]), transport, *where,
                                 *scenarios.exchange_argv(cell, settle_ms)], pass_fds=fds,
                                capture_output=True, text=True, timeout=120, env=env)
    return result.stdout.splitlines() + ["exit %d" % result.returncode]


def _check_exchange(printed, cell):
    stream, count, size, _, _ = cell
    got = [line.split() for line in printed if line.startswith("GOT")]
    indices = [int(row[1]) for row in got]
    assert all(row[2:] == [str(size), "ok"] for row in got), printed
    assert indices == sorted(set(indices)) and set(indices) <= set(range(1, count + 1)), printed
    assert "WROTE %d" % count in printed and printed[-1] == "exit 0", printed
    if stream == "reliable":
        assert indices == list(range(1, count + 1)), printed
    else:  # a share of the best-effort samples may be lost, not most
        assert len(indices) >= count // 2, printed


@pytest.mark.parametrize("transport", scenarios.EXCHANGE_TRANSPORTS)
@pytest.mark.parametrize("cell", list(scenarios.EXCHANGE_CELLS))
def test_two_clients_exchange_through_ced(programs, transport, cell):
    """As through eProsima's agent (the recording of the same cell): the same STATUS codes, every
    reliable sample once, in order, intact, whatever the transport dropped."""
    header, _ = golden.load("exchange_%s_%s" % (cell, transport))
    args = scenarios.EXCHANGE_CELLS[cell]
    printed = _exchange(programs, transport, args, "-m", "ced")
    assert [l for l in printed if l.startswith("STATUS")] == \
        [l for l in header["stdout"] if l.startswith("STATUS")]
    _check_exchange(printed, args)


DDS_CELLS = {
    "reliable_10_xml": ("reliable", 10, 64, 0, "xml"),
    "reliable_frag_drop5_bin": ("reliable", 4, scenarios.FRAGMENTED, 5, "bin"),
    "reliable_10_drop10_xml": ("reliable", 10, 64, 10, "xml"),
    "best_effort_10_drop5_bin": ("best-effort", 10, 64, 5, "bin"),
    "best_effort_10_xml": ("best-effort", 10, 64, 0, "xml"),
    "reliable_10_drop5_ref": ("reliable", 10, 64, 5, "ref"),
    "best_effort_10_ref": ("best-effort", 10, 64, 0, "ref"),
}


@pytest.fixture(scope="module")
def bridge_cache(tmp_path_factory):
    """XDG_CACHE_HOME for -m dds agents: the plain DDS bridge built once, in this run's own
    temporary directory."""
    return {"XDG_CACHE_HOME": str(tmp_path_factory.mktemp("xdg-cache"))}


@pytest.mark.parametrize("transport", scenarios.EXCHANGE_TRANSPORTS)
@pytest.mark.parametrize("cell", list(DDS_CELLS))
def test_two_clients_exchange_through_dds(programs, ros_domain, bridge_cache, transport, cell,
                                          tmp_path):
    """In ``-m dds`` the type name "Exchange" is no ROS one: both endpoints are plain DDS ones on
    the agent's Fast DDS participant, matched there; every creation succeeds (binary, XML, and by
    reference to the profiles file the agent was started with)."""
    env = dict(os.environ, **bridge_cache)
    args = ["-m", "dds"]
    if DDS_CELLS[cell][4] == "ref":
        profiles = tmp_path / "profiles.xml"
        profiles.write_text(scenarios.exchange_profiles(DDS_CELLS[cell][0]))
        args += ["-r", str(profiles)]
    printed = _exchange(programs, transport, DDS_CELLS[cell], *args, settle_ms=1500, env=env)
    assert [l for l in printed if l.startswith("STATUS")] == \
        ["STATUS reader 0 0 0 0", "STATUS writer 0 0 0 0"], printed
    _check_exchange(printed, DDS_CELLS[cell])


@pytest.mark.parametrize("transport", ["udp4", "tcp4"])
@pytest.mark.parametrize("seed", [5, 7])
def test_two_clients_exchange_at_20_percent_loss(programs, transport, seed):
    """Past the matrix's 10 %: the seeds whose runs stalled our agent (a lost batch ACKNACK, a
    by-reference reader's depth of 1) and not eProsima's; tests/eprosima/test_eprosima_regressions.py
    holds the same without the library."""
    for cell in (("reliable", 10, scenarios.FRAGMENTED, 20, "bin"), ("reliable", 10, 1200, 10, "ref")):
        with _agent_for(transport, 2, "-m", "ced") as (where, fds):
            argv = scenarios.exchange_argv(cell)
            argv[4] = str(seed)
            result = subprocess.run([str(programs["exchange"]), transport, *where, *argv],
                                    pass_fds=fds, capture_output=True, text=True, timeout=120)
        _check_exchange(result.stdout.splitlines() + ["exit %d" % result.returncode], cell)
