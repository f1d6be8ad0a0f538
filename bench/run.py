"""Every benchmark, each figure next to a baseline measured in the same run.

    .venv/bin/python bench/run.py [--quick] [--only NAME[,NAME...]]

Prints one JSON line per figure as it is measured ({"name", "value", "unit", "baseline", "ratio",
"baseline_name", "target", "note"}) and one table at the end. Groups (``--only``): ros, latency,
cost, serial, sessions, footprint, restart. ``cost`` (bench/agent_cost.py) is what the agent costs the
robot's computer: CPU per message at fixed offered rates, idle CPU, the TurtleBot3 load, memory,
ping; ``--reference DIR`` measures another source tree's agent beside it in the same run.
``restart`` (bench/restart_gap.py): the ROS gap after an agent SIGKILL + restart, and a board reset.

Agents (``xrce-agent``), the rclpy peers (bench/ros_peer.py) and client swarms
(bench/session_swarm.py) each run in their own process; ROS traffic stays on a leased ROS domain
with LOCALHOST discovery. The machine's cores are shared by the clients, the agent and the ROS
peers, as they would not be in a deployment: every figure includes that contention.
"""

import argparse
import json
import math
import os
import re
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

from agent_process import AgentProcess  # noqa: E402
from ros_helpers import DomainLease  # noqa: E402
from xrce.agent.stats_view import fetch_stats  # noqa: E402

PYTHON = sys.executable
FIGURES = []


class Figure:
    __slots__ = ("name", "value", "unit", "baseline", "baseline_name", "target", "note")

    def __init__(self, name, value, unit, baseline, baseline_name, target="", note=""):
        self.name, self.value, self.unit = name, value, unit
        self.baseline, self.baseline_name = baseline, baseline_name
        self.target, self.note = target, note

    @property
    def ratio(self):
        if self.value is None or not self.baseline:
            return None
        return self.value / self.baseline

    def as_json(self):
        return {"name": self.name, "value": _round(self.value), "unit": self.unit,
                "baseline": _round(self.baseline), "ratio": _round(self.ratio, 3),
                "baseline_name": self.baseline_name, "target": self.target, "note": self.note}


def _round(value, digits=1):
    if value is None:
        return None
    if isinstance(value, float):
        return round(value, digits) if abs(value) >= 1 or digits > 1 else round(value, 3)
    return value


def record(*args, **kwargs):
    figure = Figure(*args, **kwargs)
    FIGURES.append(figure)
    print(json.dumps(figure.as_json()), flush=True)
    return figure


def percentile(values, fraction):
    ordered = sorted(values)
    if not ordered:
        return None
    index = min(len(ordered) - 1, max(0, int(math.ceil(fraction * len(ordered))) - 1))
    return ordered[index]


def stats_port(agent):
    return int(re.search(r"stats on 127\.0\.0\.1:(\d+)", agent.banner).group(1))


def cpu_seconds(pid):
    """User + system CPU time of a process and its threads, from /proc."""
    with open("/proc/%d/stat" % pid) as stat:
        fields = stat.read().rsplit(")", 1)[1].split()
    ticks = os.sysconf("SC_CLK_TCK")
    return (int(fields[11]) + int(fields[12])) / ticks


class Child:
    """A line-protocol child process (ros_peer.py, session_swarm.py, serial_flood.py)."""

    def __init__(self, args, env=None, ready=None, timeout=60):
        self.proc = subprocess.Popen([PYTHON, *args], cwd=REPO, env=env, stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                     bufsize=1)
        if ready is not None:
            line = self.readline(timeout)
            if not line.startswith(ready):
                self.close()
                raise RuntimeError("%s did not start: %r" % (args[0], line))
            self.first_line = line

    def readline(self, timeout=120):
        result = []
        reader = threading.Thread(target=lambda: result.append(self.proc.stdout.readline()),
                                  daemon=True)
        reader.start()
        reader.join(timeout)
        if not result:
            raise RuntimeError("no answer within %.0f s" % timeout)
        return result[0].strip()

    def ask(self, line, timeout=120):
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        return self.readline(timeout)

    def close(self):
        if self.proc.poll() is None:
            try:
                self.proc.stdin.write("quit\n")
                self.proc.stdin.flush()
                self.proc.stdin.close()
            except (BrokenPipeError, OSError):
                pass
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for stream in (self.proc.stdin, self.proc.stdout):
            try:
                stream.close()
            except (BrokenPipeError, OSError):
                pass


