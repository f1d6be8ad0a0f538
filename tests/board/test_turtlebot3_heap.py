"""The TurtleBot3 firmware (xrce/examples/turtlebot3.py, unmodified, as build-mpy ships it) under
MicroPython with its heap capped for real, over the real xrce.transports.udp.UdpTransport, against a
real xrce-agent, for a minute: loaded from .mpy and from .py.

run.mjs --stepped collects garbage between the steps of the script's main() and fails the run with a
MemoryError as soon as a step needs more heap than the cap (see tests/micropython/README.md). The
steps are the stages of robot.setup_stages() and robot.step_stages() (one message taken in, the
fail-safe check, one publication, a time sync), so the cap covers what the firmware keeps plus
what one stage allocates; still stricter than a board, whose collector also runs inside a stage and
inside an import. The transport's ``socket`` is tests/micropython/socket.py, which allocates what
MicroPython's unix port does: recv(mtu + 1) a new 513-byte buffer and a new bytes per datagram
(the port frees the buffer on return; here it is garbage until the step ends: stricter again), so
what a board's socket costs is in the figures. A CPython client drives /cmd_vel (reliable) the
whole time through the same agent.

Both runs go side by side to keep the test near one minute. Heap caps: issue 10 asks for 64 KB from
.mpy and 128 KB from .py, issues 25 and 32 at most 84 KiB from .mpy over a real socket, which the
unix port meets (84 KiB: bench/micropython/unix_heap.py). The .py run meets its 128 KB and is held
to 116 KiB; from .mpy the firmware's live heap alone is ~72.3 KB plus the interpreter's and the
harness's ~8.6 KB, so the cap is what it fits in this harness, and the test keeps it from growing.
"""

import threading
import time
from pathlib import Path

import pytest

from agent_process import AgentProcess
from mp_harness import run_micropython
from xrce.client.session import Session
from xrce.msgs.geometry_msgs import Twist, Vector3
from xrce.tools import mpy
from xrce.transports.udp import UdpTransport

SCRIPT = Path(__file__).resolve().parents[1] / "micropython" / "turtlebot3_capped.py"
RUN_S = 60
SETTLE_S = 10
# The heap the runs need (mpheap.peak, absolute: the interpreter and the harness's own heap, the
# live heap, one step's garbage), over the real UdpTransport and the port-like socket. Since issue 32
# the firmware allocates its session's buffers first, in its constructor (a reliable history of 4
# message buffers that the session builds and keeps messages in, and one for /odom whole: ~4.7 KB
# kept from the start instead of copies made per message), so the live heap settles ~72.3 KB above
# the 8.6 KB baseline from .mpy (was ~67.6) while a step's garbage is smaller: peaks 84.1-86.1 KB
# from .mpy (set-up's first plan, and the loop), 90.8-96.4 KB from .py. A cap needs more than the
# peak (an allocation needs room in one piece, and this harness cannot collect inside a step):
# from .mpy 86 KiB failed; from .py 106 and 110 KiB failed; the pair 88 / 116 KiB passed 3 runs of
# 4 (the fourth failed, which of the two not recorded); 90 / 120 KiB passed 3 of 3.
# These caps are this harness's, stricter than a board's: on MicroPython's 32-bit unix port with a
# real socket (bench/micropython/unix_heap.py, whose collector runs inside a step and every 4 KB
# as the firmware asks there) the firmware runs from 84 KiB (.mpy) and 106 KiB (.py); this socket
# shim allocates 576 bytes more per datagram than the port's recv (the receive buffer the port
# frees on return, and two views: bench/micropython/unix_heap.py --socket-check).
MPY_HEAP_CAP = 90 * 1024
PY_HEAP_CAP = 120 * 1024
DRIFT_BOUND = 1024  # the live heap's low-water mark after the first 10 s may move by at most this much
EXAMPLE_FILES = ("xrce/examples/__init__.py", "xrce/examples/turtlebot3.py")
HARNESS_FILES = [SCRIPT.name, "socket.py", "mpheap.py"]
MPY_MAIN = "from %s import main\n" % SCRIPT.stem  # the script's main() from its .mpy


