"""ACKNACKs and HEARTBEATs this agent sends per reliable message, beside another agent (eProsima's
MicroXRCEAgent) on the same traffic, every row from one run.

    .venv/bin/python bench/agent/acknack_counts.py --agent-cmd $PEERS/agent.sh
        [--middleware ced|dds] [--samples 2000] [--rounds 2]

Each round starts both agents afresh, in turn, and puts a counting UDP relay between the client
and each: what the client sends on its reliable stream (messages, retransmissions included) and
what the agent sends back on stream 0 (ACKNACK, HEARTBEAT submessages) are counted per phase:

- ``creations``: a participant and 15 topics, each CREATE sent the moment the last STATUS came,
  from this repository's client with a history of 8 (and, where XRCE_EPROSIMA_CLIENT names
  eProsima's client library and a compiler is there, the same from eProsima's client:
  ``creations (C)``);
- ``writes``: ``--samples`` reliable std_msgs/String samples written back to back (the client
  waits only when its history of 8 is full), until all are acknowledged.

eProsima's agent sends one ACKNACK per reliable message it receives (its Processor), so per
message it is 1.0; this agent should be no higher. ``-m dds`` runs the agents' Fast DDS sides
(this agent's compiled receive path takes the reliable samples); run it in a network namespace
of its own with a private /dev/shm (docs/PERFORMANCE.md).
"""

import argparse
import os
import select
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from bench.agent.cost import Agent  # noqa: E402
from bench.common import figures  # noqa: E402
from bench.common.peer_agent import CommandAgent  # noqa: E402
from xrce.wire import constants as C  # noqa: E402

sys.path.insert(0, str(REPO / "tests" / "eprosima"))
HISTORY = 8
TOPICS = 15


class CountingRelay(threading.Thread):
    """127.0.0.1:port <-> the agent, one client; counts per phase (``phase`` set by the caller)."""

    def __init__(self, agent_port):
        super().__init__(daemon=True)
        self.front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.front.bind(("127.0.0.1", 0))
        self.port = self.front.getsockname()[1]
        self.back = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.back.connect(("127.0.0.1", agent_port))
        self.phase = None
        self.counts = {}
        self.client = None
        self.stopping = False
        self.start()

    def _count(self, what, n=1):
        if self.phase is not None:
            row = self.counts.setdefault(self.phase, {"reliable": 0, "acknack": 0, "heartbeat": 0})
            row[what] += n

    def run(self):
        while not self.stopping:
            ready, _, _ = select.select([self.front, self.back], [], [], 0.05)
            for sock in ready:
                try:
                    data, source = sock.recvfrom(65536)
                except OSError:
                    continue
                if sock is self.front:
                    self.client = source
                    if len(data) >= 4 and data[1] & 0x80:
                        self._count("reliable")
                    self.back.send(data)
                    continue
                if len(data) >= 8 and data[1] == C.STREAM_NONE:
                    start = 4 if data[0] & 0x80 else 8
                    offset = start
                    while offset + 4 <= len(data):
                        sub_id, length = data[offset], data[offset + 2] | (data[offset + 3] << 8)
                        if sub_id == C.ACKNACK:
                            self._count("acknack")
                        elif sub_id == C.HEARTBEAT:
                            self._count("heartbeat")
                        offset = (offset + 4 + length + 3) & ~3
                if self.client is not None:
                    self.front.sendto(data, self.client)

    def stop(self):
        self.stopping = True
        self.join(2)
        self.front.close()
        self.back.close()


