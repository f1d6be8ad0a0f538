"""PX4's traffic as a load: the c2a side of a PX4 capture (tests/golden/px4/, see its README)
replayed against a live agent at PX4's pace, for bench/px4/load.py.

``Px4Capture`` splits one PX4 boot into the connect part (session-less ping, CREATE_CLIENT, the
participant, the 500 TIMESTAMPs of the time sync, every CREATE and READ_DATA) and the streaming
part after it (WRITE_DATA on best-effort 0x01, TIMESTAMPs, GET_INFO pings, ACKNACKs), with the
recorded times. ``Px4Link`` plays PX4's XRCE client against an agent: the connect part paced on
the agent's answers (INFO, STATUS_AGENT, each TIMESTAMP_REPLY, the STATUS of every CREATE, as PX4
waits for them), then the streaming part at the recorded timing, looped for as long as asked.

Rewritten, as a live PX4 would have them: best-effort sequence numbers (they keep counting up
when the streaming part loops, else the agent would drop the second lap as old), ACKNACKs (sent
for every reliable message and HEARTBEAT of the agent, naming what this side received: the
recorded ones acknowledged eProsima's messages) and the originate time of each TIMESTAMP (the time
of day as it is sent; the kernel's receive stamp of the TIMESTAMP_REPLY ends the round trip). The reliable WRITE_DATA of
the streaming part (PX4's answer to a service request that no ROS node sends here) is left out.
"""

from __future__ import annotations

import gzip
import json
import socket
import struct
import threading
import time

from xrce.wire import constants as C

PX4_STREAM = 0x80  # PX4's reliable stream, and the agent's reliable stream to it
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)  # Linux's value where Python lacks the name
CREATE_ANSWER_S = 2.0  # a reliable message whose STATUS did not come by then is sent again


def _submessages(data: bytes):
    offset = 4 if data[0] >= 0x80 else 8
    while offset + 4 <= len(data):
        length = data[offset + 2] | (data[offset + 3] << 8)
        yield offset, data[offset], data[offset + 4:offset + 4 + length]
        offset = (offset + 4 + length + 3) & ~3


class Px4Capture:
    """``connect``: [bytes] in order; ``streaming``: [(seconds after its first, kind, bytes)],
    kind one of "sample", "timestamp", "acknack", "other"; ``lap_s``: one pass of it."""

    def __init__(self, path: str, peer: int = 0):
        with gzip.open(path, "rt") if path.endswith(".gz") else open(path) as lines:
            records = [json.loads(line) for line in lines]
        c2a = [(r["t"], bytes.fromhex(r["hex"])) for r in records
               if r["dir"] == "c2a" and r.get("peer", 0) == peer]
        # The connect part ends with the last reliable CREATE or READ_DATA message.
        last = max(i for i, (_t, data) in enumerate(c2a)
                   if data[1] == PX4_STREAM and any(sub in (C.CREATE, C.READ_DATA)
                                                    for _o, sub, _b in _submessages(data)))
        self.connect = [data for _t, data in c2a[:last + 1]]
        start = c2a[last + 1][0]
        self.streaming = []
        for t, data in c2a[last + 1:]:
            first = next(_submessages(data), (0, None, b""))[1]
            if data[1] == PX4_STREAM:
                continue  # a service reply to a request nobody sends here (module docstring)
            kind = ("sample" if data[1] == C.BUILTIN_BEST_EFFORT else
                    "timestamp" if first == C.TIMESTAMP else
                    "acknack" if first == C.ACKNACK else "other")
            self.streaming.append((t - start, kind, data))
        gaps = len(self.streaming) - 1
        self.lap_s = self.streaming[-1][0] * (1 + 1.0 / gaps) if gaps > 0 else 1.0
        self.samples_per_lap = sum(1 for _t, kind, _d in self.streaming if kind == "sample")


