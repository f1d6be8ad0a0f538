"""What eProsima's client sent across two restarts of the agent (tests/golden/eprosima_restart/,
recorded by record_board_restart.py) replayed against a real agent process that is itself stopped
with SIGINT, and later killed with SIGKILL, where the recording's agent was, and started again on
the same port and state store. CI has no eProsima library; this is what it checks instead.

The board's datagrams go at the recording's pace, rewritten only where a live board derives bytes
from the agent's answers (tests/helpers/microros_replay.py does the same for micro-ROS): its
ACKNACKs of the agent's reliable stream say what this agent sent, its service replies echo the
identity of this agent's request, its participant's domain is the test's. What the agent says to
the board is compared by meaning:

- after each restart, before anything else of the board's reliable stream arrives, the agent's
  ACKNACKs of that stream name exactly what the previous process handled last (a clean stop: with
  a NACK bit, so the board sends again what went into the outage) or a number far past anything
  the board had sent (a crash: xrce.agent.engine.resync), never one behind it;
- it asks where its own reliable stream stands (HEARTBEAT) and carries on there: /board_cmd
  samples reach the board after each restart, in order, none twice;
- ROS gets the board's best-effort and reliable samples after each restart, every service call
  is answered, and the graph holds one of each of the board's entities.
"""

import json
import signal
import socket
import time
from pathlib import Path

import pytest

from agent_process import AgentProcess
from board_side import INTERFACES, RosSide, graph_counts
from microros_replay import Answers, UdpChannel, _submessages
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from xrce.wire import constants as C
from xrce.wire.submessages import AckNack, decode_message, encode_message

GOLDEN = Path(__file__).resolve().parents[1] / "golden" / "eprosima_restart" / "board_once_udp4.jsonl"
STREAM = 0x80
BOOT = 0  # one board, one boot: Answers keeps the agent's stream as the board receives it


def _seq(data):
    return data[2] | (data[3] << 8)


def _diff(a, b):
    return (a - b) & 0xFFFF


class BoardReplay:
    def __init__(self, rows, port, domain_id, replier, reader):
        self.rows = rows
        self.channel = UdpChannel(port)
        self.answers = Answers()
        self.domain_id = domain_id
        self.replier, self.reader = replier, reader
        self.replies = 0  # the board's replies sent so far
        self.log = []  # (phase, monotonic, data) of everything the agent sent
        self.phase = 0  # agents started so far - 1
        self.sent = {}  # phase -> highest reliable seq of the board sent to that phase's agent

    def pump(self, timeout=0.0):
        for boot, message in self.channel.receive(timeout):
            if not message:
                continue
            self.log.append((self.phase, time.monotonic(), message))
            if self.answers.note(boot, message):
                first, bitmap = self.answers.reliable[BOOT].acknack()
                self.channel.send(BOOT, encode_message(0x81, 0, 0, None,
                                                       [AckNack(first, bitmap, STREAM)]))

    def wait(self, until):
        while time.monotonic() < until:
            self.pump(min(0.01, max(0.0, until - time.monotonic())))

    def rewrite(self, data):
        if data[0] <= 0x80:
            return data
        if data[1] == 0 and len(data) > 4 and data[4] == C.ACKNACK:
            first, bitmap = self.answers.reliable[BOOT].acknack()
            return encode_message(0x81, 0, 0, None, [AckNack(first, bitmap, STREAM)])
        out = bytearray(data)
        offset = 4
        for sub_id, flags, body in _submessages(data, 4):
            length = len(body)
            if sub_id == C.CREATE and length >= 8 and body[4] == C.OBJK_PARTICIPANT:
                end = offset + 4 + length
                out[end - 2:end] = self.domain_id.to_bytes(2, "little" if flags & 1 else "big")
            elif sub_id == C.WRITE_DATA and length >= 28 and (body[2] << 8 | body[3]) == self.replier:
                key = (BOOT, self.replier)
                index = self.replies
                self.replies += 1
                deadline = time.monotonic() + 10
                while len(self.answers.samples.get(key, ())) <= index and time.monotonic() < deadline:
                    self.pump(0.01)
                requests = self.answers.samples.get(key, ())
                if len(requests) > index:
                    out[offset + 8:offset + 32] = requests[index][:24]
            offset = (offset + 4 + length + 3) & ~3
        return bytes(out)

    def send(self, data):
        if data[0] > 0x80 and data[1] == STREAM:
            previous = self.sent.get(self.phase)
            seq = _seq(data)
            if previous is None or _diff(seq, previous) < 0x8000:
                self.sent[self.phase] = seq
        self.channel.send(BOOT, self.rewrite(data))


