"""Agent CPU with PX4 SITL streaming to an rclpy subscriber, xrce-agent beside eProsima's
MicroXRCEAgent in the same run, in alternating rounds with windows long enough to count.

    unshare -nm sh -c 'mount -t tmpfs tmpfs /dev/shm && mount -t tmpfs tmpfs /tmp && \\
        ip link set lo up && exec .venv/bin/python bench/px4/sitl_cpu.py \\
        --px4-build $PX4W/PX4-Autopilot/build/px4_sitl_default --px4-msgs DIR \\
        --agent-cmd $PEERS/agent.sh [--rounds 6] [--seconds 60]'

bench/px4/sitl.py checks every row of issue #37's table, but its CPU figure is 10 s of an agent at
~4 % of a core (0.4 s of CPU, clock ticks of 10 ms) taken while the node's subscriptions are still
being matched: the rounds scatter by ±30 % for both agents. Here each round starts one agent and
PX4 instance 0 (SIH quadrotor, headless), waits for PX4's time sync and its writers in the ROS
graph, subscribes to every ``/fmu/out`` topic (best effort, as px4_ros_com's listener), and reads
the agent's user + system time (all threads, /proc) over three spans: from its start until PX4 is
connected (CPU seconds: the agent's own start-up, an interpreter and rclpy for xrce-agent, and
PX4's CREATEs), the ``MATCHING_S`` after the node subscribed, and then ``--seconds`` of streaming
(the row of issue #37), with the samples the subscriber received; then stops both and does the same with
the other agent. The order alternates between rounds so that a drift of the machine's load falls
on both. Printed: every round, with each agent's busiest threads over the window (CPU and context
switches a second, threads of one name summed: Python's threads all show as ``python``), then the
medians, the ratio of the medians and the per-round ratios. The agent never sees px4_msgs (checked, as in bench/px4/sitl.py): it bridges PX4's types
by name.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce

from bench.common.figures import print_table, record  # noqa: E402
from bench.px4.sitl import (SYNCED, Agent, Node, Px4, add_px4_arguments,  # noqa: E402
                            agent_can_import_px4_msgs, check_px4_arguments, cpu_seconds, log,
                            px4_msgs_for_this_process, wait_for)

# The first seconds after the node subscribes: its 24 readers matched with the agent's writers
# (discovery, and the graph the agent watches for mismatches), reported on their own.
MATCHING_S = 10.0
OURS = "xrce-agent"
THEIRS = "MicroXRCEAgent"


def threads(pid: int) -> dict:
    """CPU seconds and context switches of each of a process's threads, summed by thread name."""
    found = {}
    tick = os.sysconf("SC_CLK_TCK")
    for task in Path("/proc/%d/task" % pid).iterdir():
        try:
            stat = (task / "stat").read_text()
            status = (task / "status").read_text()
        except OSError:  # the thread ended meanwhile
            continue
        name, fields = stat.split("(", 1)[1].rsplit(")", 1)
        fields = fields.split()
        switches = sum(int(line.split()[1]) for line in status.splitlines()
                       if "ctxt_switches:" in line)
        cpu, count = found.get(name, (0.0, 0))
        found[name] = (cpu + (int(fields[11]) + int(fields[12])) / tick, count + switches)
    return found


def busiest(before: dict, after: dict, seconds: float, top: int = 4) -> str:
    """The threads that took most CPU between two ``threads`` readings, with their wake-ups."""
    rows = []
    for name, (cpu, switches) in after.items():
        cpu0, switches0 = before.get(name, (0.0, 0))
        rows.append((100 * (cpu - cpu0) / seconds, (switches - switches0) / seconds, name))
    rows.sort(reverse=True)
    return ", ".join("%s %.2f %% %.0f sw/s" % (name, cpu, rate) for cpu, rate, name in rows[:top])


