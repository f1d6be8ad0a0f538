"""What one host on the robot's network can do to a live ``xrce-agent`` (issue 26), measured.

    python bench/hostile/network.py [--rows lockout,amplification,memory,storm]
                                    [--middleware ced|dds] [--flood-seconds 60] [--repo DIR]

Each row starts its own agent (``--repo``: run the agent of another checkout, e.g. an export of
the previous commit, for a same-run baseline) and prints one JSON line:

- ``lockout``: 1100 CREATE_CLIENTs with new keys from one socket, then the robot connects and
  creates a participant while the flood goes on at ~34 datagrams/s;
- ``amplification``: one ~60 KB datagram of GET_INFO, and one of DELETE(client), from an unknown
  session, and one of GET_INFO to the discovery port: replies and their bytes against the request;
- ``memory``: a mixed flood (out-of-order reliable messages and unfinished FRAGMENT chains on 128
  streams per key, fresh keys every second) for ``--flood-seconds``: agent RSS before, at its peak,
  and after the attacker's sessions expired;
- ``storm``: another client's session-less ping round trips (p50/p99/max), taken only while one
  client creates ten participants, each with a topic, a publisher and seven data writers (100
  CREATEs), as fast as the agent's STATUS window allows, ``rounds`` times.

``tests/hostile/test_hostile_network.py`` runs the same functions at suite size (a 20 s memory flood).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import socket
import statistics
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from agent_process import AgentProcess  # noqa: E402

from bench.hostile.fuzz_live_agent import StatsReader, rss_kib  # noqa: E402
from xrce.wire import constants as C  # noqa: E402
from xrce.client.session import Session  # noqa: E402
from xrce.wire.submessages import (  # noqa: E402
    CreateClient, Delete, Fragment, GetInfo, WriteData, encode_message,
)
from xrce.transports.udp import UdpTransport  # noqa: E402

LOCAL = "127.0.0.1"


def _tree(repo):
    """AgentProcess arguments running the agent of checkout ``repo`` (None: this one). Its path
    goes first on PYTHONPATH: the venv's editable install would otherwise win over the cwd."""
    if repo is None:
        return {"cwd": REPO}
    return {"cwd": repo, "env": {"PYTHONPATH": str(repo)}}


def _socket(timeout=0.2):
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
    sock.settimeout(timeout)
    return sock


def _drain(sock, seconds):
    """(replies, bytes) that reach ``sock`` within ``seconds``."""
    count = total = 0
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            data = sock.recv(65535)
        except (socket.timeout, BlockingIOError, ConnectionRefusedError):
            continue
        count += 1
        total += len(data)
    return count, total


def _create_client(key: bytes) -> bytes:
    # Session 0x01: the key travels in every header, so one socket can hold any number of them.
    return encode_message(0x00, 0, 0, key, [CreateClient(key, 0x01, 512)])


# ------------------------------------------------------------------------------------ lockout

def lockout(agent_args=("-m", "ced"), flood=1100, repo=None):
    """Robot admitted after a CREATE_CLIENT flood? Its CREATE_CLIENT and CREATE statuses."""
    rng = random.Random(26)
    with AgentProcess("udp4", *agent_args, "-v", "2", **_tree(repo)) as agent:
        StatsReader(agent)  # drains its output
        sock = _socket(0.001)
        started = time.monotonic()
        for _ in range(flood):
            sock.sendto(_create_client(rng.randbytes(4)), (LOCAL, agent.port))
        flood_s = time.monotonic() - started
        replies, _ = _drain(sock, 1.0)
        stop = threading.Event()

        def keep_flooding():  # ~34 datagrams/s, what the probe needed to keep it locked
            while not stop.wait(1 / 34):
                sock.sendto(_create_client(rng.randbytes(4)), (LOCAL, agent.port))

        flooder = threading.Thread(target=keep_flooding, daemon=True)
        flooder.start()
        robot = Session(UdpTransport(LOCAL, agent.port), auto_recover=False)
        try:
            admitted = robot.create(attempts=3, timeout_ms=1000)
            created = None
            if admitted:
                node = robot.create_participant(name="robot")
                created = robot.run_until_all_status(3000)
                time.sleep(1.0)  # 34 more strangers meanwhile: the robot's session stays
                robot.create_publisher(node)
                created = created and robot.run_until_all_status(3000)
                statuses = sorted(set(robot.last_statuses.values()))
            return {"row": "lockout", "flood": flood, "flood_seconds": round(flood_s, 2),
                    "flood_replies": replies, "robot_create_status": robot.create_status,
                    "robot_admitted": bool(admitted), "robot_entities_ok": bool(created),
                    "robot_statuses": statuses if admitted else None}
        finally:
            stop.set()
            flooder.join()
            robot.close()
            sock.close()


