"""Fuzz a live ``xrce-agent`` process while a well-behaved client keeps publishing.

    python bench/hostile/fuzz_live_agent.py [--count 1000000] [--middleware ced|dds] [--sockets 8]
                                    [--seed 1] [--max-seconds 300] [--serial]

Random datagrams and mutations of the golden captures (bit flips, byte overwrites, truncation,
extension, splices; tests/golden/wire_captures.json) go to the agent from several
UDP sockets (``--serial``: as byte soup and mutated frames into a second pseudoterminal of a
``multiserial`` agent), while a writer session publishes to a reader session through the same
agent, alternating reliable and best-effort samples. Printed at the end: datagrams sent, the
agent's decode errors and drops (its SIGUSR1 stats line), the good client's delivery, the agent's
RSS before and after, and whether it crashed. ``tests/hostile/test_hostile_input.py`` runs the same code at
a smaller count.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import socket
import sys
import termios
import threading
import time
import tty
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from agent_process import AgentProcess  # noqa: E402
from xrce.client.session import Session  # noqa: E402
from xrce.msgs.std_msgs import String  # noqa: E402
from xrce.tools.relays import SerialRelay  # noqa: E402
from xrce.transports.serial import SerialTransport  # noqa: E402
from xrce.transports.udp import UdpTransport  # noqa: E402

GOLDEN = REPO / "tests" / "golden" / "wire_captures.json"


def golden_corpus():
    """(datagrams, serial frames) the client side sent in the captures, as bytes."""
    data = json.loads(GOLDEN.read_text())
    datagrams = {bytes.fromhex(d["hex"]) for s in data["sections"] for d in s["datagrams"]
                 if d.get("dir", "").startswith("C")}
    for scenario in data["scenarios"].values():
        for item in scenario:
            if isinstance(item, dict) and "hex" in item and item.get("dir", "C").startswith("C"):
                datagrams.add(bytes.fromhex(item["hex"]))
    frames = [bytes.fromhex(f["raw"]) for f in data["serial"]]
    return sorted(datagrams), frames


# Keys the structured attacks use: their sessions exist (a CREATE_CLIENT now and then), so the
# stream, fragment and parking paths behind them are reached, not only the unknown-client one.
_ATTACK_KEYS = (b"\xa1\x00\x00\x01", b"\xa1\x00\x00\x02", b"\xa1\x00\x00\x03")
# A type no interface package provides: with -m dds its CREATE waits for a build (a parked client).
_UNKNOWN_TYPE = "xrcefuzz_msgs::msg::dds_::Thing_"


class Mutator:
    def __init__(self, corpus, seed):
        self.corpus = corpus
        self.rng = random.Random(seed)
        self.chains = {}  # (key, stream) -> next sequence number of a FRAGMENT chain

    def next(self):
        rng = self.rng
        roll = rng.random()
        if roll < 0.25:
            return rng.randbytes(rng.randint(0, 600))
        if roll < 0.35:
            return self.structured()
        data = bytearray(rng.choice(self.corpus))
        for _ in range(rng.randint(1, 4)):
            kind = rng.randint(0, 5)
            if kind == 0 and data:  # bit flips
                index = rng.randrange(len(data))
                data[index] ^= 1 << rng.randrange(8)
            elif kind == 1 and data:  # an interesting byte
                data[rng.randrange(len(data))] = rng.choice((0, 1, 0x7F, 0x80, 0xFF, 0x7E, 0x7D))
            elif kind == 2 and data:  # truncation
                del data[rng.randrange(len(data)):]
            elif kind == 3:  # extension
                data += rng.randbytes(rng.randint(1, 64))
            elif kind == 4:  # splice with another capture
                other = rng.choice(self.corpus)
                cut = rng.randrange(len(data) + 1)
                data = data[:cut] + other[rng.randrange(len(other) + 1):]
            elif kind == 5 and len(data) >= 8:  # a length or id field set to an extreme
                index = rng.randrange(len(data) - 1)
                data[index:index + 2] = rng.choice((b"\xff\xff", b"\x00\x00", b"\x00\x80"))
        return bytes(data)


    def structured(self):
        """Well-formed hostile messages of an established session: nested FRAGMENTs, FRAGMENT
        chains longer than the window, a client parked on a type build with reliable samples
        behind it, out-of-order reliable messages."""
        from xrce.wire import constants as C
        from xrce.wire.objects import ParticipantBin, TopicBin
        from xrce.wire.submessages import Create, CreateClient, Fragment, WriteData, encode_message

        rng = self.rng
        key = rng.choice(_ATTACK_KEYS)
        session = 0x01 + _ATTACK_KEYS.index(key)
        kind = rng.randint(0, 5)
        if kind == 0:
            return encode_message(0, 0, 0, key, [CreateClient(key, session, 512)])
        stream = rng.choice((0x80, 0x81, 0x80 + rng.randrange(128)))
        if kind == 1:  # FRAGMENT (last) in FRAGMENT (last) in ... up to thousands deep
            inner = bytes((C.WRITE_DATA, 1, 6, 0, 0, 1, 0, 0x15, 1, 2))
            for _ in range(rng.randint(2, 3000)):
                inner = bytes((C.FRAGMENT, 3, len(inner) & 0xFF, len(inner) >> 8)) + inner
                if len(inner) > 60000:
                    break
            return encode_message(session, stream, self._next(key, stream), key, [])[:8] + inner
        if kind == 2:  # the next link of a chain that runs far past the window
            seq = self._next(key, stream)
            flags = 1 | (2 if rng.random() < 0.01 else 0)
            return encode_message(session, stream, seq, key,
                                  [Fragment(rng.randbytes(rng.randint(1, 480)), flags)])
        if kind == 3:  # a participant and a topic whose type must be built: the client parks
            self.chains[(key, 0x80)] = 0
            return encode_message(session, 0x80, self._next(key, 0x80), key, [
                Create(1, 0x0011, C.OBJK_PARTICIPANT, C.REPRESENTATION_IN_BINARY,
                       ParticipantBin("fuzz"), 0, 3),
                Create(2, 0x0012, C.OBJK_TOPIC, C.REPRESENTATION_IN_BINARY,
                       TopicBin("rt/fuzz_parked", _UNKNOWN_TYPE), 0x0011, 3)])
        if kind == 4:  # reliable samples behind it (or behind nothing), in order
            return encode_message(session, 0x80, self._next(key, 0x80), key,
                                  [WriteData(3, 0x0015, rng.randbytes(rng.randint(4, 400)))])
        return encode_message(session, stream, rng.randint(1, 40), key,  # out of order
                              [WriteData(4, 0x0015, rng.randbytes(rng.randint(4, 1400)))])

    def _next(self, key, stream):
        seq = self.chains.get((key, stream), 0)
        self.chains[(key, stream)] = (seq + 1) & 0xFFFF
        return seq


def rss_kib(pid):
    try:
        with open("/proc/%d/status" % pid) as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except OSError:  # the process is gone
        pass
    return -1


class StatsReader:
    """Drains the agent's stdout (so it never blocks on a full pipe) and keeps its stats lines."""

    def __init__(self, agent):
        self.agent = agent
        self.lines = []
        self.stats = []
        self.thread = threading.Thread(target=self._drain, daemon=True)
        self.thread.start()

    def _drain(self):
        for line in self.agent.proc.stdout:
            if line.startswith("xrce-agent: stats "):
                self.stats.append(json.loads(line[len("xrce-agent: stats "):]))
            elif len(self.lines) < 10000:
                self.lines.append(line)

    def snapshot(self, timeout=5.0):
        count = len(self.stats)
        self.agent.proc.send_signal(signal.SIGUSR1)
        deadline = time.monotonic() + timeout
        while len(self.stats) == count and time.monotonic() < deadline:
            time.sleep(0.01)
        return self.stats[-1] if len(self.stats) > count else None


