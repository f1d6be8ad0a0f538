"""How long a job posted to a ROS domain's executor thread waits before it runs (post -> job).

    .venv/bin/python bench/agent/domain_wake.py [--jobs N] [--runs R]

The EventsExecutor is woken by one sample on a private wake topic of the agent's node
(xrce.agent.middleware.ros.wake). The figure is that wake-up as the agent has it (a DDS-level
topic, outside the ROS graph, transient local so that a wake-up survives the topic's move between
nodes); the baseline is the wake-up as the agent had it before (a volatile ROS topic, ``rt/``
prefix), measured in the same run. Each run is one fresh DomainRuntime in a
domain of its own (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST), N jobs posted one after another
(each after the previous one ran, so every post needs a wake-up); medians of R runs' p50/p99.
"""

import argparse
import os
import random
import statistics
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce

from bench.common.figures import percentile, print_table, record  # noqa: E402


def post_to_job_us(dds_level: bool, jobs: int) -> list:
    from xrce.agent.middleware.ros import domain as ros_domain
    from xrce.agent.middleware.ros import wake as ros_wake

    from rclpy.qos import DurabilityPolicy

    ros_wake.WAKE_DDS_LEVEL = dds_level
    ros_wake.WAKE_DURABILITY = DurabilityPolicy.TRANSIENT_LOCAL if dds_level else \
        DurabilityPolicy.VOLATILE
    runtime = ros_domain.DomainRuntime(random.randrange(150, 200), ros_domain.EXECUTOR_EVENTS)
    try:
        runtime.call(runtime.make_wake, 10.0)  # the agent node and its wake topic exist from here
        delays = []
        ran = threading.Event()
        posted = [0.0]

        def job():
            delays.append((time.perf_counter() - posted[0]) * 1e6)
            ran.set()

        for _ in range(jobs):
            ran.clear()
            time.sleep(0.001)  # the executor back asleep in rclpy: every post wakes it
            posted[0] = time.perf_counter()
            runtime.post(job)
            if not ran.wait(5.0):
                raise RuntimeError("a posted job did not run within 5 s")
        return delays
    finally:
        runtime.stop(10.0)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=2000)
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args(argv)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    results = {True: [], False: []}
    for _ in range(args.runs):
        for dds_level in (False, True):  # alternated: a load change hits both alike
            delays = post_to_job_us(dds_level, args.jobs)
            results[dds_level].append((percentile(delays, 0.5), percentile(delays, 0.99)))
    for index, name in ((0, "p50"), (1, "p99")):
        record("ROS domain post -> job %s, wake topic outside the ROS graph" % name,
               statistics.median(r[index] for r in results[True]), "us",
               statistics.median(r[index] for r in results[False]),
               "the former wake topic (volatile ROS topic)", "",
               "%d jobs, median of %d runs" % (args.jobs, args.runs))
    print_table()


if __name__ == "__main__":
    main()
