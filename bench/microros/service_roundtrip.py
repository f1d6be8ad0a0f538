"""Service round trip from ROS to a micro-ROS firmware's replier through the agent, beside another
agent (eProsima's MicroXRCEAgent, ``--agent-cmd``) in the same run, rounds interleaved.

    .venv/bin/python bench/microros/service_roundtrip.py [--rounds 3] [--calls 20] [--agent-cmd CMD] [--reference DIR]

Measure on a private loopback and /dev/shm, so no other DDS participant of the machine joins in:

    unshare -nm sh -c 'ip link set lo up && mount -t tmpfs tmpfs /dev/shm && \\
        .venv/bin/python bench/microros/service_roundtrip.py --agent-cmd $PEERS/agent.sh'

The firmware is the real one's set-up (tests/golden/microros/main.jsonl) replayed, then answering
as the firmware did in the recording (tests/helpers/firmware_replier.py). The ROS side is an rclpy ``example_interfaces/srv/AddTwoInts``
client in this process (a SingleThreadedExecutor on a thread of its own), as in the recording:
each call is timed from ``call_async`` to its future's callback, one call at a time, ``--calls``
of them per round after three warm-up calls, a fresh agent per round. Figure: the median of each
round's median, and the range of those.
"""

import os
import statistics
import struct
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from agent_process import AgentProcess  # noqa: E402
from firmware_replier import FirmwareReplier  # noqa: E402

from bench.common.figures import record  # noqa: E402
from bench.common.peer_agent import CommandAgent  # noqa: E402

INTERFACES = REPO / "tests" / "interfaces"


class RosClient:
    """rclpy AddTwoInts client, its executor spinning on a thread of its own."""

    def __init__(self, domain_id):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        from xrce.agent import interfaces

        interfaces.build([str(INTERFACES)], names=["example_interfaces"])
        from example_interfaces.srv import AddTwoInts

        self.srv = AddTwoInts
        self.context = Context()
        rclpy.init(args=[], context=self.context, domain_id=domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("service_roundtrip", context=self.context,
                                      start_parameter_services=False, enable_rosout=False)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        from rclpy.executors import ExternalShutdownException

        try:
            self.executor.spin()
        except ExternalShutdownException:
            pass

    def calls(self, count, firmware, warm_up=3, timeout_s=15.0):
        """(round trip, ROS -> firmware leg, firmware -> ROS leg) in ms of ``count`` calls to
        /add_two_ints on a new client (the legs from the firmware's receive and send times)."""
        client = self.node.create_client(self.srv, "/add_two_ints")
        try:
            deadline = time.monotonic() + timeout_s
            while not client.service_is_ready():
                if time.monotonic() > deadline:
                    raise RuntimeError("/add_two_ints never became ready")
                time.sleep(0.02)
            times = []
            index = 0
            lost = 0
            while len(times) < count:
                done = threading.Event()
                request = self.srv.Request(a=index, b=1000)
                start = time.perf_counter()
                future = client.call_async(request)
                future.add_done_callback(lambda _f: done.set())
                if not done.wait(2.0 if index < warm_up else timeout_s):
                    # A service is "ready" once its request reader is discovered; the reply
                    # may still be lost while its writer is being matched (ROS 2 services
                    # have no handshake). Only a warm-up call may be lost that way.
                    client.remove_pending_request(future)
                    lost += 1
                    if index >= warm_up or lost > 5:
                        raise RuntimeError("call %d got no reply" % index)
                    continue
                end = time.perf_counter()
                elapsed = end - start
                if future.result().sum != index + 1000:
                    raise RuntimeError("wrong sum %r" % future.result())
                if index >= warm_up:
                    times.append((1000 * elapsed,
                                  1000 * (firmware.requested_at[index] - start),
                                  1000 * (end - firmware.replied_at[index])))
                index += 1
                time.sleep(0.05)
            return times
        finally:
            self.node.destroy_client(client)

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()
        self._thread.join(2)


class ReferenceAgent:
    """This agent's CLI from another checkout (``--reference``): started as bench/agent/cost.py
    starts one, so that the other tree's code is the one imported (this venv's editable install
    imports its own checkout's xrce at start-up)."""

    def __init__(self, tree, env):
        self.tree = tree
        self.env = env
        self.agent = None
        self.port = None

    def __enter__(self):
        from bench.agent.cost import Agent

        self.agent = Agent(self.tree, self.env, "-m", "dds", "-v", "0", "--interfaces",
                           str(INTERFACES))
        self.port = self.agent.port
        return self

    def __exit__(self, *exc):
        self.agent.stop()


def one_round(start_agent, ros, domain_id, calls):
    with start_agent() as agent:
        firmware = FirmwareReplier(agent.port, domain_id)
        try:
            return ros.calls(calls, firmware)
        finally:
            firmware.close()


def main(argv=None):
    import argparse

    from bench.common.figures import print_table
    from ros_helpers import DomainLease

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--calls", type=int, default=20)
    parser.add_argument("--agent-cmd", metavar="CMD",
                        help="another agent (e.g. $PEERS/agent.sh, eProsima's agent built outside this repository), measured in the same run")
    parser.add_argument("--reference", metavar="DIR",
                        help="another checkout of xrce (e.g. main) whose agent is measured in the same run")
    args = parser.parse_args(argv)
    lease = DomainLease()
    domain_id = lease.domain_id
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    agents = [("xrce", lambda: AgentProcess("udp4", "-m", "dds", "-v", "0", "--interfaces",
                                            str(INTERFACES), env=env))]
    if args.reference:
        agents.append(("reference", lambda: ReferenceAgent(args.reference, env)))
    if args.agent_cmd:
        agents.append(("other", lambda: CommandAgent(args.agent_cmd, env)))
    ros = RosClient(domain_id)
    results = {name: [] for name, _ in agents}
    try:
        for round_ in range(args.rounds):
            for name, start in agents:
                times = one_round(start, ros, domain_id, args.calls)
                trips = [t[0] for t in times]
                results[name].append(statistics.median(trips))
                print("round %d %s: median %.3f ms (min %.3f, max %.3f); legs: ROS -> firmware "
                      "%.3f, firmware -> ROS %.3f" % (
                          round_ + 1, name, statistics.median(trips), min(trips), max(trips),
                          statistics.median(t[1] for t in times),
                          statistics.median(t[2] for t in times)), flush=True)
    finally:
        ros.close()
        lease.release()
    ours = results["xrce"]
    other = results.get("other")
    reference = results.get("reference")
    if reference:
        record("service round trip, this checkout against --reference",
               statistics.median(ours), "ms", statistics.median(reference), args.reference,
               "-", "round medians %s; reference %s" % (
                   ", ".join("%.3f" % v for v in ours), ", ".join("%.3f" % v for v in reference)))
    record("service round trip, ROS -> firmware replier -> ROS (median of %d rounds of %d calls)"
           % (args.rounds, args.calls), statistics.median(ours), "ms",
           statistics.median(other) if other else None,
           args.agent_cmd or "-", "<= 1.1x the other agent",
           "round medians %s%s" % (", ".join("%.3f" % v for v in ours),
                                   "; other %s" % ", ".join("%.3f" % v for v in other)
                                   if other else ""))
    print_table()
    return 0


if __name__ == "__main__":
    sys.exit(main())
