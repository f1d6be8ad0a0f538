"""Agent CPU at PX4's load, beside eProsima's MicroXRCEAgent in the same run, and TIMESTAMP round
trips (PX4's time sync) while streaming and on a loaded machine.

    .venv/bin/python bench/px4/load.py --agent-cmd $PEERS/agent.sh \
        --capture tests/golden/px4/px4_main.jsonl.gz --px4-msgs DIR [--rounds 5] [--seconds 20]
        [--agent-px4-msgs] [--only-subscriber | --no-subscriber]

Run it on a private loopback and /dev/shm (PX4's participant is in domain 0):
``unshare -nm sh -c 'mount -t tmpfs tmpfs /dev/shm && ip link set lo up && exec .venv/bin/python
bench/px4/load.py ...'``.

Each round starts every agent afresh, in turns (the order alternates between rounds): PX4's
connect replayed at PX4's pace (bench/px4/replay_load.py), its streaming part at the recorded
timing, and after ``SETTLE_S`` the agent's CPU (utime + stime of all its threads, /proc) over
``--seconds``, with an rclpy node subscribed to the 24 /fmu/out topics as PX4 users run one
(px4_ros_com's best-effort QoS) and without. Then, still streaming, ``--load`` busy processes
(default: one per core) and the 500 TIMESTAMPs of a time sync, each sent once the previous reply
came, as PX4 sends them after a time jump. Printed: every run, then medians and ranges and the
ratio xrce-agent / MicroXRCEAgent.

``--px4-msgs DIR``: a px4_msgs checkout of the PX4 version captured. Only the types the capture
names (and the types they contain) are built, with xrce's interface builder, into its cache, and
registered for the subscriber only (a registry file of this run, activated in that process), never
in the venv. ``--agent-px4-msgs`` gives xrce-agent the same registry (the configuration before the
agent bridged types by name).
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from bench.common.figures import percentile, print_table, record  # noqa: E402
from bench.common.harness import PYTHON, Child, cpu_seconds  # noqa: E402
from bench.common.peer_agent import CommandAgent  # noqa: E402
from bench.common.procs import interrupt, read_until  # noqa: E402
from bench.px4.replay_load import Px4Capture, Px4Link  # noqa: E402

SETTLE_S = 3.0
SYNC_COUNT = 500  # PX4 needs this many round trips under 10 ms to finish connecting
FAST_RTT_US = 10000.0


# -- px4_msgs for the subscriber ------------------------------------------------------------------

def capture_types(path: str):
    """{"/fmu/out/x": "Type"} of the capture's writers, and every px4_msgs type it names."""
    with gzip.open(path, "rt") if path.endswith(".gz") else open(path) as lines:
        blobs = [bytes.fromhex(json.loads(line)["hex"]) for line in lines]
    outputs, types = {}, set()
    for blob in blobs:
        for match in re.finditer(rb"px4_msgs::(msg|srv)::dds_::(\w+?)_\x00", blob):
            kind, name = match.group(1).decode(), match.group(2).decode()
            types.add((kind, name.split("_")[0] if kind == "srv" else name))
        for match in re.finditer(rb"rt(/fmu/out/\w+)\x00", blob):
            after = re.search(rb"px4_msgs::msg::dds_::(\w+?)_\x00", blob[match.end():])
            if after:
                outputs[match.group(1).decode()] = after.group(1).decode()
    return outputs, types


def trimmed_px4_msgs(source: str, types, into: str) -> None:
    """A copy of the px4_msgs package at ``source`` with only ``types`` and the types they hold."""
    package = os.path.join(into, "px4_msgs")
    for sub in ("msg", "srv"):
        os.makedirs(os.path.join(package, sub))
    for name in ("package.xml", "CMakeLists.txt"):
        shutil.copy(os.path.join(source, name), package)
    wanted, seen = list(types), set()
    while wanted:
        kind, name = wanted.pop()
        if (kind, name) in seen:
            continue
        seen.add((kind, name))
        path = os.path.join(source, kind, name + "." + kind)
        shutil.copy(path, os.path.join(package, kind))
        with open(path) as text:
            for line in text:
                field = line.split("#")[0].split()
                if field and re.match(r"^(px4_msgs/)?[A-Z]\w*(\[\d*\])?$", field[0]):
                    inner = field[0].split("/")[-1].split("[")[0]
                    if os.path.exists(os.path.join(source, "msg", inner + ".msg")):
                        wanted.append(("msg", inner))


def build_subscriber_registry(source: str, capture: str, workdir: str) -> str:
    """Build the trimmed px4_msgs (a cache hit after the first time): a registry file for it."""
    from xrce.agent.interfaces.builder import build

    _outputs, types = capture_types(capture)
    tree = os.path.join(workdir, "src")
    trimmed_px4_msgs(source, types, tree)
    print("building px4_msgs (%d types the capture names, and what they hold) for the subscriber"
          % len(types), flush=True)
    results = build([tree], register_results=False)
    registry = os.path.join(workdir, "px4_msgs_registry.json")
    with open(registry, "w") as out:
        json.dump({r.name: {"prefix": r.prefix, "depends": list(r.depends)} for r in results}, out)
    return registry


