"""The client's own source files, unmodified, under real MicroPython 1.27 (WebAssembly in Node) talking
to a real ``xrce-agent`` over a custom transport bridged to Node's UDP socket: session, ping, time
sync, entities, publish and receive."""

import socket
import threading
import time
from pathlib import Path

from agent_process import AgentProcess
from mp_harness import run_micropython
from xrce.client.session import Session
from xrce.msgs.geometry_msgs import Twist, Vector3
from xrce.msgs.std_msgs import String
from xrce.transports.udp import UdpTransport

SCRIPT = Path(__file__).resolve().parents[1] / "micropython" / "e2e_client.py"


class CPythonPeer(threading.Thread):
    """Reads what the MicroPython client publishes and publishes Twist for it to read."""

    def __init__(self, port):
        super().__init__(daemon=True)
        self.session = Session(UdpTransport("127.0.0.1", port), history=8)
        assert self.session.create(attempts=5, timeout_ms=500)
        node = self.session.create_participant(name="cpython_peer")
        self.received = []
        self.session.create_reader(node, "/mp_chatter", String, self.received.append)
        self.writer = self.session.create_writer(node, "/mp_cmd", Twist, reliable=False)
        assert self.session.run_until_all_status(2000)
        self.stop = threading.Event()

    def run(self):
        while not self.stop.is_set():
            self.session.write(self.writer, Twist(linear=Vector3(x=0.25)), stream_id=self.session.best_effort)
            deadline = time.monotonic() + 0.05
            while time.monotonic() < deadline:
                self.session.spin_once(10)

    def close(self):
        self.stop.set()
        self.join(5)
        self.session.delete(attempts=1, timeout_ms=200)
        self.session.close()


def test_micropython_client_against_the_real_agent():
    with AgentProcess("udp4", "-m", "ced") as agent:
        peer = CPythonPeer(agent.port)
        peer.start()
        try:
            result = run_micropython(SCRIPT, agent.port, timeout=120)
        finally:
            peer.close()
    lines = dict(line.split(" ", 1) for line in result.stdout.splitlines() if " " in line)
    assert result.returncode == 0, result.stdout + result.stderr
    for step in ("ping_agent", "create", "ping_session", "sync_time", "entities", "delivered", "delete_entity", "delete"):
        assert lines.get(step) == "True", (step, result.stdout)
    count, x = lines["received"].split()
    assert int(count) >= 3 and float(x) == 0.25
    assert abs(int(lines["epoch_ms"]) - time.time() * 1000) < 60000
    assert [m.data for m in peer.received] == ["from micropython %d" % i for i in range(10)]


DISCOVERY_SCRIPT = """
import sys
from nodeudp_transport import make_callbacks
from xrce.client.discovery import discover_agents
from xrce.transports.custom import CustomTransport

transport = CustomTransport(*make_callbacks("127.0.0.1", int(sys.argv[1])), framing=False)
for address, port in discover_agents(transport, attempts=3, period_ms=500):
    print("agent", ".".join(str(b) for b in address), port)
print("done", True)
"""


def _free_udp_port():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_micropython_discovers_the_real_agent():
    # discover_agents (its own GET_INFO and INFO reader, not the general codec) under MicroPython,
    # unicast to a real agent's discovery port: it answers with one locator per local IPv4 address,
    # each with its service port.
    discovery_port = _free_udp_port()
    with AgentProcess("udp4", "-m", "ced", "-d", str(discovery_port)) as agent:
        result = run_micropython(DISCOVERY_SCRIPT, discovery_port, timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "done True" in result.stdout
    assert "agent 127.0.0.1 %d" % agent.port in result.stdout.splitlines(), result.stdout


IDLE_SCRIPT = """
import gc
import sys
from nodeudp_transport import make_callbacks
from xrce import ticks_ms
from xrce.client.session import Session
from xrce.msgs.std_msgs import String
from xrce.transports.custom import CustomTransport

session = Session(CustomTransport(*make_callbacks("127.0.0.1", int(sys.argv[1])), framing=False),
                  key=b"\\x4d\\x50\\x00\\x0b", history=8)
assert session.create(attempts=5, timeout_ms=500)
node = session.create_participant(name="idle")
writer = session.create_writer(node, "/mp_idle", String)
assert session.run_until_all_status(3000)
sample = String(data="x")


def idle_passes(count):
    # What a firmware loop's pass costs when nothing arrives: gc.mem_alloc() counts every byte
    # allocated meanwhile (this harness collects only between runPython calls).
    gc.collect()
    before = gc.mem_alloc()
    for _ in range(count):
        session.spin_once(0)
    return gc.mem_alloc() - before


def unacknowledged_passes(count):
    # The same with a reliable message in flight: its heartbeat is scheduled, not yet due.
    session.write(writer, sample)
    session.flush()
    now = ticks_ms()
    gc.collect()
    before = gc.mem_alloc()
    for _ in range(count):
        session._periodic(now)
    return gc.mem_alloc() - before, len(session._next_heartbeat)


idle_passes(2)
print("idle", idle_passes(50))
unacknowledged_passes(1)
allocated, scheduled = unacknowledged_passes(50)
print("unacknowledged", allocated, scheduled)
assert session.run_until_confirm_delivery(2000)
session.delete(attempts=3, timeout_ms=500)
print("done", True)
"""


def test_micropython_idle_loop_pass_allocates_nothing():
    # A firmware spins the session on every pass of its loop; on a board any allocation there is
    # garbage the collector must come back for, hundreds of times a second.
    with AgentProcess("udp4", "-m", "ced") as agent:
        result = run_micropython(IDLE_SCRIPT, agent.port, timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
    lines = dict(line.split(" ", 1) for line in result.stdout.splitlines() if " " in line)
    assert lines["idle"] == "0", result.stdout
    assert lines["unacknowledged"] == "0 1", result.stdout
    assert lines["done"] == "True", result.stdout
