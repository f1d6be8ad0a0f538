"""Record tests/golden/eprosima/: eProsima's client (programs/, built against XRCE_EPROSIMA_CLIENT)
against eProsima's agent (``--agent``, default $XRCE_EPROSIMA_AGENT: the ``agent.sh`` the peers
build script writes, run with -m ced), through a transparent UDP relay that writes down
every datagram. Run by hand, as root, where both are built (PEERS: where they were built):

    XRCE_EPROSIMA_CLIENT=$PEERS/install XRCE_EPROSIMA_AGENT=$PEERS/agent.sh unshare -n sh -c \\
        'ip link set lo up multicast on; ip route add 224.0.0.0/4 dev lo; .venv/bin/python tests/eprosima/record_eprosima.py'

(a private loopback, with a route for multicast: eProsima's discovery port does not open without
one; the agent answers discovery with that host's addresses, 127.0.0.1 and ::1 only). One file
per scenario of scenarios.py: a first line with what ran and what the program printed, then one
line per datagram ``{"t", "dir": "C->A" | "A->C", "hex"}``.
"""

from __future__ import annotations

import argparse
import json
import os
import select
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent / "helpers")]

import eprosima_client  # noqa: E402
import eprosima_scenarios as scenarios  # noqa: E402

GOLDEN = HERE.parent / "golden" / "eprosima"
AGENT_PORT, RELAY_PORT, DISCOVERY_PORT = 7711, 7712, 7713


class Relay(threading.Thread):
    """Client <-> relay port <-> agent port, one client, every datagram recorded with its time."""

    def __init__(self, family, host, listen_port, agent_port):
        super().__init__(daemon=True)
        self.front = socket.socket(family, socket.SOCK_DGRAM)
        self.front.bind((host, listen_port))
        self.back = socket.socket(family, socket.SOCK_DGRAM)
        self.back.connect((host, agent_port))
        self.records = []
        self.stopping = False
        self.client = None
        self.start_time = time.monotonic()

    def run(self):
        while not self.stopping:
            ready, _, _ = select.select([self.front, self.back], [], [], 0.05)
            for sock in ready:
                data, source = sock.recvfrom(65536)
                t = round(time.monotonic() - self.start_time, 6)
                if sock is self.front:
                    self.client = source
                    self.records.append({"t": t, "dir": "C->A", "hex": data.hex()})
                    self.back.send(data)
                elif self.client is not None:
                    self.records.append({"t": t, "dir": "A->C", "hex": data.hex()})
                    self.front.sendto(data, self.client)

    def stop(self):
        self.stopping = True
        self.join(2)
        self.front.close()
        self.back.close()


def start_agent(agent, transport, *extra):
    process = subprocess.Popen([agent, transport, "-p", str(AGENT_PORT), "-m", "ced", *extra],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(1.0)  # it prints nothing when ready; it is within a few ms
    return process


def stop_agent(process):
    process.send_signal(signal.SIGTERM)  # it ignores SIGINT while a session is open
    try:
        process.wait(10)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


def record(name, header, relay, run):
    relay.start()
    try:
        header["stdout"] = run()
    finally:
        time.sleep(0.3)  # the last answers
        relay.stop()
    path = GOLDEN / ("%s.jsonl" % name)
    with path.open("w") as out:
        out.write(json.dumps(header) + "\n")
        for row in relay.records:
            out.write(json.dumps(row) + "\n")
    print("%s: %d datagrams, %s" % (path.name, len(relay.records), " | ".join(header["stdout"])))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agent", default=os.environ.get("XRCE_EPROSIMA_AGENT"),
                        help="eProsima's MicroXRCEAgent (default $XRCE_EPROSIMA_AGENT)")
    parser.add_argument("only", nargs="*", help="scenario names (default: all)")
    args = parser.parse_args()
    if not args.agent:
        parser.error("name eProsima's agent: --agent or XRCE_EPROSIMA_AGENT")
    reason = eprosima_client.missing_reason()
    if reason:
        sys.exit(reason)
    GOLDEN.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="xrce-record-") as build:
        script_exe = eprosima_client.build("script.c", build)
        discover_exe = eprosima_client.build("discover.c", build)
        for name, (transport, lines) in scenarios.CREATIONS.items():
            if args.only and name not in args.only:
                continue
            family, host = ((socket.AF_INET6, "::1") if transport.endswith("6")
                            else (socket.AF_INET, "127.0.0.1"))
            agent = start_agent(args.agent, transport)
            try:
                relay = Relay(family, host, RELAY_PORT, AGENT_PORT)

                def run():
                    result = subprocess.run([str(script_exe), transport, host, str(RELAY_PORT)],
                                            input="\n".join(lines) + "\n", capture_output=True,
                                            text=True, timeout=120)
                    return result.stdout.splitlines() + ["exit %d" % result.returncode]

                record(name, {"scenario": name, "transport": transport, "middleware": "ced",
                              "program": "script.c", "script": lines}, relay, run)
            finally:
                stop_agent(agent)
        for name, transport in scenarios.DISCOVERY.items():
            if args.only and name not in args.only:
                continue
            agent = start_agent(args.agent, transport, "-d", str(DISCOVERY_PORT))
            try:
                relay = Relay(socket.AF_INET, "127.0.0.1", RELAY_PORT, DISCOVERY_PORT)

                def run():
                    result = subprocess.run([str(discover_exe), "127.0.0.1", str(RELAY_PORT)],
                                            capture_output=True, text=True, timeout=60)
                    return result.stdout.splitlines() + ["exit %d" % result.returncode]

                record(name, {"scenario": name, "transport": transport, "middleware": "ced",
                              "program": "discover.c", "agent_port": AGENT_PORT}, relay, run)
            finally:
                stop_agent(agent)


if __name__ == "__main__":
    main()