# ------------------------------------------------------------------------------ amplification

def _unknown_datagram(payloads):
    return encode_message(0x01, 0, 0, b"\xde\xad\xbe\xef", payloads)


def amplification(agent_args=("-m", "ced"), repo=None):
    """Replies and reply bytes for one big datagram from an unknown session / to discovery."""
    discovery = _free_udp_port()
    result = {"row": "amplification"}
    with AgentProcess("udp4", *agent_args, "-v", "2", "-d", str(discovery),
                      **_tree(repo)) as agent:
        StatsReader(agent)
        cases = {
            "get_info": (agent.port, _unknown_datagram([GetInfo(i & 0xFFFF) for i in range(5000)])),
            "delete_client": (agent.port, _unknown_datagram(
                [Delete(i & 0xFFFF, C.OBJECTID_CLIENT) for i in range(5000)])),
            "discovery": (discovery, encode_message(0x80, 0, 0, None,
                                                    [GetInfo(i & 0xFFFF) for i in range(5000)])),
        }
        for name, (port, datagram) in cases.items():
            sock = _socket(0.05)
            try:
                sock.sendto(datagram, (LOCAL, port))
                replies, total = _drain(sock, 1.5)
            finally:
                sock.close()
            result[name] = {"request_bytes": len(datagram), "replies": replies,
                            "reply_bytes": total}
    return result


def _free_udp_port():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind((LOCAL, 0))
        return sock.getsockname()[1]


# ------------------------------------------------------------------------------------ memory

def _flood_key(sock, port, key, payload):
    """One stranger's session filling its buffers: out-of-order reliable messages (seq 1..15, the
    in-order 0 never comes) and unfinished FRAGMENT chains, on 128 reliable streams."""
    sock.sendto(_create_client(key), (LOCAL, port))
    for stream_id in range(0x80, 0x100):
        for seq in range(1, 16):
            sock.sendto(encode_message(0x01, stream_id, seq, key, [WriteData(1, 0x15, payload)]),
                        (LOCAL, port))
        sock.sendto(encode_message(0x01, stream_id, 0, key, [Fragment(payload, 1)]),
                    (LOCAL, port))


def memory(agent_args=("-m", "ced"), seconds=20.0, dead_time_ms=2000, max_memory=None,
           repo=None):
    """Agent RSS under a mixed flood of fresh keys, and after their sessions went quiet."""
    rng = random.Random(5)
    extra = ["--client-dead-time", str(dead_time_ms)]
    if max_memory is not None:
        extra += ["--max-memory", str(max_memory)]
    with AgentProcess("udp4", *agent_args, "-v", "2", *extra, **_tree(repo)) as agent:
        stats = StatsReader(agent)
        time.sleep(0.5)
        before = rss_kib(agent.proc.pid)
        sock = _socket(0.001)
        payload = bytes(60000)
        peak = before
        keys = 0
        started = time.monotonic()
        while time.monotonic() - started < seconds:
            try:
                _flood_key(sock, agent.port, rng.randbytes(4), payload)
            except (BlockingIOError, socket.timeout):
                time.sleep(0.01)
            keys += 1
            _drain(sock, 0.0)
            peak = max(peak, rss_kib(agent.proc.pid))
        flood_s = time.monotonic() - started
        during = stats.snapshot()
        # Silence: past the dead time every stranger's session (no objects) expires.
        deadline = time.monotonic() + dead_time_ms / 1000 * 3 + 3
        after = rss_kib(agent.proc.pid)
        while time.monotonic() < deadline:
            time.sleep(0.5)
            peak = max(peak, after)
            after = rss_kib(agent.proc.pid)
        final = stats.snapshot()
        sock.close()
        alive = agent.proc.poll() is None
    engine = (final or {}).get("engine", {})
    return {"row": "memory", "seconds": round(flood_s, 1), "keys": keys,
            "rss_before_kib": before, "rss_peak_kib": peak, "rss_after_kib": after,
            "clients_during": (during or {}).get("clients"),
            "clients_after": (final or {}).get("clients"),
            "budget_refused": engine.get("budget_refused"), "expired": engine.get("clients_expired"),
            "agent_alive": alive}


# ------------------------------------------------------------------------------------- storm

