"""The TurtleBot3 firmware's heap figure on MicroPython's real unix port, built 32-bit like an ESP32.

    .venv/bin/python bench/micropython/unix_heap.py --source MP_TREE [--caps 76,78,...] [--runs N]
        [--seconds S] [--load mpy|py] [--parallel J]
    .venv/bin/python bench/micropython/unix_heap.py --mirror MP_GIT_DIR --source MP_TREE ...

``--source`` is a MicroPython 1.27 source tree; ``--mirror`` a git directory of the
micropython/micropython repository to extract tag v1.27.0 from into ``--source`` first (this script
never downloads anything). It builds ``mpy-cross`` and the unix port once
(``ports/unix/build-32/micropython32``; needs ``gcc-multilib libc6-dev-i386``), then for every cap
runs ``xrce/examples/turtlebot3.py`` (from .mpy as ``build-mpy`` ships it, or from .py) under
``-X heapsize=CAP`` over the real ``UdpTransport`` and the port's real ``socket``, through a live
``xrce-agent -m ced``, with a CPython client publishing reliable ``/cmd_vel`` at 44 Hz and the
firmware syncing its clock every second, ``--runs`` times for ``--seconds`` each.

A run passes when the firmware connected, set up every topic, ran the whole time (no
``MemoryError``) and received commands; a run that ended without a ``MemoryError`` but without one
of the others (the agent of a loaded machine late with a set-up answer) is no heap result and is
run again, at most twice, and counted apart. The figure printed is the smallest cap from which every
larger cap tried passed every run. Per run the firmware samples its heap every ``--sample-s``
seconds: the live heap (``gc.mem_alloc()`` right after ``gc.collect()``), the peak (the highest
``gc.mem_alloc()`` seen after any loop pass, garbage included) and the largest free block
(``micropython.mem_info()``'s "max free sz", in 16-byte blocks, after that collection); the table
gives each cap's medians and the worst run's figures, ``--verbose`` every sample. The collection
every few seconds is the sampling's own: a board's collector runs when an allocation does not fit,
which these samples do not prevent (they only free garbage a little earlier).
"""

import argparse
import os
import re
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from agent_process import AgentProcess  # noqa: E402
from xrce.client.session import Session  # noqa: E402
from xrce.msgs.geometry_msgs import Twist, Vector3  # noqa: E402
from xrce.tools import mpy  # noqa: E402
from xrce.transports.udp import UdpTransport  # noqa: E402

MICROPYTHON_TAG = "v1.27.0"
PROG = "micropython32"
BUILD_FLAGS = ("MICROPY_PY_BTREE=0", "MICROPY_PY_SSL=0", "MICROPY_PY_FFI=0", "MICROPY_VFS_FAT=0",
               "MICROPY_VFS_LFS1=0", "MICROPY_VFS_LFS2=0", "FROZEN_MANIFEST=", "MICROPY_FORCE_32BIT=1",
               "BUILD=build-32", "PROG=" + PROG)
CMD_VEL_HZ = 44

# Runs under the unix port: the firmware as a board's main.py would run it (connect, setup, the loop),
# with heap samples. argv: agent_port run_seconds sample_seconds client_key_hex
FIRMWARE = """\
import gc
import sys

import micropython
from xrce import ticks_diff, ticks_ms
from xrce.examples.turtlebot3 import TurtleBot3
from xrce.transports.udp import UdpTransport

port = int(sys.argv[1])
run_ms = int(float(sys.argv[2]) * 1000)
sample_ms = int(float(sys.argv[3]) * 1000)
key = bytes(int(sys.argv[4][i:i + 2], 16) for i in (0, 2, 4, 6))
transport = UdpTransport("127.0.0.1", port)
robot = TurtleBot3(transport, cmd_vel_reliable=True, key=key, time_sync_period_ms=1000)
print("connect", robot.connect(timeout_ms=500, attempts=20) is not None)
print("setup", robot.setup())
print("failed_topics", ",".join(robot.failed_topics) or "-")
gc.collect()
print("after_setup", gc.mem_alloc())
start = ticks_ms()
due = 0
peak = 0
while True:
    elapsed = ticks_diff(ticks_ms(), start)
    if elapsed >= run_ms:
        break
    robot.step()
    used = gc.mem_alloc()
    if used > peak:
        peak = used
    if elapsed >= due:
        due += sample_ms
        gc.collect()
        print("sample", elapsed, gc.mem_alloc(), peak)
        micropython.mem_info()
print("commands_received", robot.commands_received)
print("time_syncs", robot.time_syncs)
print("published_odom", robot.published.get("odom", 0))
robot.shutdown()
print("done", True)
"""

_MAX_FREE = re.compile(r"max free sz: (\d+)")