class GoodClients:
    """A writer and a reader session through the agent; alternately reliable and best-effort."""

    def __init__(self, make_transport, domain_id=0):
        self.sessions = []
        self.received = {"reliable": [], "best_effort": []}
        self.sent = {"reliable": 0, "best_effort": 0}
        self.writer = self._session(make_transport())
        self.reader = self._session(make_transport())
        node_w = self.writer.create_participant(domain_id=domain_id, name="good_writer")
        node_r = self.reader.create_participant(domain_id=domain_id, name="good_reader")
        self.writers = {}
        for qos, reliable in (("reliable", True), ("best_effort", False)):
            topic = "/good_" + qos
            self.reader.create_reader(node_r, topic, String, self._on(qos), reliable=reliable,
                                      depth=1000)
            self.writers[qos] = self.writer.create_writer(node_w, topic, String, reliable=reliable,
                                                          depth=1000)
        for session in self.sessions:
            assert session.run_until_all_status(10000), session.last_statuses
        time.sleep(0.5)  # DDS matching under -m dds

    def _session(self, transport):
        session = Session(transport, history=16, auto_recover=False)
        assert session.create(attempts=5, timeout_ms=1000)
        self.sessions.append(session)
        return session

    def _on(self, qos):
        return lambda msg: self.received[qos].append(int(msg.data))

    def publish(self):
        for qos in ("reliable", "best_effort"):
            stream = self.writer.reliable if qos == "reliable" else self.writer.best_effort
            if self.writer.write(self.writers[qos], String(data=str(self.sent[qos])), stream_id=stream):
                self.sent[qos] += 1
        self.writer.flush()

    def spin(self, seconds=0.0):
        deadline = time.monotonic() + seconds
        while True:
            for session in self.sessions:
                session.spin_once(1)
            if time.monotonic() >= deadline:
                return

    def keep_up(self, max_lag=100, seconds=2.0):
        """Let the reader catch up: a publisher faster than its subscriber overflows KEEP_LAST
        history by design, which is not what this bench measures."""
        deadline = time.monotonic() + seconds
        while self.sent["reliable"] - len(self.received["reliable"]) > max_lag and \
                time.monotonic() < deadline:
            self.spin(0.002)

    def settle(self, seconds=10):
        deadline = time.monotonic() + seconds
        while len(self.received["reliable"]) < self.sent["reliable"] and time.monotonic() < deadline:
            self.spin(0.01)
        self.spin(0.5)

    def delivery(self):
        total_sent = sum(self.sent.values())
        total_got = sum(len(set(v)) for v in self.received.values())
        reliable_in_order = self.received["reliable"] == list(range(len(self.received["reliable"])))
        return {"sent": dict(self.sent),
                "received": {q: len(v) for q, v in self.received.items()},
                "reliable_in_order": reliable_in_order,
                "delivery_percent": 100.0 * total_got / total_sent if total_sent else 0.0}

    def close(self):
        for session in self.sessions:
            session.close()