def _pinger(port, stop, rtts):
    sock = _socket(1.0)
    request_id = 0
    try:
        while not stop.is_set():
            request_id = (request_id + 1) & 0xFFFF
            message = encode_message(0x80, 0, 0, None, [GetInfo(request_id)])
            sent = time.perf_counter()
            sock.sendto(message, (LOCAL, port))
            try:
                while True:
                    reply = sock.recv(65535)
                    if len(reply) >= 10 and reply[8] << 8 | reply[9] == request_id:
                        break
                rtts.append((time.perf_counter() - sent) * 1000)
            except socket.timeout:
                rtts.append(1000.0)
            time.sleep(0.001)
    finally:
        sock.close()


def storm(agent_args=("-m", "ced"), creates=100, domain_id=None, repo=None, rounds=1):
    """Another client's ping round trips while one client creates ``creates`` entities."""
    rtts, baseline = [], []
    if domain_id is None:
        domain_id = int(os.environ.get("ROS_DOMAIN_ID", "0"))
    with AgentProcess("udp4", *agent_args, "-v", "2", **_tree(repo)) as agent:
        StatsReader(agent)
        stop = threading.Event()
        pinger = threading.Thread(target=_pinger, args=(agent.port, stop, baseline), daemon=True)
        pinger.start()
        time.sleep(1.0)
        stop.set()
        pinger.join()
        creator = Session(UdpTransport(LOCAL, agent.port), history=16, auto_recover=False)
        try:
            assert creator.create(attempts=3, timeout_ms=2000)
            storm_s = []
            for round_ in range(rounds):
                stop = threading.Event()
                pinger = threading.Thread(target=_pinger, args=(agent.port, stop, rtts),
                                          daemon=True)
                pinger.start()
                started = time.monotonic()
                ok = True
                # Ten nodes, each with a topic of its own, a publisher and seven writers: what a
                # board's set-up looks like, ten times over (each node is a ROS node with -m dds).
                for index in range(creates):
                    step = index % 10
                    if step == 0:
                        node = creator.create_participant(domain_id=domain_id,
                                                          name="storm%d_%d" % (round_, index))
                    elif step == 1:
                        topic = creator.create_topic(node, "rt/storm%d_%d" % (round_, index),
                                                     "std_msgs::msg::dds_::String_")
                    elif step == 2:
                        publisher = creator.create_publisher(node)
                    else:
                        creator.create_datawriter(publisher, topic)
                    if index % 12 == 11:
                        # As fast as the agent's STATUS window allows: 16 replies unacknowledged
                        # at most, and a STATUS that finds it full is lost (as with eProsima).
                        ok = creator.run_until_all_status(20000) and ok
                ok = creator.run_until_all_status(20000) and ok
                storm_s.append(time.monotonic() - started)
                stop.set()
                pinger.join()
        finally:
            creator.close()
    ordered = sorted(rtts)

    def pct(values, p):
        return round(values[min(len(values) - 1, int(len(values) * p))], 2) if values else None

    return {"row": "storm", "creates": creates, "rounds": rounds, "all_ok": bool(ok),
            "storm_seconds": [round(s, 2) for s in storm_s], "pings": len(rtts),
            "ping_ms_p50": pct(ordered, 0.5), "ping_ms_p99": pct(ordered, 0.99),
            "ping_ms_max": pct(ordered, 1.0), "idle_ping_ms_p99": pct(sorted(baseline), 0.99),
            "idle_ping_ms_median": round(statistics.median(baseline), 2) if baseline else None}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rows", default="lockout,amplification,memory,storm")
    parser.add_argument("--middleware", choices=("ced", "dds"), default="ced")
    parser.add_argument("--flood-seconds", type=float, default=60.0)
    parser.add_argument("--repo", type=Path, default=None,
                        help="checkout whose agent to run (default: this one)")
    args = parser.parse_args(argv)
    agent_args = ("-m", args.middleware)
    repo = args.repo.resolve() if args.repo else None
    for row in args.rows.split(","):
        if row == "lockout":
            print(json.dumps(lockout(agent_args, repo=repo)), flush=True)
        elif row == "amplification":
            print(json.dumps(amplification(agent_args, repo=repo)), flush=True)
        elif row == "memory":
            print(json.dumps(memory(agent_args, seconds=args.flood_seconds, repo=repo)), flush=True)
        elif row == "storm":
            print(json.dumps(storm(agent_args, repo=repo, rounds=3)), flush=True)
        else:
            parser.error("unknown row %r" % row)


if __name__ == "__main__":
    main()