# Runs under the unix port and under the WebAssembly harness with its socket shim
# (tests/micropython/socket.py): what UdpTransport.recv allocates per datagram received, with the
# collector kept out of the way (disabled on the port; the WebAssembly port does not collect while
# Python runs). argv: echo_port count size
RECV_CHECK = """\
import gc
import sys

from xrce.transports.udp import UdpTransport

port = int(sys.argv[1])
count = int(sys.argv[2])
size = int(sys.argv[3])
transport = UdpTransport("127.0.0.1", port)
message = bytes(size)
got = [None] * count
for i in range(2):  # warm-up: the first poll, the first datagram
    transport.send(message)
    transport.recv(2000)
gc.collect()
gc.disable()
total = 0
for i in range(count):
    transport.send(message)
    before = gc.mem_alloc()
    got[i] = transport.recv(2000)
    total += gc.mem_alloc() - before
    got[i] = None
gc.enable()
print("recv_bytes_per_datagram", total // count)
transport.close()
"""


def build(source, mirror=None):
    """The 32-bit unix port's binary (built unless present)."""
    source = Path(source)
    if mirror is not None and not (source / "py").is_dir():
        source.mkdir(parents=True, exist_ok=True)
        archive = subprocess.Popen(["git", "--git-dir", str(mirror), "archive", MICROPYTHON_TAG],
                                   stdout=subprocess.PIPE)
        subprocess.run(["tar", "-x", "-C", str(source)], stdin=archive.stdout, check=True)
        if archive.wait() != 0:
            raise SystemExit("git archive %s failed in %s" % (MICROPYTHON_TAG, mirror))
    binary = source / "ports" / "unix" / "build-32" / PROG
    if binary.exists():
        return binary
    if not (source / "py" / "mpconfig.h").exists():
        raise SystemExit("%s is not a MicroPython source tree (see --mirror)" % source)
    jobs = "-j%d" % (os.cpu_count() or 1)
    for command in (["make", "-C", str(source / "mpy-cross"), jobs],
                    ["make", "-C", str(source / "ports" / "unix"), jobs, *BUILD_FLAGS]):
        result = subprocess.run(command, capture_output=True, text=True)
        if result.returncode != 0:
            raise SystemExit("%s failed (32-bit build: apt-get install -y gcc-multilib libc6-dev-i386):\n%s"
                             % (" ".join(command), result.stderr[-3000:]))
    return binary


def prepare_lib(workdir, load):
    """A folder to import the client from: build-mpy's output, or the same files as .py."""
    lib = workdir / ("lib-" + load)
    if load == "mpy":
        mpy.build_mpy(lib)
    else:
        for relative in mpy.shipped_files():
            target = lib / relative
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(REPO / relative, target)
    return lib


class CmdVelDriver(threading.Thread):
    """Publishes Twist(linear.x=0.1) on /cmd_vel, reliable, at CMD_VEL_HZ until stopped."""

    def __init__(self, port):
        super().__init__(daemon=True)
        self.session = Session(UdpTransport("127.0.0.1", port), history=8)
        if not self.session.create(attempts=5, timeout_ms=500):
            raise SystemExit("the /cmd_vel driver could not create its session")
        node = self.session.create_participant(name="cmd_vel_driver")
        self.writer = self.session.create_writer(node, "/cmd_vel", Twist, reliable=True)
        if not self.session.run_until_all_status(2000):
            raise SystemExit("the /cmd_vel driver could not create its writer")
        self.halt = threading.Event()

    def run(self):
        command = Twist(linear=Vector3(x=0.1))
        period = 1.0 / CMD_VEL_HZ
        next_at = time.monotonic()
        while not self.halt.is_set():
            self.session.write(self.writer, command)
            next_at += period
            while time.monotonic() < next_at:
                self.session.spin_once(max(1, int((next_at - time.monotonic()) * 1000)))

    def close(self):
        self.halt.set()
        self.join(5)
        self.session.delete(attempts=1, timeout_ms=200)
        self.session.close()