def _acknacks(messages):
    return [p for _, _, m in messages for p in _decode(m) if p.ID == C.ACKNACK and p.stream_id == STREAM]


def _decode(message):
    return decode_message(message)[1]


@pytest.mark.timeout(120)
def test_recorded_board_survives_agent_restarts(tmp_path, ros_peer, ros_domain):  # noqa: F811
    lines = GOLDEN.read_text().splitlines()
    header = json.loads(lines[0])
    rows = [json.loads(line) for line in lines[1:]]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    args = ("udp4", "-p", str(port), "-m", "dds", "-v", "0", "--state",
            str(tmp_path / "state.sqlite3"), "--interfaces", INTERFACES)
    ros = RosSide(ros_peer)
    replay = BoardReplay(rows, port, ros_domain, int(header["replier"], 16),
                         int(header["reader"], 16))
    agent = AgentProcess(*args).__enter__()
    calls, stops, banners = [], [], [time.monotonic()]
    try:
        base, origin = time.monotonic(), rows[0]["t"]
        for row in rows:
            replay.wait(base + row["t"] - origin)
            event = row.get("event")
            if event == "stop":
                stops.append(row["kind"])
                if row["kind"] == "SIGINT":
                    assert agent.stop() == 0
                else:
                    agent.proc.send_signal(signal.SIGKILL)
                    agent.proc.wait(10)
            elif event == "banner":
                agent = AgentProcess(*args).__enter__()
                replay.phase += 1
                banners.append(time.monotonic())
                base, origin = time.monotonic(), row["t"]  # the recording goes on from here
            elif event == "call":
                calls.append(((row["a"], row["b"]), ros.client.call_async(
                    ros.AddTwoInts.Request(a=row["a"], b=row["b"]))))
            elif row.get("dir") == "C->A":
                replay.send(bytes.fromhex(row["hex"]))
        replay.wait(time.monotonic() + 0.5)
        assert stops == header["stops"] == ["SIGINT", "SIGKILL"]
        assert wait_until(lambda: all(f.done() for _, f in calls), 10), \
            [(ab, f.done()) for ab, f in calls]
        assert [f.result().sum for _, f in calls] == [a + b for (a, b), _ in calls]
        # (the killed agent's participant leaves the graph when its DDS lease runs out)
        one_each = {"nodes": 1, "sensor_publishers": 1, "reliable_publishers": 1,
                    "cmd_subscribers": 1, "add_services": 1}
        assert wait_until(lambda: graph_counts(ros_peer) == one_each, 30), graph_counts(ros_peer)
    finally:
        ros.stop()
        agent.stop()
        replay.channel.close()

    for phase, kind in enumerate(stops, start=1):
        said = [entry for entry in replay.log if entry[0] == phase]
        before = replay.sent[phase - 1]  # the last the board sent the agent that went away
        # The board's reliable stream: resynchronised by the agent, never pulled behind.
        resync = _acknacks(said)
        assert resync, kind
        first = resync[0]
        ahead = _diff(first.first_unacked, before)
        assert ahead < 0x8000 or _diff(before, first.first_unacked) < 0x8000 and \
            kind == "SIGINT", (kind, first, before)  # (a clean stop may name one not sent yet)
        if kind == "SIGINT":
            # Exactly after what the previous process acknowledged last (or one more it handled
            # and had not acknowledged yet), asking for everything after it again.
            acked = _acknacks([e for e in replay.log if e[0] == phase - 1])[-1].first_unacked
            assert _diff(first.first_unacked, acked) <= 1 and first.nack_bitmap & 1, \
                (kind, first, acked)
        elif ahead > 16:  # (none if the board's own next message came first: GRACE_S)
            assert ahead >= 0x3000, (kind, first, before)  # far past it: resync.LEAP
        # The agent asked where its own stream stands, and /board_cmd went on in order.
        assert any(p.ID == C.HEARTBEAT and p.stream_id == STREAM for _, _, m in said
                   for p in _decode(m)), kind
        later = [t for t, _ in ros.sensor if t > banners[phase]]
        assert later, ("no board sample in ROS after", kind)
        assert any(t > banners[phase] for t, _ in ros.reliable), ("no reliable sample after", kind)
    commands = replay.answers.samples.get((BOOT, replay.reader), [])
    values = [int.from_bytes(body[:4], "little") for body in commands]
    assert len(values) > 20 and values == sorted(set(values)), values
    reliable = [v for _, v in ros.reliable]
    assert reliable == sorted(set(reliable)), reliable