def arrival_rate(peer, topic):
    count, first, last = peer.ask("count %s" % topic).split()
    count, first, last = int(count), float(first), float(last)
    return (count - 1) / (last - first) if count > 1 and last > first else 0.0, count


def wait_for(predicate, timeout_s=10.0, interval_s=0.05):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() >= deadline:
            return False
        time.sleep(interval_s)
    return True


# ----------------------------------------------------------------------------------- ROS figures

def ros_benchmarks(env, domain_id, seconds, latency_count, ping_count, groups):
    from xrce.client.session import Session
    from xrce.msgs.geometry_msgs import Twist, Vector3
    from xrce.transports.udp import UdpTransport

    sink = Child(["bench/ros_peer.py"], env=env, ready="ready")
    source = Child(["bench/ros_peer.py"], env=env, ready="ready")
    agent = AgentProcess("udp4", "-m", "dds", "-v", "0", "--stats-port", "0", env=env)
    agent.__enter__()
    session = Session(UdpTransport("127.0.0.1", agent.port), history=16)
    try:
        if not session.create(attempts=5, timeout_ms=2000):
            raise RuntimeError("no session with the dds agent")
        node = session.create_participant(domain_id=domain_id, name="bench_client")

        if "ros" in groups:
            for kind, reliable in (("be", False), ("rel", True)):
                bare = "/bare_%s" % kind
                sink.ask("sub %s %s" % (bare, kind))
                source.ask("flood %s %s %.1f" % (bare, kind, seconds), timeout=seconds + 30)
                time.sleep(0.3)
                baseline, _ = arrival_rate(sink, bare)

                topic = "/xrce_%s" % kind
                sink.ask("sub %s %s" % (topic, kind))
                writer = session.create_writer(node, topic, Twist, reliable=reliable, depth=1000)
                if not session.run_until_all_status(5000):
                    raise RuntimeError("writer not created: %r" % session.last_statuses)
                wait_for(lambda: sink.ask("publishers %s" % topic) != "0")
                time.sleep(0.5)
                stream = session.reliable if reliable else session.best_effort
                sample = Twist(linear=Vector3(x=1.0))
                sent = 0
                cpu_before = cpu_seconds(agent.proc.pid)
                start = time.monotonic()
                end = start + seconds
                while time.monotonic() < end:
                    for _ in range(50):
                        session.write(writer, sample, stream_id=stream)
                        session.flush()
                    sent += 50
                    if reliable:
                        session.spin_once(0)
                elapsed = time.monotonic() - start
                agent_cpu = (cpu_seconds(agent.proc.pid) - cpu_before) / elapsed
                if reliable:
                    session.run_until_confirm_delivery(5000)
                time.sleep(0.5)
                rate, received = arrival_rate(sink, topic)
                record("client->ROS %s" % ("reliable" if reliable else "best-effort"), rate,
                       "msg/s", baseline, "bare rclpy pub->same sub",
                       ">= 0.8" if not reliable else "",
                       "client sent %.0f msg/s, sub got %d of %d, agent CPU %.0f %% of one core"
                       % (sent / elapsed, received, sent, 100 * agent_cpu))

            # ROS -> client: the bare publisher's own rate is the baseline.
            topic = "/to_client"
            got = []
            session.create_reader(node, topic, Twist, lambda m: got.append(time.monotonic()),
                                  reliable=False, depth=1000)
            if not session.run_until_all_status(5000):
                raise RuntimeError("reader not created: %r" % session.last_statuses)
            answer = []
            flood = threading.Thread(target=lambda: answer.append(
                source.ask("flood %s be %.1f" % (topic, seconds), timeout=seconds + 30)))
            flood.start()
            while flood.is_alive():
                session.spin_once(10)
            session.run_until_timeout(500)
            published, published_s = answer[0].split()[:2]
            baseline = int(published) / float(published_s)
            rate = (len(got) - 1) / (got[-1] - got[0]) if len(got) > 1 else 0.0
            record("ROS->client best-effort", rate, "msg/s", baseline, "bare rclpy publish rate",
                   "", "client got %d of %s" % (len(got), published))

        if "latency" in groups:
            # Ping: GET_INFO in the session, timed by the client; baseline: raw UDP echo.
            rtts = []
            for _ in range(ping_count):
                if session.ping(timeout_ms=1000):
                    rtts.append(session.last_rtt_us)
            echo = udp_echo_rtts(ping_count)
            record("ping RTT p50", percentile(rtts, 0.5), "us", percentile(echo, 0.5),
                   "raw UDP echo p50 (Python, loopback)", "< 200 us")
            record("ping RTT p99", percentile(rtts, 0.99), "us", percentile(echo, 0.99),
                   "raw UDP echo p99")

            # End to end: client write -> rclpy callback; baseline: rclpy pub -> same sub.
            sink.ask("lat /bare_lat be")
            source.ask("stamped /bare_lat be %d 200" % latency_count, timeout=latency_count / 100 + 30)
            time.sleep(0.3)
            bare = [s * 1e3 for s in json.loads(sink.ask("latency /bare_lat"))]
            sink.ask("lat /xrce_lat be")
            writer = session.create_writer(node, "/xrce_lat", Twist, reliable=False)
            if not session.run_until_all_status(5000):
                raise RuntimeError("latency writer not created")
            wait_for(lambda: sink.ask("publishers /xrce_lat") != "0")
            time.sleep(0.5)
            sample = Twist()
            start = time.monotonic()
            for index in range(latency_count):
                due = start + index / 200.0
                while True:
                    now = time.monotonic()
                    if now >= due:
                        break
                    session.spin_once(0)
                    remaining = due - time.monotonic()
                    if remaining > 0.001:
                        time.sleep(remaining - 0.0005)
                sample.linear.x = time.monotonic()
                session.write(writer, sample, stream_id=session.best_effort)
                session.flush()
            time.sleep(0.5)
            xrce = [s * 1e3 for s in json.loads(sink.ask("latency /xrce_lat"))]
            note = "received %d of %d" % (len(xrce), latency_count)
            record("end-to-end latency p50", percentile(xrce, 0.5), "ms", percentile(bare, 0.5),
                   "bare rclpy pub->sub p50", "< 1 ms", note)
            record("end-to-end latency p99", percentile(xrce, 0.99), "ms", percentile(bare, 0.99),
                   "bare rclpy pub->sub p99", "< 5 ms", note)
    finally:
        try:
            session.delete(attempts=2, timeout_ms=500)
        finally:
            session.close()
            agent.stop()
            sink.close()
            source.close()