def one_round(args, workdir: Path, node: Node, command) -> dict:
    """One agent with PX4 streaming: its CPU share and the samples the node received per second."""
    workdir.mkdir(parents=True)
    agent = Agent(command, workdir / "agent.log")
    px4 = Px4(args.px4_build, 0, workdir / "px4_0")
    try:
        agent.start()
        px4.start()
        if not wait_for(lambda: px4.said(SYNCED), 90):
            raise RuntimeError("PX4 did not synchronize its time with %s" % (command or OURS))
        if not wait_for(lambda: len(node.topics("/fmu/out/")) >= 20, 60, 0.5):
            raise RuntimeError("PX4's writers did not reach the ROS graph through %s"
                               % (command or OURS))
        time.sleep(2)  # the rest of the graph
        connected = cpu_seconds(agent.proc.pid)
        subscribed_at = time.monotonic()
        node.subscribe_all("/fmu/out/")
        time.sleep(MATCHING_S)
        received0 = sum(node.count(topic) for topic in node.arrivals)
        cpu0, t0, threads0 = cpu_seconds(agent.proc.pid), time.monotonic(), threads(agent.proc.pid)
        time.sleep(args.seconds)
        cpu1, t1, threads1 = cpu_seconds(agent.proc.pid), time.monotonic(), threads(agent.proc.pid)
        received1 = sum(node.count(topic) for topic in node.arrivals)
        if agent.proc.poll() is not None:
            raise RuntimeError("the agent exited during the window: see %s" % agent.log_path)
        return {"cpu": 100 * (cpu1 - cpu0) / (t1 - t0), "rate": (received1 - received0) / (t1 - t0),
                "connect": connected, "matching": 100 * (cpu0 - connected) / (t0 - subscribed_at),
                "threads": busiest(threads0, threads1, t1 - t0)}
    finally:
        node.unsubscribe_all()
        px4.stop()
        agent.stop()
        shutil.rmtree(workdir, ignore_errors=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_px4_arguments(parser)
    parser.add_argument("--agent-cmd", required=True,
                        help="eProsima's agent, run as CMD udp4 -p 8888 (e.g. $PEERS/agent.sh)")
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--seconds", type=float, default=60.0, help="CPU window per agent and round")
    args = parser.parse_args(argv)
    check_px4_arguments(parser, args)
    if args.rounds < 1 or args.seconds <= 0:
        parser.error("--rounds and --seconds must be positive")
    if agent_can_import_px4_msgs(None):
        parser.error("this interpreter can import px4_msgs: the agent would not bridge by name")

    workdir = Path(tempfile.mkdtemp(prefix="px4-sitl-cpu-"))
    results = {OURS: [], THEIRS: []}
    try:
        px4_msgs_for_this_process(args.px4_msgs, str(workdir))
        node = Node()
        try:
            for index in range(args.rounds):
                order = [(OURS, None), (THEIRS, args.agent_cmd)]
                if index % 2:
                    order.reverse()
                for name, command in order:
                    log("round %d/%d: %s" % (index + 1, args.rounds, name))
                    run = one_round(args, workdir / ("%s_%d" % (name, index)), node, command)
                    results[name].append(run)
                ours, theirs = results[OURS][-1], results[THEIRS][-1]
                print("round %d: streaming %s %.2f %% of a core (%.0f samples/s received), %s "
                      "%.2f %% (%.0f/s): ratio %.2f; matching %.1f %% / %.1f %%; start and connect "
                      "%.2f s / %.2f s of CPU" % (
                          index + 1, OURS, ours["cpu"], ours["rate"], THEIRS, theirs["cpu"],
                          theirs["rate"], ours["cpu"] / theirs["cpu"], ours["matching"],
                          theirs["matching"], ours["connect"], theirs["connect"]), flush=True)
                for name in (OURS, THEIRS):
                    print("  %s threads: %s" % (name, results[name][-1]["threads"]), flush=True)
        finally:
            node.close()
    finally:
        shutil.rmtree(workdir, ignore_errors=True)

    ours = [run["cpu"] for run in results[OURS]]
    theirs = [run["cpu"] for run in results[THEIRS]]
    ratios = sorted(a / b for a, b in zip(ours, theirs))
    rates = [run["rate"] for runs in results.values() for run in runs]
    record("agent CPU, PX4 SITL streaming to an rclpy subscriber", statistics.median(ours),
           "% core", statistics.median(theirs), "MicroXRCEAgent (%s)" % args.agent_cmd, "<= 1.0x",
           "medians of %d rounds over %.0f s; xrce-agent %.2f-%.2f, MicroXRCEAgent %.2f-%.2f; "
           "per-round ratio median %.2f (%.2f-%.2f); samples received %.0f-%.0f/s" % (
               len(ours), args.seconds, min(ours), max(ours), min(theirs), max(theirs),
               statistics.median(ratios), ratios[0], ratios[-1], min(rates), max(rates)))
    for what, unit, label in (("matching", "% core", "the %.0f s after an rclpy node subscribed "
                                                       "to PX4's /fmu/out topics" % MATCHING_S),
                              ("connect", "s CPU", "from the agent's start until PX4 is connected")):
        mine = [run[what] for run in results[OURS]]
        other = [run[what] for run in results[THEIRS]]
        record("agent CPU, %s" % label, statistics.median(mine), unit, statistics.median(other),
               "MicroXRCEAgent (%s)" % args.agent_cmd, "-", "medians of %d rounds; xrce-agent "
               "%.2f-%.2f, MicroXRCEAgent %.2f-%.2f" % (len(mine), min(mine), max(mine),
                                                        min(other), max(other)))
    print_table()
    return 0


if __name__ == "__main__":
    sys.exit(main())