def run_firmware(binary, lib, script, workdir, cap_kib, port, seconds, sample_s, key):
    """One run: its figures as a dict (``ok``, ``samples`` [(ms, live, peak, max_free_bytes)], ...)."""
    env = dict(os.environ, MICROPYPATH=str(lib))
    # From an empty folder: the port puts the working directory first on its path.
    command = [str(binary), "-X", "heapsize=%dk" % cap_kib, "-c",
               "import sys; sys.argv[1:] = %r; import firmware_heap" % ([str(port), str(seconds), str(sample_s),
                                                                        "%08x" % key],)]
    try:
        result = subprocess.run(command, cwd=workdir, env=env, capture_output=True, text=True,
                                timeout=seconds + 120)
        stdout, stderr, code = result.stdout, result.stderr, result.returncode
    except subprocess.TimeoutExpired as expired:
        stdout = expired.stdout.decode() if isinstance(expired.stdout, bytes) else (expired.stdout or "")
        stderr, code = "timeout", -1
    lines = {}
    samples = []
    for line in stdout.splitlines():
        if line.startswith("sample "):
            _, ms, live, peak = line.split()
            samples.append([int(ms), int(live), int(peak), None])
        else:
            match = _MAX_FREE.search(line)
            if match and samples:
                samples[-1][3] = int(match.group(1)) * 16  # blocks of 4 words on a 32-bit port
            elif " " in line:
                key_, value = line.split(" ", 1)
                lines[key_] = value
    ok = (code == 0 and lines.get("connect") == "True" and lines.get("setup") == "True"
          and lines.get("done") == "True" and lines.get("failed_topics") == "-"
          and int(lines.get("commands_received", "0")) > 0)
    error = ""
    if not ok and code == 0:
        # Ran to its end without a MemoryError: a set-up request the agent did not answer in time,
        # or no command came through (a loaded machine). No heap result: the caller runs it again.
        error = "no heap failure: setup %s, failed topics %s, commands %s" % (
            lines.get("setup"), lines.get("failed_topics"), lines.get("commands_received"))
        return {"ok": ok, "cap": cap_kib, "samples": samples, "lines": lines, "error": error, "retry": True}
    if not ok:
        # The traceback (the unix port prints it on stdout): where it failed, and what.
        tail = [line.strip() for line in (stdout + stderr).strip().splitlines() if line.strip()]
        where = [line for line in tail if line.startswith("File ")]
        error = "exit %d: %s%s" % (code, tail[-1] if tail else "", (" at " + where[-1]) if where else "")
        lines["traceback"] = "\n".join(tail[-12:])
    return {"ok": ok, "cap": cap_kib, "samples": samples, "lines": lines, "error": error}


class Echo(threading.Thread):
    """A UDP peer that sends every datagram back."""

    def __init__(self):
        super().__init__(daemon=True)
        import socket

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]

    def run(self):
        try:
            while True:
                data, address = self.sock.recvfrom(4096)
                self.sock.sendto(data, address)
        except OSError:
            pass  # closed


def socket_check(binary, lib, workdir, sizes=(24, 200, 500), count=50):
    """Bytes UdpTransport.recv allocates per datagram: the unix port's real socket beside the
    WebAssembly harness' socket shim, which should allocate the same plus the n-byte receive
    buffer the port frees on return (garbage until the step ends there) and its two views."""
    from mp_harness import run_micropython

    echo = Echo()
    echo.start()
    try:
        script = workdir / "recv_check.py"
        script.write_text(RECV_CHECK)
        rows = []
        for size in sizes:
            args = [str(echo.port), str(count), str(size)]
            port = subprocess.run([str(binary), str(script), *args], cwd=workdir, capture_output=True, text=True,
                                  env=dict(os.environ, MICROPYPATH=str(lib)), timeout=120)
            shim = run_micropython(RECV_CHECK, *args, timeout=120)
            values = []
            for result in (port, shim):
                match = re.search(r"recv_bytes_per_datagram (\d+)", result.stdout)
                values.append(int(match.group(1)) if match else None)
                if match is None:
                    print("recv check failed:", result.stdout[-500:], result.stderr[-500:])
            rows.append((size, values[0], values[1]))
        return rows
    finally:
        echo.sock.close()


def figure(results):
    """The smallest cap from which every larger cap tried passed every run (None if the largest failed)."""
    best = None
    for cap in sorted(results, reverse=True):
        if all(run["ok"] for run in results[cap]):
            best = cap
        else:
            break
    return best