UDP_ECHO = r"""
import socket, sys
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind(("127.0.0.1", 0))
print(s.getsockname()[1], flush=True)
while True:
    data, addr = s.recvfrom(2048)
    if data == b"quit":
        break
    s.sendto(data, addr)
"""


def udp_echo_rtts(count):
    """Round trips of a 16-byte datagram to a Python echo process, in microseconds."""
    import socket

    echo = subprocess.Popen([PYTHON, "-c", UDP_ECHO], stdout=subprocess.PIPE, text=True)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        address = ("127.0.0.1", int(echo.stdout.readline()))
        sock.settimeout(1.0)
        rtts = []
        for _ in range(count):
            start = time.perf_counter_ns()
            sock.sendto(b"0123456789abcdef", address)
            sock.recvfrom(2048)
            rtts.append((time.perf_counter_ns() - start) / 1000.0)
        sock.sendto(b"quit", address)
        echo.wait(5)
        return rtts
    finally:
        sock.close()
        if echo.poll() is None:
            echo.kill()
            echo.wait()
        echo.stdout.close()


# ----------------------------------------------------------------------------------- serial

def serial_goodput(baudrate, seconds, size=200):
    """Best-effort samples through a paced relay (baud/10 bytes per second each way) into an agent
    pseudoterminal; the ratio is the line's utilisation: framed bytes the agent read per second
    over baud/10. Loss: samples written minus samples the agent accepted."""
    from xrce.tools.relays import SerialRelay

    line_bytes_per_s = baudrate / 10.0
    count = max(20, int(line_bytes_per_s * seconds / (size + 27)))
    with AgentProcess("pseudoterminal", "-m", "ced", "-v", "0", "--stats-port", "0") as agent:
        port = stats_port(agent)
        device = agent.device.rstrip(";")
        with SerialRelay(device, baudrate=baudrate) as relay:
            client = Child(["bench/serial_flood.py", "--device", relay.client_path,
                            "--baudrate", str(baudrate), "--count", str(count),
                            "--size", str(size)], ready="ready")
            try:
                before = fetch_stats(port)
                link_before = before["links"][0]["bytes_in"]
                start = time.monotonic()
                client.proc.stdin.write("go\n")
                client.proc.stdin.flush()
                samples = done_at = 0
                last_progress = time.monotonic()
                topic = {}
                while True:
                    time.sleep(0.01)
                    snapshot = fetch_stats(port)
                    topic = next((t for t in snapshot["topics"]
                                  if t["topic"] == "rt/serial_goodput"), {})
                    now = time.monotonic()
                    if topic.get("samples", 0) != samples:
                        samples, last_progress, done_at = topic["samples"], now, now
                    if samples >= count or now - last_progress > 2.0:
                        break
                elapsed = done_at - start
                line_bytes = snapshot["links"][0]["bytes_in"] - link_before
                utilisation = line_bytes / elapsed / line_bytes_per_s if elapsed > 0 else 0
                goodput = topic.get("bytes", 0) / elapsed if elapsed > 0 else 0
                payload_share = topic.get("bytes", 0) / line_bytes if line_bytes else 0
                record("serial goodput %d baud" % baudrate, goodput, "B/s",
                       line_bytes_per_s * payload_share,
                       "line capacity after framing/XRCE overhead (baud/10 x payload share %.3f)"
                       % payload_share, ">= 0.95, 0 loss",
                       "%d-byte strings, %d sent, %d lost, line utilisation %.3f"
                       % (size, count, count - samples, utilisation))
                client.proc.stdin.write("done\n")
                client.proc.stdin.flush()
            finally:
                client.close()


