"""A restored board's own reliable output streams, set going again by the agent (issue 51).

eProsima's client (2.4.3) sends a HEARTBEAT on a reliable output stream only after its listening
loop waited ``UXR_CONFIG_MIN_HEARTBEAT_TIME_INTERVAL`` (100 ms) without reading anything: each call
that finds a message waiting pushes the timer back. A board fed samples at 10 Hz or more never
sends one; once the old agent is gone its output stream holds messages nobody acknowledged and
waits for an ACKNACK, for ever: its samples on that stream and its service replies never reach
the new process. So the new process sends that ACKNACK first. At the board, an ACKNACK moves the
acknowledged point to ``first_unacked - 1`` whatever it was:

- at or ahead of the board's point (within what it sent), it frees what it names and, with a
  NACK bit set, has everything after it sent again: nothing lost, nothing repeated;
- behind it, the point walks round the whole sequence space, every slot of the history is freed
  (what was sent and never handled is gone), and the board writes again only while its next
  number is at most a history past the new point.

After a clean stop (SIGINT, SIGTERM) the store holds the last number the agent handled on each
of the board's streams, read after the compiled paths were paused: at least what the board had
acknowledged, at most what it sent. ``last + 1`` with the first NACK bit is then exact: the board
sends again what went into the outage, and the input stream starts at ``last``.

After a crash the store holds a checkpoint up to 10 s old, a lower bound. Then the ACKNACK names
a number ``LEAP`` past it, far ahead of anything the board can have reached since (it frees its
whole history, which the outage had filled anyway, and lets it write at once); its next message,
whatever its number, starts the input stream (``ClientProxy.resume_inputs``), and the ACKNACK for
that brings the board's point back to it. What the board sent into the outage is lost then, and
only that. (A board that sent more than ``LEAP`` reliable messages after the last checkpoint is
not caught up this way: 1,600 a second for 10 s.)

A board that does send HEARTBEATs (idle for 100 ms) gets ``GRACE_S`` to say where it is first:
its HEARTBEAT, or any reliable message on that stream, ends the guessing for it. The ACKNACK goes
again with the timed rounds until then, at most ``TRIES`` times; received once, it is a no-op at
the board.
"""

from __future__ import annotations

import logging
from typing import Callable, Dict, Optional, Tuple

from xrce.agent.engine.limits import STREAM_WINDOW
from xrce.wire.streams import InputReliableStream, seq_add
from xrce.wire.submessages import AckNack

log = logging.getLogger("xrce.agent")

GRACE_S = 0.15
LEAP = 0x4000
TRIES = 5


class InputResync:
    """The board's reliable streams still to set going (``ClientProxy.input_resync``):
    stream id -> (the last number the agent handled on it, whether a clean stop wrote it)."""

    __slots__ = ("positions", "started", "created", "tries")

    def __init__(self, positions: Dict[int, Tuple[int, bool]]):
        self.positions = dict(positions)
        self.started: Optional[float] = None
        self.created: Dict[int, InputReliableStream] = {}
        self.tries: Dict[int, int] = {}

    def start(self, client, now: float, send: Callable[[object], None],
              period: float) -> Optional[float]:
        """The board spoke: streams of a clean stop start where they were, at once."""
        self.started = now
        for stream_id, (seq, clean) in self.positions.items():
            if clean and stream_id not in client.in_reliable:
                stream = InputReliableStream(stream_id, STREAM_WINDOW)
                stream.last_handled = seq
                stream.last_announced = seq_add(seq, 1)  # (the first NACK bit: "send again")
                client.in_reliable[stream_id] = self.created[stream_id] = stream
        return self.run(client, now, send, period)

    def _settled(self, client, stream_id: int, seq: int, clean: bool) -> bool:
        stream = client.in_reliable.get(stream_id)
        if not clean:
            return stream is not None  # its first message or HEARTBEAT placed it
        return stream is not self.created.get(stream_id) or stream.last_handled != seq or \
            bool(stream.stored) or stream.last_announced != seq_add(seq, 1)

    def run(self, client, now: float, send: Callable[[object], None],
            period: float) -> Optional[float]:
        """Send what is due; when to come back (None: every stream is going again)."""
        due = None
        for stream_id, (seq, clean) in list(self.positions.items()):
            tries = self.tries.get(stream_id, 0)
            if self._settled(client, stream_id, seq, clean) or tries >= TRIES:
                del self.positions[stream_id]
                continue
            if not clean and now < self.started + GRACE_S:
                at = self.started + GRACE_S
            else:
                if clean:
                    first, bitmap = seq_add(seq, 1), 1
                else:
                    first, bitmap = seq_add(seq, LEAP + 1), 0
                if not tries:
                    log.debug("client %s: its reliable stream 0x%02X %s", client.key.hex(),
                              stream_id, "goes on after %d (clean stop)" % seq if clean else
                              "was last seen at %d (crash): asked to go on from %d, what it "
                              "sent into the outage is lost" % (seq, first))
                self.tries[stream_id] = tries + 1
                send(AckNack(first, bitmap, stream_id))
                at = now + period
            due = at if due is None or at < due else due
        return due