def summarize(cap, runs):
    passed = sum(run["ok"] for run in runs)
    lives = [s[1] for run in runs for s in run["samples"][1:]]
    peaks = [run["samples"][-1][2] for run in runs if run["samples"]]
    frees = [s[3] for run in runs for s in run["samples"][1:] if s[3] is not None]
    errors = sorted({run["error"] for run in runs if run["error"]})

    def kb(values, pick):
        return "%.1f" % (pick(values) / 1000) if values else "-"

    return ("%4d KiB  %2d/%-2d  live %5s..%-5s KB  peak %5s KB  largest free %5s..%-5s KB  %s" % (
        cap, passed, len(runs), kb(lives, min), kb(lives, max), kb(peaks, max), kb(frees, min),
        kb(frees, max), "; ".join(errors)[:160]))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--source", required=True, help="MicroPython 1.27 source tree (built here)")
    parser.add_argument("--mirror", help="git dir of micropython/micropython to extract %s from" % MICROPYTHON_TAG)
    parser.add_argument("--caps", default="76,78,80,82,84,86,88,90,92,96,100",
                        help="heap caps in KiB, comma-separated")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=30)
    parser.add_argument("--sample-s", type=float, default=5)
    parser.add_argument("--load", choices=("mpy", "py"), default="mpy")
    parser.add_argument("--parallel", type=int, default=4, help="firmware runs at once")
    parser.add_argument("--verbose", action="store_true", help="every heap sample of every run")
    parser.add_argument("--socket-check", action="store_true",
                        help="also compare the test harness' socket shim with the port's recv (no sweep if --caps is empty)")
    args = parser.parse_args(argv)
    caps = sorted(int(cap) for cap in args.caps.split(",") if cap)
    binary = build(args.source, args.mirror)
    if args.socket_check:
        with tempfile.TemporaryDirectory(prefix="xrce-unix-recv-") as tmp:
            tmp = Path(tmp)
            lib = prepare_lib(tmp, "mpy")
            workdir = tmp / "cwd"
            workdir.mkdir()
            print("UdpTransport.recv, bytes allocated per datagram (gc.mem_alloc growth, no collection):")
            print("  datagram  unix port  harness shim  shim - port")
            for size, port, shim in socket_check(binary, lib, workdir):
                print("  %8d  %9s  %12s  %11s" % (size, port, shim,
                                                 "-" if port is None or shim is None else shim - port))
        if not caps:
            return 0
    print("port: %s (32-bit unix, MicroPython %s); load: .%s; %d run(s) of %g s per cap; /cmd_vel %d Hz"
          % (binary, MICROPYTHON_TAG, args.load, args.runs, args.seconds, CMD_VEL_HZ), flush=True)
    results = {cap: [] for cap in caps}
    reruns = {}  # runs repeated because they ended without a heap result
    with tempfile.TemporaryDirectory(prefix="xrce-unix-heap-") as tmp:
        tmp = Path(tmp)
        lib = prepare_lib(tmp, args.load)
        script_dir = tmp / "script"
        script_dir.mkdir()
        (script_dir / "firmware_heap.py").write_text(FIRMWARE)
        # From .mpy too, as a board's own main loop: compiled from source it would keep its code
        # and names on the heap, under the cap.
        mpy.build_mpy(lib, root=script_dir, files=["firmware_heap.py"])
        script = None
        workdir = tmp / "cwd"
        workdir.mkdir()
        jobs = [(cap, run) for run in range(args.runs) for cap in caps]
        with AgentProcess("udp4", "-m", "ced") as agent:
            driver = CmdVelDriver(agent.port)
            driver.start()
            lock = threading.Lock()
            try:
                def worker(index):
                    while True:
                        with lock:
                            if not jobs:
                                return
                            cap, run = jobs.pop(0)
                        key = 0x55480000 | (cap << 4) | (run & 0xF) | (index << 12)
                        for attempt in range(3):
                            outcome = run_firmware(binary, lib, script, workdir, cap, agent.port, args.seconds,
                                                   args.sample_s, key + (attempt << 8))
                            if not outcome.get("retry"):
                                break
                            with lock:
                                reruns[cap] = reruns.get(cap, 0) + 1
                                print("  %d KiB run %d: again (%s)" % (cap, run + 1, outcome["error"]), flush=True)
                        with lock:
                            results[cap].append(outcome)
                            last = outcome["samples"][-1] if outcome["samples"] else None
                            print("  %d KiB run %d: %s%s" % (
                                cap, run + 1, "pass" if outcome["ok"] else "FAIL " + outcome["error"],
                                "" if last is None else " (live %d, peak %d, largest free %s)" % tuple(last[1:])),
                                flush=True)
                            if args.verbose:
                                if not outcome["ok"]:
                                    print("    " + outcome["lines"].get("traceback", "").replace("\n", "\n    "))
                                for sample in outcome["samples"]:
                                    print("    t=%6d ms live %6d peak %6d largest free %s" % tuple(sample))

                workers = [threading.Thread(target=worker, args=(i,), daemon=True) for i in range(args.parallel)]
                for thread in workers:
                    thread.start()
                for thread in workers:
                    while thread.is_alive():  # a join with a timeout lets Ctrl-C through
                        thread.join(1)
            finally:
                driver.close()
    print()
    print("cap       pass   live heap (after collect)  peak      largest free block")
    for cap in caps:
        print(summarize(cap, results[cap]) + ("  (%d run(s) repeated: no heap result)" % reruns[cap]
                                              if reruns.get(cap) else ""))
    best = figure(results)
    print()
    print("figure (.%s): %s" % (args.load, "%d KiB" % best if best is not None else "none: the largest cap failed"))
    return 0


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    sys.exit(main())