# ----------------------------------------------------------------------------------- sessions

def concurrent_sessions(count, seconds, rate=10.0, per_process=250):
    drivers = []
    args = ["udp4", "-m", "ced", "-v", "0", "--stats-port", "0", "--max-clients",
            str(max(2048, count * 2))]
    with AgentProcess(*args) as agent:
        port = stats_port(agent)
        try:
            processes = max(1, int(math.ceil(count / float(per_process))))
            shares = [count // processes + (1 if i < count % processes else 0)
                      for i in range(processes)]
            first_key = 1
            for share in shares:
                drivers.append(Child(["bench/session_swarm.py", "--port", str(agent.port),
                                      "--sessions", str(share), "--rate", str(rate),
                                      "--seconds", str(seconds), "--first-key", str(first_key)]))
                first_key += share
            creation = [float(d.readline(300).split()[2]) for d in drivers]
            # The agent-wide counter: the drivers delete their sessions (and topics) when done.
            samples_before = fetch_stats(port)["agent"]["samples_in"]
            cpu_before = cpu_seconds(agent.proc.pid)
            start = time.monotonic()
            for driver in drivers:
                driver.proc.stdin.write("go\n")
                driver.proc.stdin.flush()
            results = [d.readline(seconds + 120).split() for d in drivers]
            elapsed = time.monotonic() - start
            time.sleep(0.3)
            cpu = (cpu_seconds(agent.proc.pid) - cpu_before) / elapsed
            sent = sum(int(r[1]) for r in results)
            late = sum(int(r[2]) for r in results)
            delivered = fetch_stats(port)["agent"]["samples_in"] - samples_before
            record("%d sessions at %.0f Hz: delivery" % (count, rate), 100.0 * delivered / sent
                   if sent else 0.0, "%", 100.0, "samples sent by the clients", ">= 99.9 %",
                   "%d/%d delivered; agent CPU %.0f %% of one core; %d late writes; sessions "
                   "created in %.1f s by %d processes" % (delivered, sent, 100 * cpu, late,
                                                           max(creation), len(drivers)))
        finally:
            for driver in drivers:
                driver.close()


# ----------------------------------------------------------------------------------- footprint

