"""Where best-effort samples from one client go missing on their way to ROS, stage by stage, beside
another agent (eProsima's MicroXRCEAgent) on the same offered load.

    .venv/bin/python bench/agent/best_effort_loss.py [--agent-cmd $PEERS/agent.sh] [--rate 5000]
        [--seconds 5] [--rounds 2]

bench/agent/xrce_flood.py offers Twist samples best effort (one datagram each, a C client's cost)
at ``--rate`` into an rclpy subscriber (bench/common/ros_peer.py, best effort, raw, EventsExecutor).
For each agent, per round:

- ``sent``: datagrams the client's send() took;
- ``socket``: what the kernel dropped at the agent's UDP socket (``/proc/net/udp``'s drops of its
  port: a receive buffer that was full);
- ``agent in``, ``agent drops``: this agent's own counters (its stats port): messages its link
  took, and what it dropped itself (the hand-off of its receive thread, stale sequence numbers,
  rcl's refusals to publish); the other agent has none;
- ``ROS``: what the subscriber got. What the agent took and published but ROS never saw was lost
  between the two DDS participants (their shared memory or UDP transport, the subscriber's
  history).

Run it in a network namespace of its own with a private /dev/shm (docs/PERFORMANCE.md, "Loss at
5,000 samples a second"): ``unshare -nm sh -c 'ip link set lo up && mount -t tmpfs tmpfs /dev/shm
&& .venv/bin/python bench/agent/best_effort_loss.py --agent-cmd $PEERS/agent.sh'``.
"""

import argparse
import json
import os
import re
import socket
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from bench.common import figures  # noqa: E402
from bench.common.harness import Child  # noqa: E402
from bench.common.peer_agent import CommandAgent  # noqa: E402
from agent_process import AgentProcess  # noqa: E402

DRAIN_SECONDS = 1.0


def socket_drops(port):
    """The kernel's drop count of the UDP socket bound to ``port`` (IPv4 or IPv6), or None."""
    total = None
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            rows = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            fields = row.split()
            if len(fields) > 12 and int(fields[1].split(":")[1], 16) == port:
                total = (total or 0) + int(fields[-1])
    return total


def agent_stats(stats_port):
    with socket.create_connection(("127.0.0.1", stats_port), timeout=5) as sock:
        data = b""
        while True:
            chunk = sock.recv(65536)
            if not chunk:
                break
            data += chunk
    return json.loads(data)


class OurAgent:
    def __init__(self, env):
        self.process = AgentProcess("udp4", "--stats-port", "0", env=env, cwd=REPO).__enter__()
        self.port = self.process.port
        self.stats_port = int(re.search(r"stats on [\d.]+:(\d+)", self.process.banner).group(1))

    def counters(self):
        snapshot = agent_stats(self.stats_port)
        agent, link = snapshot["agent"], snapshot["links"][0]
        return {"in": link["messages_in"], "samples": agent["samples_in"],
                "drops": link["drops"] + agent["dropped"] + agent.get("publish_errors", 0)}

    def stop(self):
        self.process.stop()


class TheirAgent(CommandAgent):
    def counters(self):
        return None


def one_run(agent, env, rate, seconds, label, index):
    sink = Child(["bench/common/ros_peer.py"], env=env, ready="ready")
    topic = "/loss_%s_%d" % (label.replace("-", "_"), index)
    flood = None
    try:
        sink.ask("sub %s be" % topic)
        flood = Child(["bench/agent/xrce_flood.py", "--port", str(agent.port), "--topic", topic,
                       "--key", hex(0x20000000 + index)], env=env, ready="ready")
        deadline = time.monotonic() + 30
        while sink.ask("publishers %s" % topic) == "0" and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(0.5)
        before_drops = socket_drops(agent.port) or 0
        before = agent.counters()
        sent, _elapsed = flood.ask("go %d %.1f" % (rate, seconds), timeout=seconds + 60).split()
        time.sleep(DRAIN_SECONDS)
        after = agent.counters()
        dropped = (socket_drops(agent.port) or 0) - before_drops
        got = int(sink.ask("count %s" % topic).split()[0])
    finally:
        if flood is not None:
            flood.close()
        sink.close()
    row = {"sent": int(sent), "socket": dropped, "ros": got}
    if before is not None:
        row.update({key: after[key] - before[key] for key in after})
    return row


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agent-cmd", help="the other agent, e.g. $PEERS/agent.sh")
    parser.add_argument("--rate", type=int, default=5000)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    env = dict(os.environ)
    labels = ["xrce-agent"] + (["other"] if args.agent_cmd else [])
    rows = {label: [] for label in labels}
    for index in range(args.rounds):
        for label in labels:
            agent = OurAgent(env) if label == "xrce-agent" else TheirAgent(args.agent_cmd, env)
            try:
                row = one_run(agent, env, args.rate, args.seconds, label, index)
            finally:
                agent.stop()
            rows[label].append(row)
            print("round %d %-10s sent %6d  socket drops %5d  agent in %6s  samples %6s  agent "
                  "drops %5s  ROS %6d (%.2f %%)" % (
                      index + 1, label, row["sent"], row["socket"], row.get("in", "-"),
                      row.get("samples", "-"), row.get("drops", "-"), row["ros"],
                      100.0 * row["ros"] / max(row["sent"], 1)), flush=True)
    delivered = {label: sum(r["ros"] for r in rows[label]) / max(sum(r["sent"] for r in rows[label]), 1)
                 for label in labels}
    figures.record("best-effort samples reaching ROS at %d/s" % args.rate,
                   100 * delivered["xrce-agent"], "%",
                   100 * delivered["other"] if "other" in delivered else None,
                   "other agent" if "other" in delivered else "-", ">= 99.9 %",
                   "%d rounds of %.0f s" % (args.rounds, args.seconds))
    figures.print_table()


if __name__ == "__main__":
    main()
