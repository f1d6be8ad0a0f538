"""Every benchmark, each figure next to a baseline measured in the same run.

The bench's entry: bench/README.md lists the scripts by folder, docs/PERFORMANCE.md the figures by
the question they answer.

    .venv/bin/python bench/run.py [--quick] [--only NAME[,NAME...]] [--reference DIR]
    .venv/bin/python bench/run.py --smoke

Prints one JSON line per figure as it is measured ({"name", "value", "unit", "baseline", "ratio",
"baseline_name", "target", "note"}) and one table at the end. Groups (``--only``):

- ``ros``, ``latency`` (bench/agent/ros_bridge.py): samples between a client and rclpy through the
  agent beside two bare rclpy processes, ping beside a raw UDP echo, end-to-end latency;
- ``cost`` (bench/agent/cost.py): what the agent costs the robot's computer: CPU per message at
  fixed offered rates, idle CPU, the TurtleBot3 load, memory, ping; ``--reference DIR`` measures
  another source tree's agent beside it in the same run;
- ``serial``, ``sessions``, ``footprint`` (here, with bench/agent/serial_flood.py,
  bench/churn/session_swarm.py, bench/micropython/client_footprint.py);
- ``restart`` (bench/restart/restart_gap.py): the ROS gap after an agent SIGKILL + restart, and a
  board reset;
- ``creation`` (bench/microros/entity_creation.py): a micro-ROS firmware's entity creation beside
  eProsima's agent answering the same CREATEs;
- ``discovery`` (bench/restart/discovery.py): first sample after either side appears, per start
  order, 20 trials each (5 with ``--quick``), with the agent-restart gap beside them.

``--smoke`` runs nothing of that: every script of bench/ once from its path (its ``--help``, or its
shortest run), every module imported, in about ten seconds (the README's test runs it).

Agents (``xrce-agent``), the rclpy peers (bench/common/ros_peer.py) and client swarms each run in
their own process; ROS traffic stays on a leased ROS domain with LOCALHOST discovery. The machine's
cores are shared by the clients, the agent and the ROS peers, as they would not be in a deployment:
every figure includes that contention.
"""

import argparse
import importlib.util
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from agent_process import AgentProcess  # noqa: E402
from ros_helpers import DomainLease  # noqa: E402
from xrce.agent.observe.stats_view import fetch_stats  # noqa: E402