class CmdVelDriver(threading.Thread):
    """Publishes Twist(linear.x=0.1) on /cmd_vel, reliable, at 10 Hz until stopped."""

    def __init__(self, port):
        super().__init__(daemon=True)
        self.session = Session(UdpTransport("127.0.0.1", port), history=8)
        assert self.session.create(attempts=5, timeout_ms=500)
        node = self.session.create_participant(name="driver")
        self.writer = self.session.create_writer(node, "/cmd_vel", Twist, reliable=True)
        assert self.session.run_until_all_status(2000)
        self.halt = threading.Event()

    def run(self):
        command = Twist(linear=Vector3(x=0.1))
        while not self.halt.is_set():
            self.session.write(self.writer, command)
            deadline = time.monotonic() + 0.1
            while time.monotonic() < deadline:
                self.session.spin_once(10)

    def close(self):
        self.halt.set()
        self.join(5)
        self.session.delete(attempts=1, timeout_ms=200)
        self.session.close()


def _lines(result):
    return dict(line.split(" ", 1) for line in result.stdout.splitlines() if " " in line)


@pytest.mark.timeout(240)
def test_turtlebot3_runs_a_minute_in_a_capped_heap_from_mpy_and_from_py(tmp_path):
    # build-mpy's own file set: the install route carries the firmware.
    assert set(EXAMPLE_FILES) <= set(mpy.shipped_files())
    mpy.build_mpy(tmp_path)
    # The .mpy run loads the script and the harness's adapters from .mpy too, as a board would run
    # its own main loop and transport: compiled from source they would keep ~2.6 KB more of code
    # and names that are no part of the firmware (run.mjs leaves out the .py of a mounted .mpy).
    mpy.build_mpy(tmp_path, root=SCRIPT.parent, files=HARNESS_FILES)
    runs = {
        # key: (script, heap cap, mounts, default mount, client key)
        "mpy": (MPY_MAIN, MPY_HEAP_CAP, [(tmp_path, "/lib")], False, "54420001"),
        "py": (SCRIPT, PY_HEAP_CAP, [], True, "54420002"),
    }
    results = {}
    with AgentProcess("udp4", "-m", "ced") as agent:
        driver = CmdVelDriver(agent.port)
        driver.start()
        try:
            threads = [threading.Thread(target=lambda name=name, spec=spec: results.setdefault(name, run_micropython(
                spec[0], agent.port, RUN_S, SETTLE_S, spec[4], heap=spec[1], mounts=spec[2],
                default_mount=spec[3], stepped=True, timeout=RUN_S + 90)), daemon=True)
                for name, spec in runs.items()]
            for thread in threads:
                thread.start()
            for thread in threads:
                thread.join(RUN_S + 100)
        finally:
            driver.close()
    for name in runs:
        result = results[name]
        assert result.returncode == 0, (name, result.stdout, result.stderr)  # no MemoryError
        lines = _lines(result)
        print(name, {key: lines.get(key) for key in (
            "baseline", "imported", "after_setup", "settled_low", "settled_high", "low_first_10s", "low_last_10s",
            "peak_setup", "peak_loop", "peak", "commands_received", "published_odom", "time_syncs")})
        assert lines["connect"] == lines["setup"] == lines["done"] == "True", (name, result.stdout)
        assert lines["failed_topics"] == "-", (name, result.stdout)
        # Drift: how far the live heap's low-water mark moved from the first 10 s after settling to
        # the last 10 s. The spread of single samples (settled_high - settled_low, ~0.8-1.1 KB) also
        # counts the messages a step happened to leave in flight, which is not a leak.
        drift = abs(int(lines["low_last_10s"]) - int(lines["low_first_10s"]))
        assert drift <= DRIFT_BOUND, (name, drift, result.stdout)
        # 10 Hz topics over ~60 s; rates are checked in test_turtlebot3.py, here only that the
        # firmware kept working (two interpreters in WebAssembly share a loaded machine).
        for topic in ("sensor_state", "imu", "odom", "tf"):
            assert int(lines["published_" + topic]) >= 0.5 * 10 * RUN_S, (name, topic, result.stdout)
        assert int(lines["time_syncs"]) >= RUN_S // 4, (name, result.stdout)
        assert int(lines["commands_received"]) >= 0.5 * 10 * (RUN_S - 5), (name, result.stdout)
        assert lines["last_command"] == "0.1,0.0", (name, result.stdout)
        assert float(lines["x"]) > 0.1 * (RUN_S - 10), (name, result.stdout)
