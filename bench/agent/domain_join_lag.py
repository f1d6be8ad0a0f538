"""How long the agent's loop is held up while a client joins a ROS domain the agent is not in.

    .venv/bin/python bench/agent/domain_join_lag.py [--joins N] [--runs R]

In-process ``RosMiddleware(park_creation=True)`` (the CLI's): a participant CREATE in a new domain
is parked while the domain's thread makes the context and the client's node, whose DDS participant
rmw makes with it. A ticker on the loop (every 0.5 ms) records its longest gap during each join:
the time every other client would have waited. The figure is the agent as it is (the participant
made with the GIL released through the compiled helper, ``xrce.agent.middleware.ros.participant``);
the baseline is the same agent with the participant made by rclpy's node, GIL held, in the same
run, alternating. Each run joins N fresh domains (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST);
medians over all joins of all runs, with the join's own duration beside.
"""

import argparse
import asyncio
import os
import random
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce

from bench.common.figures import print_table, record  # noqa: E402


async def joins(count: int, gil_free: bool, first_domain: int) -> list:
    """(join ms, the loop's longest gap ms) of ``count`` joins of fresh domains."""
    from xrce.agent.middleware import TypeNotReady
    from xrce.agent.middleware.ros import participant
    from xrce.agent.middleware.ros.ros_middleware import RosMiddleware

    participant._helper = None if gil_free else False  # looked up again, or the rclpy node's
    mw = RosMiddleware(park_creation=True)
    await mw.start()
    results = []
    try:
        for index in range(count):
            worst = [0.0]
            done = asyncio.Event()

            async def tick():
                last = time.perf_counter()
                while not done.is_set():
                    await asyncio.sleep(0.0005)
                    now = time.perf_counter()
                    worst[0] = max(worst[0], now - last)
                    last = now

            ticker = asyncio.ensure_future(tick())
            await asyncio.sleep(0.02)
            worst[0] = 0.0
            started = time.perf_counter()
            while True:
                try:
                    mw.create_participant((1, index), first_domain + index, "joins_%d" % index)
                    break
                except TypeNotReady as parked:
                    future = parked.future
                    await (future if isinstance(future, asyncio.Future)
                           else asyncio.wrap_future(future))
            took = time.perf_counter() - started
            done.set()
            await ticker
            results.append((took * 1000, worst[0] * 1000))
    finally:
        await mw.close()
    return results


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--joins", type=int, default=5)
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args(argv)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    results = {True: [], False: []}
    for _ in range(args.runs):
        for gil_free in (False, True):  # alternated: a load change hits both alike
            first = random.randrange(150, 220 - args.joins)
            results[gil_free] += asyncio.run(joins(args.joins, gil_free, first))
    for index, name in ((1, "the loop's longest gap during a join"), (0, "the join itself")):
        now = [r[index] for r in results[True]]
        before = [r[index] for r in results[False]]
        record("ROS domain join: %s" % name, statistics.median(now), "ms",
               statistics.median(before), "participant made by rclpy's node, GIL held", "",
               "%d joins; range %.1f-%.1f, baseline %.1f-%.1f"
               % (len(now), min(now), max(now), min(before), max(before)))
    print_table()


if __name__ == "__main__":
    main()