def _open_fuzz_pty():
    master, slave = os.openpty()
    tty.setraw(master, termios.TCSANOW)
    tty.setraw(slave, termios.TCSANOW)
    os.set_blocking(master, False)
    path = os.ttyname(slave)
    os.close(slave)
    return master, path


def run(count=20000, middleware="ced", sockets=8, seed=1, max_seconds=300.0, serial=False,
        domain_id=0, publish_every=100, agent_args=()):
    datagrams, frames = golden_corpus()
    mutator = Mutator(frames if serial else datagrams, seed)
    relays = []
    fuzz_master = None
    if serial:
        relays = [SerialRelay(), SerialRelay()]  # a clean line for each good session
        fuzz_master, fuzz_path = _open_fuzz_pty()
        devices = [relay.agent_path for relay in relays] + [fuzz_path]
        link_args = ["multiserial", "--devs", " ".join(devices)]
    else:
        link_args = ["udp4"]
    agent = AgentProcess(*link_args, "-m", middleware, "-v", "2", *agent_args).__enter__()
    fuzz_sockets = []
    good = None
    result = {"middleware": middleware, "link": "serial" if serial else "udp"}
    try:
        reader = StatsReader(agent)
        if serial:
            lines = iter(relays)
            good_transport = lambda: SerialTransport(next(lines).client_path, 115200)  # noqa: E731
        else:
            good_transport = lambda: UdpTransport("127.0.0.1", agent.port)  # noqa: E731
        good = GoodClients(good_transport, domain_id)
        good.spin(0.2)
        for _ in range(sockets if not serial else 0):
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.setblocking(False)
            fuzz_sockets.append(sock)
        before = reader.snapshot()
        rss_before = rss_kib(agent.proc.pid)
        start = time.monotonic()
        sent = 0
        while sent < count and time.monotonic() - start < max_seconds:
            data = mutator.next()
            if serial:
                # Byte soup and mutated frames; a flag first so not every frame merges.
                try:
                    os.write(fuzz_master, b"\x7e" + data)
                except BlockingIOError:
                    good.spin(0.002)
                    continue
            else:
                sock = fuzz_sockets[sent % len(fuzz_sockets)]
                try:
                    sock.sendto(data, ("127.0.0.1", agent.port))
                except BlockingIOError:
                    good.spin(0.002)
                    continue
                try:
                    while True:
                        sock.recv(65535)  # replies are not read by anyone; keep buffers empty
                except (BlockingIOError, ConnectionRefusedError):
                    pass
            sent += 1
            if sent % publish_every == 0:
                good.publish()
                good.spin()
                good.keep_up()
            if serial and sent % 64 == 0:
                try:  # drain what the agent answers on the fuzz line
                    while os.read(fuzz_master, 65536):
                        pass
                except (BlockingIOError, OSError):
                    pass
        elapsed = time.monotonic() - start
        good.settle()
        after = reader.snapshot()
        if after is None:  # no stats line: the agent is dead or stuck
            raise RuntimeError("agent gave no stats; its last output:\n" + "".join(reader.lines[-30:]))
        rss_after = rss_kib(agent.proc.pid)
        crashed = agent.proc.poll() is not None
        result.update({
            "datagrams": sent, "seconds": round(elapsed, 1), "rate_per_s": int(sent / elapsed),
            "decode_errors": after["engine"]["decode_errors"] - before["engine"]["decode_errors"],
            "dropped": after["engine"]["dropped"] - before["engine"]["dropped"],
            "link_drops": sum(l["drops"] for l in after["links"].values())
            - sum(l["drops"] for l in before["links"].values()),
            "handler_errors": after["engine"]["handler_errors"],
            "clients": after["clients"],
            "rss_before_kib": rss_before, "rss_after_kib": rss_after,
            "crashes": int(crashed),
        })
        result.update(good.delivery())
    finally:
        if good is not None:
            good.close()
        for sock in fuzz_sockets:
            sock.close()
        code = agent.stop()
        result["exit_code"] = code
        if fuzz_master is not None:
            os.close(fuzz_master)
        for relay in relays:
            relay.close()
    return result


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=1_000_000)
    parser.add_argument("--middleware", choices=("ced", "dds"), default="ced")
    parser.add_argument("--sockets", type=int, default=8)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--max-seconds", type=float, default=300.0)
    parser.add_argument("--serial", action="store_true")
    args = parser.parse_args(argv)
    result = run(args.count, args.middleware, args.sockets, args.seed, args.max_seconds, args.serial,
                 domain_id=int(os.environ.get("ROS_DOMAIN_ID", "0")))
    for key, value in result.items():
        print("%-18s %s" % (key, value))
    return 0 if result["crashes"] == 0 and result["exit_code"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
