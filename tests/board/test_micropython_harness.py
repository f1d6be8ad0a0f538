"""The MicroPython harness itself: real MicroPython 1.27 in Node, the mounted xrce package and the
synchronous UDP bridge (tests/micropython/run.mjs)."""

import socket
import subprocess
import sys
import threading
import time

import pytest

from ros_helpers import ros_domain  # noqa: F401
from mp_harness import RUNNER, ensure_installed, node_executable, run_micropython


def _check(result):
    assert result.returncode == 0, "exit %d\nstdout:\n%s\nstderr:\n%s" % (result.returncode, result.stdout, result.stderr)
    return result.stdout


def test_runs_real_micropython_1_27():
    out = _check(
        run_micropython(
            "import sys\n"
            "print(sys.implementation.name)\n"
            "print('%d.%d' % sys.implementation.version[:2])\n"
            "print(sys.argv[1:])\n",
            "first",
            "second arg",
        )
    )
    assert out.splitlines() == ["micropython", "1.27", "['first', 'second arg']"]


def test_mounted_wire_core_imports_and_round_trips():
    script = r"""
import sys
from xrce.wire.cdr import CdrReader, CdrWriter
from xrce import IS_MICROPYTHON, ticks_add, ticks_diff, ticks_ms
from xrce import DecodeError, XrceError
import xrce.wire.cdr

assert IS_MICROPYTHON
assert xrce.wire.cdr.__file__.startswith("/lib/xrce/"), xrce.wire.cdr.__file__
assert issubclass(DecodeError, XrceError)
now = ticks_ms()
assert ticks_diff(ticks_add(now, 25), now) == 25

w = CdrWriter()
w.u8(7)
w.u32(0xDEADBEEF)
w.f64(-1.25)
w.string("héllo")
w.i64(-(2 ** 40))
data = w.getvalue()
r = CdrReader(data)
values = (r.u8(), r.u32(), r.f64(), r.string(), r.i64())
print(repr(values[:3] + values[4:]))
print(values[3])
print(len(data))
try:
    CdrReader(b"\x05\x00").u32()
except DecodeError:
    print("truncated input raises DecodeError")
"""
    out = _check(run_micropython(script)).splitlines()
    assert out[0] == repr((7, 0xDEADBEEF, -1.25, -(2**40)))
    assert out[1] == "héllo"
    # u8, pad to 4, u32, f64, u32 length + "héllo\0" (7 bytes), pad to 8, i64
    assert out[2] == str(1 + 3 + 4 + 8 + 4 + 7 + 5 + 8)
    assert out[3] == "truncated input raises DecodeError"


@pytest.fixture
def udp_echo_server():
    """A CPython UDP echo server on 127.0.0.1 with an ephemeral port; yields (port, received list)."""
    server = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    server.bind(("127.0.0.1", 0))
    server.settimeout(0.1)
    received = []
    stop = threading.Event()

    def serve():
        while not stop.is_set():
            try:
                data, peer = server.recvfrom(65535)
            except socket.timeout:
                continue
            except OSError:
                return
            received.append(data)
            server.sendto(data, peer)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield server.getsockname()[1], received
    finally:
        stop.set()
        thread.join(timeout=5)
        server.close()


NODEUDP_SCRIPT = r"""
import sys, time
import nodeudp

port = int(sys.argv[1])
handle = nodeudp.open("127.0.0.1", port)
payloads = [
    b"\x00",
    bytes(range(256)),
    bytearray(b"\xff\x00" * 700),
    memoryview(b"..slice..")[2:7],
    b"",
]
for payload in payloads:
    sent = nodeudp.send(handle, payload)
    echoed = nodeudp.recv(handle, 2000)
    assert sent == len(payload), (sent, len(payload))
    assert type(echoed) is bytes, type(echoed)
    assert echoed == bytes(payload), (echoed, payload)
    print("echo", len(payload))

start = time.ticks_ms()
nothing = nodeudp.recv(handle, 150)
waited = time.ticks_diff(time.ticks_ms(), start)
print("timeout", nothing, waited)
assert nodeudp.dropped(handle) == 0
assert nodeudp.close(handle) == 1
assert nodeudp.send(handle, b"late") == -1
assert "no open socket" in nodeudp.last_error(), nodeudp.last_error()
assert nodeudp.send(nodeudp.open("127.0.0.1", port), "not bytes") == -1
assert "expected bytes" in nodeudp.last_error(), nodeudp.last_error()
print("errors ok")

# Nobody listens on this port: the ICMP port-unreachable must neither kill the socket nor the run.
silent = nodeudp.open("127.0.0.1", int(sys.argv[2]))
assert nodeudp.send(silent, b"anyone?") == 7
assert nodeudp.recv(silent, 100) is None
assert nodeudp.send(silent, b"still here") == 10
assert nodeudp.close(silent) == 1
print("unreachable ok")
"""