def footprint():
    output = subprocess.run([PYTHON, "bench/client_footprint.py", "--iterations", "1000"],
                            cwd=REPO, capture_output=True, text=True, timeout=600).stdout
    heap = re.search(r"total heap after imports\s+(\d+)", output)
    encode = re.search(r"encode us/op\s+([\d.]+)\s+([\d.]+)", output)
    decode = re.search(r"decode us/op\s+([\d.]+)\s+([\d.]+)", output)
    headline = re.search(r"TOTAL import \+ session \+ publisher \+ subscriber\s+(\d+)", output)
    if headline:
        record("MicroPython heap: import + session + pub + sub", int(headline.group(1)), "bytes",
               None, "-", "", "bench/client_footprint.py headline figure")
    if heap:
        record("MicroPython heap after client imports", int(heap.group(1)), "bytes", None,
               "-", "", "bench/client_footprint.py, WebAssembly MicroPython 1.27")
    if encode:
        record("Twist CDR encode (MicroPython)", float(encode.group(1)), "us",
               float(encode.group(2)), "CPython, same code")
    if decode:
        record("Twist CDR decode (MicroPython)", float(decode.group(1)), "us",
               float(decode.group(2)), "CPython, same code")


# ----------------------------------------------------------------------------------- main

def print_table():
    headers = ("figure", "value", "unit", "baseline", "ratio", "target", "baseline is")
    rows = []
    for f in FIGURES:
        rows.append((f.name, _text(f.value), f.unit, _text(f.baseline),
                     "-" if f.ratio is None else "%.3f" % f.ratio, f.target or "-",
                     f.baseline_name))
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h)
              for i, h in enumerate(headers)]
    print()
    print("| " + " | ".join(h.ljust(w) for h, w in zip(headers, widths)) + " |")
    print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    for row in rows:
        print("| " + " | ".join(c.ljust(w) for c, w in zip(row, widths)) + " |")
    notes = [(f.name, f.note) for f in FIGURES if f.note]
    for name, note in notes:
        print("  %s: %s" % (name, note))


def _text(value):
    if value is None:
        return "-"
    if isinstance(value, float):
        return "%.3f" % value if abs(value) < 10 else "%.0f" % value
    return str(value)


GROUPS = ("ros", "latency", "cost", "serial", "sessions", "footprint", "restart")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short runs (under 2 minutes)")
    parser.add_argument("--only", default=",".join(GROUPS),
                        help="comma-separated groups: %s" % ", ".join(GROUPS))
    parser.add_argument("--reference", metavar="DIR",
                        help="cost group: also measure the agent of this source tree (baseline)")
    args = parser.parse_args(argv)
    groups = set(args.only.split(","))
    unknown = groups - set(GROUPS)
    if unknown:
        parser.error("unknown group(s): %s" % ", ".join(sorted(unknown)))
    quick = args.quick
    started = time.monotonic()
    lease = DomainLease()
    env = dict(os.environ, ROS_DOMAIN_ID=str(lease.domain_id),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    try:
        if groups & {"ros", "latency"}:
            ros_benchmarks(env, lease.domain_id, seconds=2.0 if quick else 5.0,
                           latency_count=300 if quick else 2000,
                           ping_count=300 if quick else 2000, groups=groups)
        if "cost" in groups:
            sys.modules.setdefault("run", sys.modules[__name__])  # one FIGURES list for both
            from agent_cost import cost_benchmarks
            cost_benchmarks(env, lease.domain_id, quick, args.reference)
        if "serial" in groups:
            for baudrate in (115200, 921600):
                serial_goodput(baudrate, seconds=2.0 if quick else 8.0)
        if "sessions" in groups:
            for count in ((100, 500) if quick else (100, 500, 1000)):
                concurrent_sessions(count, seconds=3.0 if quick else 20.0)
        if "footprint" in groups:
            footprint()
        if "restart" in groups:  # bench/restart_gap.py: agent SIGKILL + restart, board reset
            import restart_gap
            restart_gap.report(record, env, runs=3 if quick else 5)
    finally:
        lease.release()
    print_table()
    print("total %.0f s (%s run, %d cores shared by clients, agent and ROS peers)"
          % (time.monotonic() - started, "quick" if quick else "full", os.cpu_count()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