SUBSCRIBER = r"""
import sys, threading
from xrce.agent.interfaces import registry
registry.activate_registry(sys.argv[1])
import importlib, rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy, DurabilityPolicy, HistoryPolicy
msg = importlib.import_module("px4_msgs.msg")
rclpy.init(args=[])
node = rclpy.create_node("px4_listener")
qos = QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                 history=HistoryPolicy.KEEP_LAST, depth=1)
counts = {}
def counter(topic):
    counts[topic] = 0
    def got(_message):
        counts[topic] += 1
    return got
for pair in sys.argv[2:]:
    topic, name = pair.split("=")
    node.create_subscription(getattr(msg, name), topic, counter(topic), qos)
executor = SingleThreadedExecutor()
executor.add_node(node)
threading.Thread(target=executor.spin, daemon=True).start()
print("ready", flush=True)
for line in sys.stdin:
    if line.strip() == "count":
        print(sum(counts.values()), flush=True)
    elif line.strip() == "quit":
        break
executor.shutdown()
node.destroy_node()
rclpy.shutdown()
"""


# -- the agents ----------------------------------------------------------------------------------

class XrceAgent:
    """This checkout's ``xrce-agent udp4 -p 0`` (CLI defaults), with px4_msgs registered in its
    process only when ``registry`` is given."""

    def __init__(self, env, registry=None):
        bootstrap = ("import runpy, sys\n"
                     "from xrce.agent.interfaces import registry\n"
                     "if sys.argv[1]: registry.activate_registry(sys.argv[1])\n"
                     "sys.argv[:2] = ['xrce-agent']\n"
                     "runpy.run_module('xrce.agent', run_name='__main__', alter_sys=True)\n")
        self.proc = subprocess.Popen([PYTHON, "-c", bootstrap, registry or "", "udp4", "-p", "0"],
                                     cwd=REPO, env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True)
        line, output = read_until(self.proc, lambda text: re.search(r"on port (\d+)", text), 60)
        if line is None:
            self.stop()
            raise RuntimeError("xrce-agent did not start: %s" % output[-2000:])
        self.port = int(re.search(r"on port (\d+)", line).group(1))
        self.pid = self.proc.pid
        self.output = []
        threading.Thread(target=lambda: self.output.extend(self.proc.stdout), daemon=True).start()

    def stop(self):
        interrupt(self.proc, 20)


# -- one run -------------------------------------------------------------------------------------

def hogs(count):
    return [subprocess.Popen([PYTHON, "-c", "while True: pass"]) for _ in range(count)]


def one_run(agent, capture, seconds, subscriber, load):
    """{"cpu": fraction of a core over the window, "samples": sent, "delivered": subscriber's
    count, "rtt": {label: [µs]}}."""
    link = Px4Link(agent.port)
    stop = threading.Event()
    try:
        link.connect(capture)
        sync_rtts = [v for label, v in link.rtts if label == "sync"]
        link.label = "streaming"
        total = SETTLE_S + seconds + 60.0
        streamer = threading.Thread(target=link.stream, args=(capture, total, stop))
        streamer.start()
        time.sleep(SETTLE_S)
        got_before = int(subscriber.ask("count")) if subscriber else 0
        cpu_before, started = cpu_seconds(agent.pid), time.monotonic()
        sent_before = link.samples_sent
        time.sleep(seconds)
        elapsed = time.monotonic() - started
        cpu = (cpu_seconds(agent.pid) - cpu_before) / elapsed
        rate = (link.samples_sent - sent_before) / elapsed
        delivered = int(subscriber.ask("count")) - got_before if subscriber else None
        busy = hogs(load)
        try:
            time.sleep(0.5)
            link.label = "loaded"
            answered = link.sync(_a_timestamp(capture), SYNC_COUNT)
        finally:
            for proc in busy:
                proc.kill()
                proc.wait()
        stop.set()
        streamer.join()
    finally:
        stop.set()
        link.close()
    rtts = {"sync": sync_rtts}
    for label in ("streaming", "loaded"):
        rtts[label] = [v for name, v in link.rtts if name == label]
    return {"cpu": cpu, "delivered": delivered, "answered_loaded": answered, "rtt": rtts,
            "rate": rate, "recorded_rate": capture.samples_per_lap / capture.lap_s}


def _a_timestamp(capture):
    return next(data for _t, kind, data in capture.streaming if kind == "timestamp")


