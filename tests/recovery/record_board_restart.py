"""Record what eProsima's client sends across two restarts of xrce-agent, for CI (which has no
eProsima library): tests/golden/eprosima_restart/board_once_udp4.jsonl.

    XRCE_EPROSIMA_CLIENT=/path/to/prefix unshare -n sh -c \\
        'ip link set lo up && .venv/bin/python tests/recovery/record_board_restart.py'

tests/recovery/programs/board_once.c (creates its session and entities once, never again) talks
through a transparent UDP relay to ``xrce-agent udp4 -m dds --state FILE``; an rclpy node
subscribes to its writers, publishes /board_cmd at 20 Hz and calls /board_add. After a few seconds
the agent is stopped with SIGINT, started again 1 s later on the same port and store, and later
killed with SIGKILL and started again the same way. The relay's socket towards the agent stays the
same, so each agent sees the board at one address, as a board that never noticed would be.

What is recorded is the board's behaviour, not a spec of the agent: each line is a datagram
(``t`` seconds since the relay started, ``dir`` ``C->A`` board to agent or ``A->C``, ``hex``) or
an event (``event``: ``stop`` with its ``kind``, ``banner`` when the restarted agent is up,
``call`` with the service request's ``a`` and ``b`` as the ROS side made it). The first line says
what was recorded. tests/recovery/test_board_restart_replay.py replays the board's side.
"""

import json
import os
import select
import signal
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent / "helpers"), str(HERE.parents[1])]

import eprosima_client  # noqa: E402
from agent_process import AgentProcess  # noqa: E402
from board_side import INTERFACES, PROGRAM, Board, RosSide, free_udp_port  # noqa: E402
from ros_helpers import DomainLease, RosPeer, wait_until  # noqa: E402

OUT = HERE.parent / "golden" / "eprosima_restart" / "board_once_udp4.jsonl"
PHASE_S = 4.0  # data between events
AWAY_S = 1.0  # the agent's downtime


class Relay:
    """Board <-> relay <-> agent, every datagram logged with its time."""

    def __init__(self, agent_port):
        self.front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.front.bind(("127.0.0.1", 0))
        self.port = self.front.getsockname()[1]
        self.back = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.back.bind(("127.0.0.1", 0))
        self.agent = ("127.0.0.1", agent_port)
        self.board = None
        self.started = time.monotonic()
        self.rows = []
        self._stop = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def event(self, **fields):
        self.rows.append(dict({"t": round(time.monotonic() - self.started, 6)}, **fields))

    def _run(self):
        while not self._stop:
            ready, _, _ = select.select([self.front, self.back], [], [], 0.1)
            for sock in ready:
                try:
                    data, source = sock.recvfrom(65536)
                except OSError:  # an ICMP error of a send to a stopped agent
                    continue
                t = round(time.monotonic() - self.started, 6)
                if sock is self.front:
                    self.board = source
                    self.rows.append({"t": t, "dir": "C->A", "hex": data.hex()})
                    self.back.sendto(data, self.agent)
                elif self.board is not None:
                    self.rows.append({"t": t, "dir": "A->C", "hex": data.hex()})
                    self.front.sendto(data, self.board)

    def close(self):
        self._stop = True
        self._thread.join(2)
        self.front.close()
        self.back.close()


def main():
    if eprosima_client.missing_reason():
        sys.exit(eprosima_client.missing_reason())
    lease = DomainLease()
    os.environ["ROS_DOMAIN_ID"] = str(lease.domain_id)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    work = tempfile.mkdtemp(prefix="xrce-record-")
    exe = eprosima_client.build(PROGRAM, Path(work) / "build")
    port = free_udp_port()
    args = ("udp4", "-p", str(port), "-m", "dds", "--state", os.path.join(work, "state.sqlite3"),
            "--interfaces", INTERFACES)
    peer = RosPeer(lease.domain_id)
    ros = RosSide(peer)
    agent = AgentProcess(*args).__enter__()
    relay = Relay(port)
    board = Board(exe, ("udp", "127.0.0.1", str(relay.port), "60"))
    stops = ("SIGINT", "SIGKILL")
    try:
        assert wait_until(lambda: board.has("READY"), 30), board.lines
        assert wait_until(lambda: ros.sensor and ros.reliable and board.commands(), 30)
        for n, kind in enumerate(("", ) + stops):
            if kind:
                relay.event(event="stop", kind=kind)
                if kind == "SIGINT":
                    agent.stop()
                else:
                    agent.proc.send_signal(signal.SIGKILL)
                    agent.proc.wait(10)
                time.sleep(AWAY_S)
                agent = AgentProcess(*args).__enter__()
                relay.event(event="banner")
            time.sleep(PHASE_S / 2)
            a, b = 10 * n + 2, 3 * n + 3
            relay.event(event="call", a=a, b=b)
            assert ros.call(a, b, timeout=10) == a + b, (kind, a, b)
            time.sleep(PHASE_S / 2)
        relay.event(event="end")
    finally:
        ros.stop()
        board.stop()
        agent.stop()
        relay.close()
        peer.close()
        lease.release()
        import shutil
        shutil.rmtree(work, ignore_errors=True)
    header = {"recorded": "tests/recovery/record_board_restart.py", "program": "board_once.c",
              "client": "eProsima Micro XRCE-DDS Client 2.4.3", "transport": "udp4",
              "stops": list(stops), "away_s": AWAY_S, "board_cmd_hz": 20,
              "replier": "0x0018", "reader": "0x0016"}
    OUT.parent.mkdir(parents=True, exist_ok=True)
    with open(OUT, "w") as out:
        out.write(json.dumps(header) + "\n")
        for row in relay.rows:
            out.write(json.dumps(row) + "\n")
    print("%s: %d lines" % (OUT, len(relay.rows) + 1))


if __name__ == "__main__":
    main()