def python_client_traffic(relay, samples, key):
    from xrce.client.entities import create_participant, create_topic
    from xrce.client.session import Session
    from xrce.msgs.std_msgs import String
    from xrce.transports.udp import UdpTransport

    session = Session(UdpTransport("127.0.0.1", relay.port), key=key, history=HISTORY)
    try:
        if not session.create(attempts=5, timeout_ms=2000):
            raise RuntimeError("no session")
        relay.phase = "creations"
        node = create_participant(session, 0, "acknack_counts")
        if not session.run_until_all_status(5000):
            raise RuntimeError("participant not created")
        for n in range(TOPICS):
            create_topic(session, node, "rt/acknack_counts_%d" % n, String.TYPE_NAME)
            if not session.run_until_all_status(5000):
                raise RuntimeError("topic %d not created" % n)
        relay.phase = None
        writer = session.create_writer(node, "/acknack_counts", String, reliable=True)
        if not session.run_until_all_status(5000):
            raise RuntimeError("writer not created")
        session.run_until_timeout(200)
        relay.phase = "writes"
        message = String(data="acknack")
        for _ in range(samples):
            session.write(writer, message)
        if not session.run_until_confirm_delivery(10000):
            raise RuntimeError("writes not all acknowledged")
        session.run_until_timeout(300)  # the last ACKNACKs on their way
        relay.phase = None
    finally:
        session.close()


def eprosima_client_traffic(relay, program):
    import eprosima_scenarios as scenarios

    relay.phase = "creations (C)"
    result = subprocess.run([str(program), "udp4", "127.0.0.1", str(relay.port)],
                            input="\n".join(scenarios.BACK_TO_BACK) + "\n", capture_output=True,
                            text=True, timeout=120)
    time.sleep(0.3)
    relay.phase = None
    if result.returncode != 0:
        raise RuntimeError("eProsima's client: %s" % result.stdout[-300:])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agent-cmd", required=True, help="the other agent, e.g. $PEERS/agent.sh")
    parser.add_argument("--middleware", choices=("ced", "dds"), default="ced")
    parser.add_argument("--samples", type=int, default=2000)
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    env = dict(os.environ)
    program = None
    import eprosima_client

    with tempfile.TemporaryDirectory(prefix="xrce-acknack-") as build:
        if eprosima_client.missing_reason() is None:
            program = eprosima_client.build("script.c", build)
        totals = {}
        for round_number in range(args.rounds):
            for label in ("xrce-agent", "other"):
                agent = (Agent(str(REPO), env, "-m", args.middleware) if label == "xrce-agent"
                         else CommandAgent(args.agent_cmd, env, options=("-m", args.middleware)))
                relay = CountingRelay(agent.port)
                try:
                    python_client_traffic(relay, args.samples,
                                          bytes([0x0A, 0xC0, round_number, len(totals)]))
                    if program is not None:
                        eprosima_client_traffic(relay, program)
                finally:
                    relay.stop()
                    agent.stop()
                for phase, row in relay.counts.items():
                    total = totals.setdefault((phase, label), {"reliable": 0, "acknack": 0,
                                                               "heartbeat": 0})
                    for key, value in row.items():
                        total[key] += value
    phases = sorted({phase for phase, _ in totals})
    print("%-14s %-11s %9s %9s %8s %10s %8s" % ("traffic", "agent", "reliable", "ACKNACK", "per msg",
                                               "HEARTBEAT", "per msg"))
    for phase in phases:
        for label in ("xrce-agent", "other"):
            row = totals.get((phase, label))
            if row is None:
                continue
            reliable = max(row["reliable"], 1)
            print("%-14s %-11s %9d %9d %8.3f %10d %8.3f" % (
                phase, label, row["reliable"], row["acknack"], row["acknack"] / reliable,
                row["heartbeat"], row["heartbeat"] / reliable))
        ours, theirs = totals.get((phase, "xrce-agent")), totals.get((phase, "other"))
        if ours and theirs:
            for what in ("acknack", "heartbeat"):
                figures.record("%s per reliable message, %s (-m %s)" % (what.upper(), phase,
                                                                        args.middleware),
                               ours[what] / max(ours["reliable"], 1), "per message",
                               theirs[what] / max(theirs["reliable"], 1), "other agent",
                               target="<= other agent")
    figures.print_table()


if __name__ == "__main__":
    main()