class Px4Link:
    """One PX4 client's UDP socket to ``port``; a thread reads the agent's answers."""

    def __init__(self, port: int):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        # The kernel stamps each answer as it arrives (CLOCK_REALTIME): a round trip is then the
        # agent's and the loopback's, not this process's threads waiting for the GIL.
        self.sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        self.sock.connect(("127.0.0.1", port))
        self.lock = threading.Condition()
        self.statuses = {}  # request id -> status code
        self.infos = self.status_agent = self.replies = 0
        self.rtts = []  # (label, µs) per TIMESTAMP_REPLY
        self.label = "sync"
        self.next_in = 0  # the agent's next reliable sequence number this side expects
        self.out_seq = 0  # best-effort sequence number of the next sample
        self.samples_sent = 0
        self.running = True
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def close(self) -> None:
        self.running = False
        self.sock.close()
        self.reader.join(5)

    # -- the agent's side --------------------------------------------------------------------

    def _read(self) -> None:
        self.sock.settimeout(0.2)
        while self.running:
            try:
                data, ancillary, _flags, _address = self.sock.recvmsg(4096, 64)
            except socket.timeout:
                continue
            except OSError:
                if not self.running:
                    return
                continue
            now = next((sec * 1000000000 + nsec for level, kind, value in ancillary
                        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS
                        for sec, nsec in [struct.unpack_from("qq", value)]), time.time_ns())
            if len(data) < 4:
                continue
            acknowledge = False
            if data[1] == PX4_STREAM:
                seq = data[2] | (data[3] << 8)
                with self.lock:
                    if seq == self.next_in:
                        self.next_in = (seq + 1) & 0xFFFF
                acknowledge = True
            for _offset, sub, body in _submessages(data):
                if sub == C.TIMESTAMP_REPLY and len(body) >= 24:
                    sec, nsec = struct.unpack_from("<iI", body, 16)
                    with self.lock:
                        self.rtts.append((self.label, (now - (sec * 1000000000 + nsec)) / 1000.0))
                        self.replies += 1
                        self.lock.notify_all()
                elif sub == C.STATUS and len(body) >= 5:
                    with self.lock:
                        self.statuses[(body[0] << 8) | body[1]] = body[4]
                        self.lock.notify_all()
                elif sub == C.STATUS_AGENT:
                    with self.lock:
                        self.status_agent += 1
                        self.lock.notify_all()
                elif sub == C.INFO:
                    with self.lock:
                        self.infos += 1
                        self.lock.notify_all()
                elif sub == C.HEARTBEAT and len(body) >= 5 and body[4] == PX4_STREAM:
                    first = body[0] | (body[1] << 8)
                    with self.lock:
                        if ((first - self.next_in) & 0xFFFF) < 0x8000:
                            self.next_in = first  # the agent gave up on what came before
                    acknowledge = True
            if acknowledge:
                self.send(self.acknack())

    def acknack(self) -> bytes:
        with self.lock:
            first = self.next_in
        return bytes((C.DEFAULT_SESSION_ID, 0, 0, 0, C.ACKNACK, 0x01, 5, 0, first & 0xFF,
                      first >> 8, 0, 0, PX4_STREAM))

    def send(self, data: bytes) -> None:
        try:
            self.sock.send(data)
        except OSError:  # e.g. the agent's port went away: the bench notices the missing answers
            pass

    def _wait(self, predicate, timeout_s: float) -> bool:
        with self.lock:
            return self.lock.wait_for(predicate, timeout_s)

    # -- PX4's side --------------------------------------------------------------------------

    def timestamp(self, data: bytes) -> bytes:
        """``data`` (a TIMESTAMP) with the time of day as originate (the clock of the kernel's
        receive stamps)."""
        now = time.time_ns()
        out = bytearray(data)
        struct.pack_into("<iI", out, 8, now // 1000000000, now % 1000000000)
        return bytes(out)

    def sync(self, data: bytes, count: int, timeout_s: float = 1.0) -> int:
        """``count`` TIMESTAMPs, each sent once the previous one's reply came (PX4's time sync):
        how many were answered."""
        answered = 0
        for _ in range(count):
            with self.lock:
                before = self.replies
            self.send(self.timestamp(data))
            if self._wait(lambda: self.replies > before, timeout_s):
                answered += 1
        return answered

    def connect(self, capture: Px4Capture, timeout_s: float = 30.0) -> None:
        """The connect part, paced on the agent's answers as PX4 paces it."""
        for data in capture.connect:
            first = next(_submessages(data), (0, None, b""))[1]
            if data[0] == C.SESSION_ID_NONE_WITHOUT_KEY and first == C.GET_INFO:
                with self.lock:
                    before = self.infos
                self.send(data)
                if not self._wait(lambda: self.infos > before, timeout_s):
                    raise RuntimeError("the agent did not answer PX4's ping")
            elif first == C.CREATE_CLIENT:
                with self.lock:
                    before = self.status_agent
                self.send(data)
                if not self._wait(lambda: self.status_agent > before, timeout_s):
                    raise RuntimeError("no STATUS_AGENT for PX4's CREATE_CLIENT")
            elif first == C.TIMESTAMP:
                if not self.sync(data, 1, timeout_s):
                    raise RuntimeError("a TIMESTAMP of the time sync was not answered")
            elif first == C.ACKNACK:
                continue  # this side acknowledges the agent's messages itself (_read)
            elif data[1] == PX4_STREAM:
                self._reliable(data, timeout_s)
            else:
                self.send(data)

    def _reliable(self, data: bytes, timeout_s: float) -> None:
        requests = [(body[0] << 8) | body[1] for _o, sub, body in _submessages(data)
                    if sub == C.CREATE and len(body) >= 2]
        deadline = time.monotonic() + timeout_s
        while True:
            self.send(data)
            if self._wait(lambda: all(r in self.statuses for r in requests), CREATE_ANSWER_S):
                break
            if time.monotonic() > deadline:
                raise RuntimeError("no STATUS for requests %s" % requests)
        failed = {r: self.statuses[r] for r in requests if self.statuses[r] > C.STATUS_OK_MATCHED}
        if failed:
            raise RuntimeError("the agent refused PX4's CREATEs (request id: status) %s" % failed)

    def stream(self, capture: Px4Capture, seconds: float, stop=None) -> int:
        """The streaming part at its recorded timing, looped for ``seconds``: samples sent."""
        start = time.monotonic()
        sent = lap = 0
        while True:
            base = start + lap * capture.lap_s
            for t, kind, data in capture.streaming:
                due = base + t
                if due - start > seconds or (stop is not None and stop.is_set()):
                    return sent
                delay = due - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                if kind == "sample":
                    out = bytearray(data)
                    out[2], out[3] = self.out_seq & 0xFF, (self.out_seq >> 8) & 0xFF
                    self.out_seq = (self.out_seq + 1) & 0xFFFF
                    data = bytes(out)
                    sent += 1
                    self.samples_sent += 1
                elif kind == "timestamp":
                    data = self.timestamp(data)
                elif kind == "acknack":
                    data = self.acknack()
                self.send(data)
            lap += 1
