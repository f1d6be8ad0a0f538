"""What a stranger's client costs the agent on the ROS side: ROS domains joined and left, and
service requests waiting for a server that never comes.

    .venv/bin/python bench/hostile/ros.py [--domains 20] [--requests 2000] [--reference DIR]

- "domains": one client creates a participant in each of ``--domains`` ROS domains (leased like the
  tests' domains, so no other run's graph is touched), then deletes them all; the agent's resident
  memory and threads before, at the peak and 3 s after the deletes (``/proc/<pid>/status``).
- "pending requests": one client sends ``--requests`` best-effort requests to a service nobody
  serves; the agent's CPU (utime + stime of all its threads) over the 5 s after they are in, well
  inside the 10 s the agent holds a request.

``--reference DIR`` runs the same against the agent of another source tree (e.g. ``git archive
main`` unpacked): the figures print side by side, the baseline measured in the same run.
"""

import argparse
import os
import re
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from ros_helpers import DomainLease  # noqa: E402

from bench.agent.cost import Agent, rss_mb  # noqa: E402
from bench.common.harness import cpu_seconds  # noqa: E402
from xrce.client.session import Session  # noqa: E402
from xrce.transports.udp import UdpTransport  # noqa: E402


class RawBasicTypes:
    TYPE_NAME_REQUEST = "test_msgs::srv::dds_::BasicTypes_Request_"
    TYPE_NAME_RESPONSE = "test_msgs::srv::dds_::BasicTypes_Response_"
    Request = None
    Response = None


def threads(pid):
    with open("/proc/%d/status" % pid) as status:
        return int(re.search(r"^Threads:\s+(\d+)", status.read(), re.M).group(1))


def domains_figure(tree, env, home, domain_ids):
    agent = Agent(tree, env, "-m", "dds")
    try:
        session = Session(UdpTransport("127.0.0.1", agent.port), history=16)
        try:
            assert session.create(attempts=5, timeout_ms=1000)
            session.create_participant(domain_id=home, name="home")
            assert session.run_until_all_status(5000), session.last_statuses
            time.sleep(1.0)
            before = (rss_mb(agent.pid), threads(agent.pid))
            nodes = []
            for i, domain_id in enumerate(domain_ids):
                nodes.append(session.create_participant(domain_id=domain_id, name="visitor%d" % i))
                assert session.run_until_all_status(20000), session.last_statuses
            time.sleep(1.0)
            peak = (rss_mb(agent.pid), threads(agent.pid))
            for node in nodes:
                session.delete_entity(node)
                assert session.run_until_all_status(20000), session.last_statuses
            time.sleep(3.0)
            after = (rss_mb(agent.pid), threads(agent.pid))
            session.delete(attempts=2, timeout_ms=500)
        finally:
            session.close()
    finally:
        agent.stop()
    return before, peak, after


def pending_figure(tree, env, home, count):
    from rclpy.serialization import serialize_message
    from test_msgs.srv import BasicTypes

    agent = Agent(tree, env, "-m", "dds")
    try:
        session = Session(UdpTransport("127.0.0.1", agent.port), history=16)
        try:
            assert session.create(attempts=5, timeout_ms=1000)
            node = session.create_participant(domain_id=home, name="asker")
            requester = session.create_service_client(node, "/nobody_serves_this", RawBasicTypes,
                                                      lambda request_id, reply: None)
            assert session.run_until_all_status(5000), session.last_statuses
            body = serialize_message(BasicTypes.Request(int32_value=1))[4:]
            for i in range(count):
                session.send_request(requester, body, stream_id=session.best_effort)
                session.flush()
                if i % 50 == 49:
                    time.sleep(0.005)
            assert session.ping(timeout_ms=2000)
            time.sleep(0.5)
            before, start = cpu_seconds(agent.pid), time.monotonic()
            time.sleep(5.0)
            share = (cpu_seconds(agent.pid) - before) / (time.monotonic() - start)
            session.delete(attempts=2, timeout_ms=500)
        finally:
            session.close()
    finally:
        agent.stop()
    return share


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--domains", type=int, default=20)
    parser.add_argument("--requests", type=int, default=2000)
    parser.add_argument("--reference", metavar="DIR")
    args = parser.parse_args(argv)
    leases = [DomainLease() for _ in range(args.domains + 1)]
    env = dict(os.environ, ROS_DOMAIN_ID=str(leases[0].domain_id),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    trees = [("this tree", str(REPO))] + ([("reference", args.reference)] if args.reference else [])
    try:
        for label, tree in trees:
            before, peak, after = domains_figure(tree, env, leases[0].domain_id,
                                                 [lease.domain_id for lease in leases[1:]])
            print("%-10s %d domains joined and left: RSS %.1f -> %.1f -> %.1f MB, threads %d -> %d "
                  "-> %d" % (label, args.domains, before[0], peak[0], after[0], before[1], peak[1],
                             after[1]), flush=True)
        for label, tree in trees:
            share = pending_figure(tree, env, leases[0].domain_id, args.requests)
            print("%-10s %d requests waiting for a server: agent CPU %.1f %% of a core"
                  % (label, args.requests, share * 100), flush=True)
    finally:
        for lease in leases:
            lease.release()
    return 0


if __name__ == "__main__":
    sys.exit(main())
