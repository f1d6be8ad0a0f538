"""Replaying real PX4 traffic (tests/golden/px4/, see its README) against a live agent.

PX4's ``uxrce_dds_client`` is an XRCE client like micro-ROS firmware, so the replay is
tests/helpers/microros_replay.py's ``Replayer`` with what PX4 does differently:

- a capture names its PX4 instances (``peer``: one UDP source address each, the second boot of a
  restarted PX4 included); each gets its own socket, and the two vehicles of ``px4_two`` interleave
  as they did, each paced on its own answers: PX4 waits for the STATUS of each reliable message
  before its next one and for each TIMESTAMP_REPLY before its next TIMESTAMP (the base replayer's
  waits);
- the HEARTBEATs PX4 sent about its reliable stream are rewritten to what this replay has in
  flight (sent only while something is, as the client library does), like its ACKNACKs; nothing
  else is rewritten (besides the participant's domain id, so that a test's ROS graph stays its own,
  and with ``answer_requests`` the sample identity of PX4's service replies).

``Px4Capture`` holds PX4's side by instance and what eProsima's agent answered, by meaning
(microros_replay.Answers), so a test compares the two.
"""

from __future__ import annotations

import gzip
import json
from pathlib import Path

from microros_replay import Answers, Capture, Replayer, _submessages
from xrce.wire import constants as C

CAPTURES = Path(__file__).resolve().parents[1] / "golden" / "px4"
NAMES = ("px4_main", "px4_restart", "px4_two")
FIRMWARE_STREAM = 0x80  # PX4's reliable output, and the agent's reliable output to PX4

# The replier PX4 creates for its one service (the README's "Replier"); the same id in every
# instance.
REPLIER = 0x8008


class Px4Capture(Capture):
    """One capture: PX4's messages by instance (``peer``), and eProsima's answers to each."""

    def __init__(self, name: str):
        self.name = name
        with gzip.open(str(CAPTURES / (name + ".jsonl.gz")), "rt") as lines:
            self.records = [json.loads(line) for line in lines]
        self.steps = []  # (peer, bytes) of every c2a message
        self.times = []
        self.eprosima = Answers()
        for record in self.records:
            data = bytes.fromhex(record["hex"])
            if record["dir"] == "c2a":
                self.steps.append((record["peer"], data))
                self.times.append(record["t"])
            else:
                self.eprosima.note(record["peer"], data)
        self.boots = 1 + max(peer for peer, _ in self.steps)

    def submessages(self, wanted: int):
        """(step index, peer, body) of every submessage ``wanted`` PX4 sent in a session."""
        for index, (peer, data) in enumerate(self.steps):
            if data[0] > 0x80:
                for sub_id, _flags, body in _submessages(data, 4):
                    if sub_id == wanted:
                        yield index, peer, body

    def step_of_first(self, wanted: int, peer: int | None = None) -> int:
        """Index of the first step carrying a ``wanted`` submessage (of ``peer``, if given)."""
        return next(index for index, sender, _body in self.submessages(wanted)
                    if peer is None or sender == peer)

    def read_requests(self):
        """{(peer, request id): datareader or replier id} of every READ_DATA."""
        return {(peer, (body[0] << 8) | body[1]): (body[2] << 8) | body[3]
                for _index, peer, body in self.submessages(C.READ_DATA)}

    def replier_reply_steps(self):
        """Step indexes of PX4's service replies (WRITE_DATA from the replier)."""
        return [index for index, _peer, body in self.submessages(C.WRITE_DATA)
                if ((body[2] << 8) | body[3]) == REPLIER]


class Px4Replayer(Replayer):
    """``Replayer`` for PX4 captures (module docstring): HEARTBEATs rewritten to the replay's own
    reliable stream."""

    def _send(self, boot: int, data: bytes) -> None:
        if data[0] > 0x80 and data[1] == 0 and len(data) > 4 and data[4] == C.HEARTBEAT:
            pending = sorted(seq for peer, seq in self.unacked if peer == boot)
            if not pending:
                return  # nothing of ours unacknowledged: a live PX4 would not send it
            order = "little" if data[5] & C.FLAG_LITTLE_ENDIAN else "big"
            body = pending[0].to_bytes(2, order) + pending[-1].to_bytes(2, order) + \
                bytes([FIRMWARE_STREAM])
            header = bytes([C.HEARTBEAT, data[5], len(body), 0])
            data = data[:4] + header + body
        super()._send(boot, data)