def test_nodeudp_bridge_echoes_byte_exact_and_times_out(udp_echo_server):
    port, received = udp_echo_server
    started = time.monotonic()
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    closed_port = probe.getsockname()[1]
    probe.close()
    out = _check(run_micropython(NODEUDP_SCRIPT, port, closed_port, timeout=30)).splitlines()
    assert out[:5] == ["echo 1", "echo 256", "echo 1400", "echo 5", "echo 0"]
    word, value, waited = out[5].split()
    assert (word, value) == ("timeout", "None")
    assert 140 <= int(waited) < 1000
    assert out[6:] == ["errors ok", "unreachable ok"]
    assert received == [b"\x00", bytes(range(256)), b"\xff\x00" * 700, b"slice", b""]
    assert time.monotonic() - started < 30


def test_nodeudp_transport_callbacks(udp_echo_server):
    port, received = udp_echo_server
    script = r"""
import sys
from nodeudp_transport import make_callbacks

port = int(sys.argv[1])
open_cb, close_cb, write_cb, read_cb = make_callbacks("127.0.0.1", port)
buf = bytearray(512)
assert read_cb(None, buf, 512, 10) == 0  # not open yet
assert write_cb(None, b"x") == 0
assert open_cb(None) is True
assert write_cb(None, b"\x81\x00\x00\x00hello") == 9
n = read_cb(None, buf, 512, 2000)
assert bytes(buf[:n]) == b"\x81\x00\x00\x00hello", buf[:n]
# packet mode: a datagram longer than size is truncated like recvfrom on a short buffer
assert write_cb(None, bytes(range(20))) == 20
assert read_cb(None, buf, 8, 2000) == 8 and bytes(buf[:8]) == bytes(range(8))
assert read_cb(None, buf, 512, 100) == 0  # the tail was dropped, nothing else queued
assert close_cb(None) is True

open_cb, close_cb, write_cb, read_cb = make_callbacks("127.0.0.1", port, stream=True)
assert open_cb(None)
assert write_cb(None, bytearray(range(10))) == 10
got = bytearray()
while len(got) < 10:
    n = read_cb(None, buf, 4, 2000)
    assert 0 < n <= 4
    got.extend(buf[:n])
assert got == bytearray(range(10)), got
assert read_cb(None, buf, 4, 100) == 0
assert close_cb(None)

refused_open, _, _, _ = make_callbacks("127.0.0.1", 0)  # port 0 cannot be connected to
assert refused_open(None) is False

# The bridge moves bytes in place: a send and a receive allocate nothing on the heap (a capped
# run counts every byte of garbage against the firmware; a board's socket makes none).
import gc
open_cb, close_cb, write_cb, read_cb = make_callbacks("127.0.0.1", port)
assert open_cb(None)
message = bytearray(bytes(range(256)) * 2)
window = memoryview(message)[100:400]
assert write_cb(None, message) == 512 and read_cb(None, buf, 512, 2000) == 512



def exchange(times):  # a function: module-level names would grow the globals dict meanwhile
    gc.collect()
    before = gc.mem_alloc()
    for _ in range(times):
        assert write_cb(None, window) == 300
        assert read_cb(None, buf, 512, 2000) == 300
    return gc.mem_alloc() - before


allocated = exchange(20)
assert buf[:300] == message[100:400]
assert allocated == 0, allocated
assert close_cb(None)
print("callbacks ok")
"""
    out = _check(run_micropython(script, port, timeout=30))
    assert out.strip() == "callbacks ok"
    assert received == [b"\x81\x00\x00\x00hello", bytes(range(20)), bytes(range(10))] + \
        [bytes(range(256)) * 2] + [bytes(range(100, 256)) + bytes(range(144))] * 20


def test_script_exception_gives_exit_1_and_traceback():
    result = run_micropython("def fail():\n    raise ValueError('deliberate failure 42')\n\nprint('before')\nfail()\n")
    assert result.returncode == 1
    assert result.stdout == "before\n"
    assert "Traceback (most recent call last):" in result.stderr
    assert "line 5" in result.stderr and "line 2, in fail" in result.stderr
    assert "ValueError: deliberate failure 42" in result.stderr


def test_sys_exit_status_is_the_exit_code():
    assert run_micropython("import sys\nsys.exit(3)\n").returncode == 3
    assert run_micropython("import sys\nsys.exit()\n").returncode == 0


