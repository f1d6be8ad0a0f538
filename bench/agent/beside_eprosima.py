"""This agent beside another one (eProsima's MicroXRCEAgent) at rest and at a robot's rates, every
row from one run, rounds interleaved.

    .venv/bin/python bench/agent/beside_eprosima.py --agent-cmd $PEERS/agent.sh [--rounds 3]
        [--reference DIR] [--rows idle,10hz,10hz-in,robot,service,creation] [--no-state-too]

Each round starts every agent afresh, in turn (this checkout's, then ``--reference DIR``'s if
given, then this checkout's with ``--no-state`` if ``--no-state-too``: what its state store costs,
then ``--agent-cmd``'s), and measures on each, from ``/proc/<pid>/stat``:

- ``idle``: the agent alone, no client, CPU over 30 s after a 20 s start;
- ``10hz``: one client writing a best-effort Twist at 10 Hz, CPU over 10 s once 5 s have passed
  since its participant (whose DDS discovery is a cost of joining, not of the rate);
- ``10hz-in``: one client reading a best-effort Twist that an rclpy publisher sends at 10 Hz,
  likewise;
- ``robot``: the simulated TurtleBot3 of ``xrce-agent demo`` (5 topics out, reliable cmd_vel at
  30 Hz in) with its ROS side, as ``bench/agent/cost.py --robot-only`` runs it.

``service`` and ``creation`` run ``bench/microros/service_roundtrip.py`` and ``bench/microros/entity_creation.py``
with the same agents (their own interleaved rounds) and print their rows here. The table gives
medians of the rounds with their ranges, and the ratio to the other agent. Run it in a network
namespace of its own with a private /dev/shm (docs/PERFORMANCE.md), so no other DDS participant
joins in.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from bench.agent.cost import Agent, OtherAgent, robot_load  # noqa: E402
from bench.common.harness import PYTHON, Child, cpu_seconds  # noqa: E402

ROWS = ("idle", "10hz", "10hz-in", "robot", "service", "creation")
IDLE_START_S = 20.0
IDLE_WINDOW_S = 30.0
RATE_WINDOW_S = 10.0
SETTLE_AFTER_JOIN_S = 5.0


def client_10hz(agent, domain_id, reading: bool, env) -> float:
    """CPU fraction of ``agent`` while one client writes (or reads) a best-effort Twist at 10 Hz."""
    from xrce.client.entities import create_reader
    from xrce.client.session import Session
    from xrce.msgs.geometry_msgs import Twist
    from xrce.transports.udp import UdpTransport

    session = Session(UdpTransport("127.0.0.1", agent.port), key=b"\x0c\x05\x70\x02", history=16)
    ros = Child(["bench/common/ros_peer.py"], env=env, ready="ready") if reading else None
    try:
        if not session.create(attempts=5, timeout_ms=2000):
            raise RuntimeError("no session")
        node = session.create_participant(domain_id=domain_id, name="beside_10hz")
        if reading:
            got = []
            create_reader(session, node, "/beside_10hz_in", Twist, got.append, reliable=False)
            session.run_until_all_status(5000)
            count = int((RATE_WINDOW_S + SETTLE_AFTER_JOIN_S + 3) * 10)
            driver = threading.Thread(target=lambda: ros.ask(
                "stamped /beside_10hz_in be %d 10" % count, timeout=count / 10 + 30))
            driver.start()
            deadline = time.monotonic() + SETTLE_AFTER_JOIN_S
            while time.monotonic() < deadline:
                session.spin_once(100)
            if not got:
                raise RuntimeError("the client read nothing at 10 Hz")
            before, start = cpu_seconds(agent.pid), time.monotonic()
            while time.monotonic() - start < RATE_WINDOW_S:
                session.spin_once(100)
            cpu = (cpu_seconds(agent.pid) - before) / (time.monotonic() - start)
            driver.join()
            return cpu
        writer = session.create_writer(node, "/beside_10hz", Twist, reliable=False)
        session.run_until_all_status(5000)
        sample = Twist()
        # The first seconds after a client's participant are its domain's (the DDS
        # participant's discovery, for either agent): the window is the steady state after.
        start = time.monotonic()
        before = None
        for index in range(int((SETTLE_AFTER_JOIN_S + RATE_WINDOW_S) * 10)):
            time.sleep(max(0.0, start + index / 10.0 - time.monotonic()))
            if index == int(SETTLE_AFTER_JOIN_S * 10):
                before, window = cpu_seconds(agent.pid), time.monotonic()
            session.write(writer, sample, stream_id=session.best_effort)
            session.flush()
        return (cpu_seconds(agent.pid) - before) / (time.monotonic() - window)
    finally:
        session.delete(attempts=2, timeout_ms=500)
        session.close()
        if ros is not None:
            ros.close()


def idle(agent) -> float:
    time.sleep(IDLE_START_S)
    return agent.cpu_over(IDLE_WINDOW_S)


def run_rounds(rows, agents, rounds, env, domain_id):
    """{row: {label: [per-round values]}} for the rows measured here, agents taking turns."""
    results = {row: {label: [] for label, _ in agents} for row in rows}
    for number in range(1, rounds + 1):
        for label, start in agents:
            for row in rows:
                agent = start()
                try:
                    if row == "idle":
                        value = 100 * idle(agent)
                    elif row in ("10hz", "10hz-in"):
                        value = 100 * client_10hz(agent, domain_id, row == "10hz-in", env)
                    else:
                        value = 100 * robot_load(agent, env, domain_id, RATE_WINDOW_S)[0]
                finally:
                    agent.stop()
                results[row][label].append(value)
                print("round %d %-9s %-8s %.3f %% of a core (load average %s)"
                      % (number, label, row, value, os.getloadavg()[0]), flush=True)
    return results


def delegated(script, args, agent_cmd, reference):
    """The JSON rows another bench script prints for the same agents."""
    command = [PYTHON, script, *args, "--agent-cmd", agent_cmd]
    if reference:
        command += ["--reference", reference]
    print("running", " ".join(command), flush=True)
    out = subprocess.run(command, capture_output=True, text=True, cwd=REPO).stdout
    sys.stdout.write(out)
    return [json.loads(line) for line in out.splitlines() if line.startswith("{")]



def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--agent-cmd", metavar="CMD", required=True,
                        help="the other agent's command line (it gets 'udp4 -p PORT'), e.g. "
                             "$PEERS/agent.sh, eProsima's agent built outside this repository")
    parser.add_argument("--reference", metavar="DIR", help="another checkout of xrce as well")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--no-state-too", action="store_true",
                        help="also this checkout's agent without its state store (--no-state)")
    parser.add_argument("--rows", default=",".join(ROWS),
                        help="comma-separated, of: %s" % ", ".join(ROWS))
    args = parser.parse_args(argv)
    rows = [row for row in args.rows.split(",") if row]
    unknown = [row for row in rows if row not in ROWS]
    if unknown or args.rounds < 1:
        parser.error("unknown row %s (rows: %s)" % (", ".join(unknown), ", ".join(ROWS))
                     if unknown else "--rounds must be at least 1")
    from ros_helpers import DomainLease

    lease = DomainLease()
    domain_id = lease.domain_id
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    try:
        table = measure(args, rows, env, domain_id)
    finally:
        lease.release()
    print()
    print("| row | xrce | other agent | xrce / other |")
    print("|---|---|---|---|")
    for name, median, spread, ratio in table:
        print("| %s | %.3f (%s) | %.3f (%s) | %s |" % (
            name, median["xrce"], spread["xrce"], median["other"], spread["other"],
            "-" if ratio is None else "%.2f" % ratio))
        for label, words in (("reference", "reference checkout"), ("no-state", "xrce --no-state")):
            if label in median:
                print("|   %s | %.3f (%s) | | |" % (words, median[label], spread[label]))
    return 0


def measure(args, rows, env, domain_id):
    agents = [("xrce", lambda: Agent(str(REPO), env))]
    if args.reference:
        agents.append(("reference", lambda: Agent(args.reference, env)))
    if args.no_state_too:
        agents.append(("no-state", lambda: Agent(str(REPO), env, "--no-state")))
    agents.append(("other", lambda: OtherAgent(args.agent_cmd, env)))
    here = [row for row in rows if row not in ("service", "creation")]
    results = run_rounds(here, agents, args.rounds, env, domain_id)
    table = []
    for row in here:
        values = results[row]
        median = {label: statistics.median(v) for label, v in values.items()}
        spread = {label: "%.2f-%.2f" % (min(v), max(v)) for label, v in values.items()}
        other = median["other"]
        table.append((row + " (% of a core)", median, spread,
                      median["xrce"] / other if other else float("inf")))
    if "service" in rows:
        for record in delegated("bench/microros/service_roundtrip.py", ["--rounds", str(args.rounds)],
                                args.agent_cmd, args.reference):
            if record.get("baseline"):
                table.append((record["name"], {"xrce": record["value"], "other": record["baseline"]},
                              {"xrce": record.get("note", ""), "other": ""}, record.get("ratio")))
    if "creation" in rows:
        for record in delegated("bench/microros/entity_creation.py", ["--runs", str(max(3, args.rounds))],
                                args.agent_cmd, args.reference):
            if record.get("baseline"):
                table.append((record["name"], {"xrce": record["value"], "other": record["baseline"]},
                              {"xrce": record.get("note", ""), "other": ""}, record.get("ratio")))
    return table


if __name__ == "__main__":
    sys.exit(main())