def rtt_summary(values):
    if not values:
        return "none answered"
    fast = sum(1 for v in values if v < FAST_RTT_US)
    return "p50 %.0f p99 %.0f max %.0f us, %d/%d under 10 ms" % (
        percentile(values, 0.5), percentile(values, 0.99), max(values), fast, len(values))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agent-cmd", required=True,
                        help="eProsima's agent (it gets 'udp4 -p PORT'), e.g. $PEERS/agent.sh "
                             "(docs/PERFORMANCE.md)")
    parser.add_argument("--capture", default=str(REPO / "tests/golden/px4/px4_main.jsonl.gz"))
    parser.add_argument("--px4-msgs", metavar="DIR", help="px4_msgs source for the subscriber")
    parser.add_argument("--agent-px4-msgs", action="store_true",
                        help="register the same px4_msgs in xrce-agent's process too")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--load", type=int, default=os.cpu_count() or 2,
                        help="busy processes during the loaded time sync")
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--no-subscriber", action="store_true")
    group.add_argument("--only-subscriber", action="store_true")
    args = parser.parse_args(argv)
    if not args.no_subscriber and not args.px4_msgs:
        parser.error("the subscriber needs --px4-msgs DIR (or pass --no-subscriber)")
    if args.agent_px4_msgs and not args.px4_msgs:
        parser.error("--agent-px4-msgs needs --px4-msgs DIR")
    capture = Px4Capture(args.capture)
    outputs, _types = capture_types(args.capture)
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env.pop("ROS_DOMAIN_ID", None)  # PX4's participant is in domain 0: so is its ROS user
    workdir = tempfile.mkdtemp(prefix="xrce-px4-load-")
    try:
        registry = build_subscriber_registry(args.px4_msgs, args.capture, workdir) \
            if args.px4_msgs else None
        configs = ([] if args.only_subscriber else [False]) + ([] if args.no_subscriber else [True])
        agents = [("xrce-agent", lambda: XrceAgent(env, registry if args.agent_px4_msgs else None)),
                  ("MicroXRCEAgent", lambda: CommandAgent(args.agent_cmd, env))]
        results = {}
        for round_index in range(args.rounds):
            for with_sub in configs:
                order = agents if round_index % 2 == 0 else agents[::-1]
                for name, start in order:
                    subscriber = None
                    if with_sub:
                        subscriber = Child(["-c", SUBSCRIBER, registry] +
                                           ["%s=%s" % kv for kv in sorted(outputs.items())],
                                           env=env, ready="ready")
                    agent = start()
                    try:
                        run = one_run(agent, capture, args.seconds, subscriber, args.load)
                    finally:
                        agent.stop()
                        if subscriber:
                            subscriber.close()
                    results.setdefault((name, with_sub), []).append(run)
                    print("round %d %s, %s: CPU %.2f %% of a core (%.0f samples/s sent of %.0f recorded%s); "
                          "TIMESTAMP sync %s; streaming %s; loaded (%d busy) %s"
                          % (round_index + 1, name, "subscriber" if with_sub else "no subscriber",
                             100 * run["cpu"], run["rate"], run["recorded_rate"],
                             ", %d delivered to the subscriber (%.0f/s)"
                             % (run["delivered"], run["delivered"] / args.seconds)
                             if with_sub else "",
                             rtt_summary(run["rtt"]["sync"]), rtt_summary(run["rtt"]["streaming"]),
                             args.load, rtt_summary(run["rtt"]["loaded"])), flush=True)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    report(results, configs, args)
    print_table()
    return 0


def report(results, configs, args):
    median = lambda values: sorted(values)[len(values) // 2]  # noqa: E731
    for with_sub in configs:
        ours = [100 * r["cpu"] for r in results[("xrce-agent", with_sub)]]
        theirs = [100 * r["cpu"] for r in results[("MicroXRCEAgent", with_sub)]]
        ratios = sorted(a / b for a, b in zip(ours, theirs) if b)
        rates = [r["rate"] for name in ("xrce-agent", "MicroXRCEAgent")
                 for r in results[(name, with_sub)]]
        label = "with an rclpy subscriber on /fmu/out" if with_sub else "no subscriber"
        record("agent CPU at PX4's load, %s" % label, median(ours), "% core", median(theirs),
               "MicroXRCEAgent 2.4.3 (%s)" % args.agent_cmd, "<= 1.0x",
               "medians of %d rounds over %.0f s; xrce-agent %.2f-%.2f, MicroXRCEAgent %.2f-%.2f, "
               "per-round ratio %.2f-%.2f; samples sent %.0f-%.0f/s%s" % (
                   len(ours), args.seconds, min(ours), max(ours), min(theirs), max(theirs),
                   ratios[0], ratios[-1], min(rates), max(rates),
                   "; xrce-agent with px4_msgs" if args.agent_px4_msgs else
                   "; xrce-agent without px4_msgs"))
    for name in ("xrce-agent", "MicroXRCEAgent"):
        runs = [r for key, rs in results.items() if key[0] == name for r in rs]
        for label, what in (("sync", "time sync, idle"), ("streaming", "while streaming"),
                            ("loaded", "streaming, %d busy processes" % args.load)):
            values = [v for r in runs for v in r["rtt"][label]]
            if not values:
                continue
            fast = sum(1 for v in values if v < FAST_RTT_US)
            record("%s TIMESTAMP round trip p50, %s" % (name, what), percentile(values, 0.5), "us",
                   None, "-", "", rtt_summary(values))
            record("%s TIMESTAMP round trips under 10 ms, %s" % (name, what),
                   100.0 * fast / len(values), "%", None, "-", "100 %",
                   "p99 %.0f us, max %.0f us" % (percentile(values, 0.99), max(values)))


if __name__ == "__main__":
    sys.exit(main())