def test_callbacks_drive_the_custom_transport(udp_echo_server):
    """The adapter plugged into xrce.transports.custom.CustomTransport, packet and framed modes."""
    port, received = udp_echo_server
    script = r"""
import sys
from nodeudp_transport import make_callbacks
from xrce.transports.custom import CustomTransport

port = int(sys.argv[1])
messages = [b"\x81\x00\x00\x00" + bytes(range(40)), b"\x7e\x7d" * 50, bytes(300)]

packets = CustomTransport(*make_callbacks("127.0.0.1", port), framing=False, mtu=512)
for message in messages:
    assert packets.send(message)
    assert packets.recv(2000) == message
assert packets.recv(50) is None
packets.close()

framed = CustomTransport(*make_callbacks("127.0.0.1", port, stream=True), framing=True, mtu=512)
for message in messages:
    assert framed.send(message)
    assert framed.recv(2000) == message
framed.close()
print("sent", packets.sent + framed.sent, "received", packets.received + framed.received)
"""
    out = _check(run_micropython(script, port, timeout=30))
    assert out.strip() == "sent 6 received 6"
    messages = [b"\x81\x00\x00\x00" + bytes(range(40)), b"\x7e\x7d" * 50, bytes(300)]
    assert received[:3] == messages
    # Framed, the bytes are the §11 frames (written a piece of at most 64 bytes per write_cb call,
    # each its own datagram here), never the raw messages.
    from xrce.transports.framing import encode_frame

    assert b"".join(received[3:]) == b"".join(encode_frame(m, 0, 0) for m in messages)
    assert max(len(piece) for piece in received[3:]) <= 64


PUBLISHER_SCRIPT = r"""
import sys
import nodeudp
from nodeudp_transport import make_callbacks
from xrce.client.session import Session, ping_agent
from xrce.msgs.std_msgs import String
from xrce.transports.custom import CustomTransport

port, domain, control_port, limit = [int(arg) for arg in sys.argv[1:5]]
transport = CustomTransport(*make_callbacks("127.0.0.1", port), framing=False, mtu=512)
assert ping_agent(transport, 1000, 5) is not None, "agent did not answer the ping"
session = Session(transport, key=0x4D505931)
assert session.create(attempts=5, timeout_ms=500), "no session"
participant = session.create_participant(domain)
writer = session.create_writer(participant, "/mp_harness_chatter", String)
assert session.run_until_all_status(3000), "entities not confirmed"
# DDS discovery between the agent and the test's subscriber takes a variable time, so publish
# until the test says it has seen enough (or the limit is reached).
control = nodeudp.open("127.0.0.1", control_port)
nodeudp.send(control, b"publishing")
sent = 0
while sent < limit and nodeudp.recv(control, 0) != b"stop":
    session.write(writer, String("micropython says %d" % sent))
    sent += 1
    session.run_until_timeout(50)
assert session.delete(attempts=3, timeout_ms=500)
transport.close()
nodeudp.close(control)
print("published", sent)
"""


def test_micropython_client_publishes_to_ros_through_the_agent(tmp_path, ros_domain):  # noqa: F811
    """End to end: the client under MicroPython, the nodeudp bridge, the Python agent, rclpy."""
    domain = ros_domain  # leased, with LOCALHOST discovery set by the fixture
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import String

    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    ensure_installed()
    script = tmp_path / "publisher.py"
    script.write_text(PUBLISHER_SCRIPT)
    wanted, limit = 15, 400
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    with open(tmp_path / "agent.log", "w") as agent_log:
        agent = subprocess.Popen([sys.executable, "-m", "xrce.agent", "udp4", "-p", str(port)],
                                 stdout=subprocess.PIPE, stderr=agent_log, text=True)
        publisher = None
        control = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            control.bind(("127.0.0.1", 0))
            control.setblocking(False)
            banner = agent.stdout.readline()
            assert "udp4" in banner, banner
            node = rclpy.create_node("mp_harness_listener", context=context)
            received = []
            node.create_subscription(String, "/mp_harness_chatter", lambda msg: received.append(msg.data), 50)
            executor = SingleThreadedExecutor(context=context)
            executor.add_node(node)
            publisher = subprocess.Popen(
                [node_executable(), str(RUNNER), str(script), str(port), str(domain),
                 str(control.getsockname()[1]), str(limit)],
                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            )
            script_address = None
            deadline = time.monotonic() + 45
            while publisher.poll() is None and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.02)
                try:
                    _, script_address = control.recvfrom(64)
                except BlockingIOError:
                    pass
                if script_address is not None and len(received) >= wanted:
                    control.sendto(b"stop", script_address)
            out, err = publisher.communicate(timeout=10)
            settle = time.monotonic() + 0.5
            while time.monotonic() < settle:
                executor.spin_once(timeout_sec=0.02)
            assert publisher.returncode == 0, out + err
            sent = int(out.split()[-1])
            assert out.strip() == "published %d" % sent and sent < limit, out
            # Samples written before DDS matched the subscription are legitimately lost (volatile).
            assert len(received) >= wanted, (received, (tmp_path / "agent.log").read_text())
            numbers = [int(text.rsplit(" ", 1)[1]) for text in received]
            assert received == ["micropython says %d" % n for n in numbers]
            assert numbers == sorted(set(numbers)) and numbers[-1] < sent, numbers
            executor.shutdown()
            node.destroy_node()
        finally:
            if publisher is not None and publisher.poll() is None:
                publisher.kill()
                publisher.communicate()
            agent.terminate()
            try:
                agent.wait(timeout=10)
            except subprocess.TimeoutExpired:
                agent.kill()
                agent.wait()
            agent.stdout.close()
            control.close()
            rclpy.shutdown(context=context)