from bench.agent.ros_bridge import ros_benchmarks  # noqa: E402
from bench.common.figures import print_table, record  # noqa: E402
from bench.common.harness import PYTHON, Child, cpu_seconds, stats_port  # noqa: E402


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
            client = Child(["bench/agent/serial_flood.py", "--device", relay.client_path,
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
                    # DDS name: "topic" is the ROS one since issue 38 (a baseline has only it)
                    topic = next((t for t in snapshot["topics"] if t.get(
                        "dds_topic", t["topic"]) == "rt/serial_goodput"), {})
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
                drivers.append(Child(["bench/churn/session_swarm.py", "--port", str(agent.port),
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
    output = subprocess.run([PYTHON, "bench/micropython/client_footprint.py", "--iterations", "1000"],
                            cwd=REPO, capture_output=True, text=True, timeout=600).stdout
    heap = re.search(r"total heap after imports\s+(\d+)", output)
    encode = re.search(r"encode us/op\s+([\d.]+)\s+([\d.]+)", output)
    decode = re.search(r"decode us/op\s+([\d.]+)\s+([\d.]+)", output)
    headline = re.search(r"TOTAL import \+ session \+ publisher \+ subscriber\s+(\d+)", output)
    if headline:
        record("MicroPython heap: import + session + pub + sub", int(headline.group(1)), "bytes",
               None, "-", "", "bench/micropython/client_footprint.py headline figure")
    if heap:
        record("MicroPython heap after client imports", int(heap.group(1)), "bytes", None,
               "-", "", "bench/micropython/client_footprint.py, WebAssembly MicroPython 1.27")
    if encode:
        record("Twist CDR encode (MicroPython)", float(encode.group(1)), "us",
               float(encode.group(2)), "CPython, same code")
    if decode:
        record("Twist CDR decode (MicroPython)", float(decode.group(1)), "us",
               float(decode.group(2)), "CPython, same code")


# ----------------------------------------------------------------------------------- smoke

# Scripts whose shortest run is not ``--help``: their arguments and what their output must hold.
SMOKE_RUNS = {
    "bench/common/ros_peer.py": ([], "ready"),  # a line-protocol child: ready, then ends at EOF
    "bench/hostile/atheris_engine.py": (["-runs=200"], "Done 200 runs"),  # libFuzzer's options
}
# Scripts that need a package the test extras may not have installed on every platform.
SMOKE_NEEDS = {"bench/hostile/atheris_engine.py": "atheris"}


def smoke_commands():
    """(name, argv, text its output must hold) for every file of bench/: a script's ``--help``
    (or its SMOKE_RUNS entry), a shell script's syntax, and one import of every module that has no
    main of its own. Nothing here starts an agent or joins a ROS domain."""
    commands, modules = [], []
    for path in sorted((REPO / "bench").rglob("*")):
        name = path.relative_to(REPO).as_posix()
        if path.suffix == ".sh":
            commands.append((name, ["bash", "-n", name], ""))
        elif path.suffix == ".py" and "__pycache__" not in path.parts:
            if name in SMOKE_NEEDS and importlib.util.find_spec(SMOKE_NEEDS[name]) is None:
                commands.append((name, None, "no %s installed" % SMOKE_NEEDS[name]))
            elif name in SMOKE_RUNS:
                args, expected = SMOKE_RUNS[name]
                commands.append((name, [PYTHON, name, *args], expected))
            elif '__name__ == "__main__"' in path.read_text():
                commands.append((name, [PYTHON, name, "--help"], "usage:"))
            else:
                modules.append(".".join(path.relative_to(REPO).with_suffix("").parts))
    imports = "; ".join("import " + module.removesuffix(".__init__") for module in modules)
    commands.append(("%d modules without a main" % len(modules), [PYTHON, "-c", imports], ""))
    return commands


def smoke(workers=2):
    """Run every smoke command, ``workers`` at a time; one line each; 0 when all passed."""
    from concurrent.futures import ThreadPoolExecutor

    def run(command):
        name, argv, expected = command
        if argv is None:
            return name, None, expected, 0.0
        started = time.monotonic()
        try:
            done = subprocess.run(argv, cwd=REPO, stdin=subprocess.DEVNULL, capture_output=True,
                                  text=True, timeout=300)
        except subprocess.TimeoutExpired:
            return name, False, "no end within 300 s", time.monotonic() - started
        output = done.stdout + done.stderr
        passed = done.returncode == 0 and expected in output
        return name, passed, "" if passed else "exit %d: %s" % (done.returncode, output[-2000:]), \
            time.monotonic() - started

    failed = 0
    with ThreadPoolExecutor(workers) as pool:
        for name, passed, why, seconds in pool.map(run, smoke_commands()):
            if passed is None:
                print("skip %s: %s" % (name, why), flush=True)
                continue
            print("%-4s %s (%.1f s)%s" % ("ok" if passed else "FAIL", name, seconds,
                                         "" if passed else "\n" + why), flush=True)
            failed += not passed
    print("smoke: %s" % ("%d failed" % failed if failed else "every bench file runs"))
    return 1 if failed else 0


# ----------------------------------------------------------------------------------- main


GROUPS = ("ros", "latency", "cost", "serial", "sessions", "footprint", "restart", "creation",
          "discovery")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short runs (172 s on a busy 2-core machine)")
    parser.add_argument("--only", default=",".join(GROUPS),
                        help="comma-separated groups: %s" % ", ".join(GROUPS))
    parser.add_argument("--smoke", action="store_true",
                        help="only check that every bench script starts from its path (--help, or "
                        "its shortest run; ~1 min) and exit")
    parser.add_argument("--reference", metavar="DIR",
                        help="cost group: also measure the agent of this source tree (baseline)")
    args = parser.parse_args(argv)
    if args.smoke:
        return smoke()
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
            from bench.agent.cost import cost_benchmarks
            cost_benchmarks(env, lease.domain_id, quick, args.reference)
        if "serial" in groups:
            for baudrate in (115200, 921600):
                serial_goodput(baudrate, seconds=2.0 if quick else 8.0)
        if "sessions" in groups:
            for count in ((100, 500) if quick else (100, 500, 1000)):
                concurrent_sessions(count, seconds=3.0 if quick else 20.0)
        if "footprint" in groups:
            footprint()
        if "restart" in groups:  # agent SIGKILL + restart, board reset
            from bench.restart import restart_gap
            restart_gap.report(record, env, runs=3 if quick else 5)
        if "creation" in groups:  # a micro-ROS firmware's set-up vs eProsima's agent
            from bench.microros import entity_creation
            entity_creation.build_interfaces()
            # The firmware's node in the agent's own domain, as deployed (entity_creation.py).
            entity_creation.report(record, env, runs=3 if quick else 7, domain_id=lease.domain_id)
        if "discovery" in groups:  # first sample per start order
            from bench.restart import discovery
            discovery.report(record, env, lease.domain_id, quick)
    finally:
        lease.release()
    print_table()
    print("total %.0f s (%s run, %d cores shared by clients, agent and ROS peers)"
          % (time.monotonic() - started, "quick" if quick else "full", os.cpu_count()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
