"""Does the compiled UDP receive path pay? Best-effort CPU per message, compiled vs Python, same run.

    .venv/bin/python bench/agent/fastpath_cost.py [--runs N] [--seconds S] [--reference DIR] [--robot]

Starts this checkout's agent with the compiled path (default) and with ``XRCE_FASTPATH=0`` (the
pure Python path it falls back to), and optionally the agent of another source tree, one after the
other in each round, and offers bench/agent/xrce_flood.py's best-effort Twist flood at 5k, 20k and 50k
msg/s into a raw EventsExecutor subscriber, exactly as bench/agent/cost.py does (same functions).
``--robot`` adds the TurtleBot3 load (CPU, RSS). Prints every round and the medians.
"""

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from bench.agent.cost import IDLE_SECONDS, SETTLE_SECONDS, Agent, offered_load, robot_load  # noqa: E402
from bench.common.harness import Child  # noqa: E402

RATES = (5000, 20000, 50000)


def measure(tree, env, domain_id, sink, seconds, robot):
    out = {}
    agent = Agent(tree, env)
    try:
        time.sleep(SETTLE_SECONDS)
        for rate in RATES:
            per, fraction, _offered, _count, _sent = offered_load(
                agent, sink, env, domain_id, False, rate, seconds)
            out[rate] = (per, fraction)
    finally:
        agent.stop()
    if robot:
        agent = Agent(tree, env)
        try:
            cpu, rss, _threads = robot_load(agent, env, domain_id, IDLE_SECONDS)
            out["robot"] = (100 * cpu, rss)
        finally:
            agent.stop()
    return out


def main(argv=None):
    from ros_helpers import DomainLease

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=2)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--reference", metavar="DIR")
    parser.add_argument("--robot", action="store_true")
    args = parser.parse_args(argv)
    lease = DomainLease()
    env = dict(os.environ, ROS_DOMAIN_ID=str(lease.domain_id),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    variants = [("compiled", str(REPO), dict(env, XRCE_FASTPATH="1")),
                ("python", str(REPO), dict(env, XRCE_FASTPATH="0"))]
    if args.reference:
        variants.append(("reference", args.reference, env))
    results = {name: [] for name, _, _ in variants}
    sink = Child(["bench/common/ros_peer.py"], env=env, ready="ready")
    try:
        for run in range(args.runs):
            for name, tree, variant_env in variants:
                out = measure(tree, variant_env, lease.domain_id, sink, args.seconds, args.robot)
                results[name].append(out)
                print("run %d %-9s " % (run + 1, name) + "  ".join(
                    "%dk %.1f us/msg (%.1f %%)" % (rate // 1000, out[rate][0] or 0,
                                                   100 * out[rate][1]) for rate in RATES)
                    + ("  robot %.2f %% %.1f MB" % out["robot"] if "robot" in out else ""),
                    flush=True)
    finally:
        sink.close()
        lease.release()
    print()
    for name, runs in results.items():
        cells = []
        for rate in RATES:
            per = statistics.median(r[rate][0] or 0 for r in runs)
            delivered = statistics.median(100 * r[rate][1] for r in runs)
            cells.append("%dk %.1f us/msg (%.1f %% delivered)" % (rate // 1000, per, delivered))
        if args.robot:
            cells.append("robot %.2f %% CPU, %.1f MB" % (
                statistics.median(r["robot"][0] for r in runs),
                statistics.median(r["robot"][1] for r in runs)))
        print("median of %d, %-9s: %s" % (len(runs), name, "; ".join(cells)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
