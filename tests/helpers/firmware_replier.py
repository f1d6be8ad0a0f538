"""The real micro-ROS firmware's ``/add_two_ints`` replier, replayed: its set-up from
tests/golden/microros/main.jsonl (rclc + rmw_microxrcedds creating its node, topics, the replier
and its READ_DATA, binary, REUSE|REPLACE) through ``microros_replay.Replayer``, then answering as
the firmware did in the recording: each request's DATA with a WRITE_DATA of the reply on its
reliable stream, the request's sample identity in front (the recorded message's bytes, with its
sequence number, request id, identity and sum rewritten), the agent's reliable stream acknowledged
as the firmware's client library does, its own unacknowledged messages sent again every 0.2 s.

Used by bench/microros/service_roundtrip.py (timed) and tests/fastpath/test_fastpath_repliers.py (``reply`` changed
to send what a board gets wrong).
"""

from __future__ import annotations

import struct
import threading
import time

from microros_replay import FIRMWARE_STREAM, Capture, Replayer, UdpChannel

from xrce.wire import constants as C

REPLIER_OBJECT = b"\x00\x08"
REPLIER_ID = 0x0008  # its object id, which the DATA of its requests carries


def _first_sample(capture):
    return next(i for i, (_b, data) in enumerate(capture.steps)
                if data[0] > 0x80 and len(data) > 4 and data[4] == C.WRITE_DATA)


def _reply_template(capture):
    """The firmware's first recorded reply: (message bytes, offset of its WRITE_DATA body)."""
    for _boot, data in capture.steps:
        if data[0] > 0x80 and data[1] == FIRMWARE_STREAM and len(data) > 8 and \
                data[4] == C.WRITE_DATA and data[10:12] == REPLIER_OBJECT:
            return bytearray(data), 8
    raise RuntimeError("no reply in the capture")


class FirmwareReplier:
    """The firmware after its set-up, answering every request on a thread of its own.

    ``reply(identity, a, b)`` gives the reply's sample bytes (identity, then the CDR body) or None
    for no reply; the default is the firmware's: the identity and ``a + b``. ``requests`` keeps
    every request's sample (identity, then body) as it arrived."""

    def __init__(self, port, domain_id, reply=None):
        self.capture = Capture("main")
        self.channel = UdpChannel(port)
        self.replay = Replayer(self.capture, self.channel, domain_id=domain_id)
        until = _first_sample(self.capture)
        self.replay.run(until_step=until)
        statuses = self.replay.answers.statuses
        if statuses.get((0, 0x0012), (0, None))[1] != C.STATUS_OK:
            raise RuntimeError("the replier's CREATE was not answered OK: %r" % (statuses,))
        self.seq = 1 + max(d[2] | (d[3] << 8) for b, d in self.capture.steps[:until]
                           if d[0] > 0x80 and d[1] == FIRMWARE_STREAM)
        self.template, self.body = _reply_template(self.capture)
        self.reply = reply or (lambda identity, a, b: identity + struct.pack("<q", a + b))
        self.request_id = 0x0100
        self.answered = 0
        self.requests = []
        self.requested_at = {}  # a -> perf_counter when its request's DATA arrived
        self.replied_at = {}  # a -> perf_counter when its reply left
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="firmware", daemon=True)
        self._thread.start()

    def send_sample(self, sample: bytes) -> None:
        """One WRITE_DATA of the replier carrying ``sample`` on the firmware's reliable stream."""
        with self._lock:
            message = bytearray(self.template[:self.body + 4])  # headers, request and object id
            message[2:4] = struct.pack("<H", self.seq)
            message[self.body - 2:self.body] = struct.pack("<H", 4 + len(sample))
            message[self.body:self.body + 2] = struct.pack(">H", self.request_id)
            data = bytes(message) + bytes(sample)
            self.replay.unacked[(0, self.seq)] = data
            self.channel.send(0, data)
            self.seq = (self.seq + 1) & 0xFFFF
            self.request_id = 0x0100 + ((self.request_id + 1) & 0x7FFF)

    def _answer(self, identity: bytes, a: int, b: int) -> None:
        sample = self.reply(identity, a, b)
        if sample is None:
            return
        self.replied_at[a] = time.perf_counter()  # before the reply can arrive
        self.send_sample(sample)
        self.answered += 1

    def _run(self) -> None:
        replay = self.replay
        resend_at = time.monotonic() + 0.2
        seen = 0  # of answers.samples[(0, REPLIER_ID)]
        while not self._stop.is_set():
            for boot, message in self.channel.receive(0.05):
                # The agent's reliable stream in order, as the firmware's client library
                # receives it (tests/microros_replay.Answers), acknowledged as it does.
                if replay.answers.note(boot, message):
                    replay._acknack(boot)
                acked = replay.answers.acked.get(boot, 0)
                with self._lock:
                    for key in [k for k in replay.unacked if k[1] < acked]:
                        del replay.unacked[key]
                samples = replay.answers.samples[(0, REPLIER_ID)]
                while seen < len(samples):
                    sample = bytes(samples[seen])
                    seen += 1
                    self.requests.append(sample)
                    if len(sample) < 40:
                        continue
                    a, b = struct.unpack_from("<qq", sample, 24)
                    self.requested_at[a] = time.perf_counter()
                    self._answer(sample[:24], a, b)
            now = time.monotonic()
            if now >= resend_at:  # what the firmware's client does for unacknowledged messages
                with self._lock:
                    for (boot, _seq), data in sorted(replay.unacked.items()):
                        self.channel.send(boot, data)
                resend_at = now + 0.2

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.channel.close()
