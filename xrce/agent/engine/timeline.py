"""Recovery timelines: where the time goes when a client comes back (issue 12).

A client "comes back" when the agent sees a CREATE_CLIENT for a key whose session it still holds
(a board that reset), or for a session it heard traffic from without knowing it (the agent itself
restarted while the client kept talking). For such a client the agent notes, as offsets from the
first datagram of the comeback:

- first datagram seen (traffic of the unknown session, or the CREATE_CLIENT itself),
- session established (STATUS_AGENT OK sent),
- entities re-created (the last CREATE answered OK or OK_MATCHED so far, and how many),
- READ_DATAs restored (the last READ_DATA so far, and how many),
- first sample published into ROS (the first WRITE_DATA the middleware accepted),

and logs them as one line at INFO (the default verbosity) once the first sample went into ROS, or,
for a client that publishes nothing, once it has been quiet for ``SETTLE_S`` after its last
READ_DATA or ``GIVE_UP_S`` after the first datagram. The last ``KEEP`` timelines are kept for
``xrce-agent stats``.

"First sample published into ROS" is when rclpy accepted it. Whether a ROS subscriber receives it
then depends on DDS discovery between the agent's participant and the subscriber's, which the
agent cannot observe per sample (bench/restart/restart_gap.py measures the whole gap from the subscriber).
"""

from __future__ import annotations

import collections
import logging
from typing import Any, Deque, Dict, Hashable, List, Optional

from xrce.wire import constants as C
from xrce.agent.observe.timeline_text import format_timeline

log = logging.getLogger("xrce.agent")

KEEP = 32  # finished timelines kept for the stats view
MAX_UNKNOWN = 1024  # unknown sessions remembered at once (oldest forgotten first)
UNKNOWN_TTL_S = 30.0  # traffic older than this does not count as the start of a comeback
SETTLE_S = 1.0  # a client without writers: done this long after its last READ_DATA
GIVE_UP_S = 10.0  # report whatever was reached by then
TIMELINE_CHECK_S = 0.5  # how often the engine's timer looks at pending timelines


class Timeline:
    """The phases of one comeback, as agent clock times (None until reached)."""

    __slots__ = ("key", "cause", "origin", "established", "created", "creates", "read",
                 "reads", "first_sample", "writers")

    def __init__(self, key: bytes, cause: str, origin: float, established: float):
        self.key = key
        self.cause = cause
        self.origin = origin
        self.established = established
        self.created: Optional[float] = None
        self.creates = 0
        self.read: Optional[float] = None
        self.reads = 0
        self.first_sample: Optional[float] = None
        self.writers = 0

    def _offset(self, moment: Optional[float]) -> Optional[float]:
        return None if moment is None else round(moment - self.origin, 3)

    def as_dict(self) -> Dict[str, Any]:
        return {"key": self.key.hex(), "cause": self.cause,
                "first_datagram_s": 0.0,
                "session_established_s": self._offset(self.established),
                "entities_recreated_s": self._offset(self.created), "entities": self.creates,
                "read_data_restored_s": self._offset(self.read), "read_datas": self.reads,
                "first_sample_to_ros_s": self._offset(self.first_sample)}

    def line(self) -> str:
        return format_timeline(self.as_dict())


class RecoveryTimelines:
    """Fed by the engine's hooks; cheap when nothing is pending (one truth test per sample)."""

    def __init__(self, clock):
        self.clock = clock
        # (link, endpoint) or client key -> when traffic of a session the agent did not know
        # first arrived from there.
        self._unknown: "collections.OrderedDict[Hashable, float]" = collections.OrderedDict()
        self.pending: Dict[bytes, Timeline] = {}
        self.recent: Deque[Dict[str, Any]] = collections.deque(maxlen=KEEP)

    # -- hooks --------------------------------------------------------------------------------

    def unknown_traffic(self, link, endpoint: Hashable, header) -> None:
        """A message of a session the agent does not know (what a restarted agent first sees)."""
        now = self.clock()
        where = header.key if header.session_id < C.SESSION_ID_WITHOUT_KEY_MASK else (link, endpoint)
        if where in self._unknown:
            return
        self._unknown[where] = now
        while len(self._unknown) > MAX_UNKNOWN:
            self._unknown.popitem(last=False)

    def established(self, client, restarted: bool) -> None:
        """STATUS_AGENT OK for ``client``; ``restarted``: the agent still held its session."""
        now = self.clock()
        seen = [self._unknown.pop(where, None) for where in (client.key, (client.link, client.endpoint))]
        seen = [t for t in seen if t is not None and now - t <= UNKNOWN_TTL_S]
        if restarted:
            cause = "session restarted by the client"
        elif seen:
            cause = "session unknown to this agent"
        else:
            self.pending.pop(client.key, None)
            return  # a client connecting for the first time: not a comeback
        origin = min(seen) if seen else now
        self.pending[client.key] = Timeline(client.key, cause, origin, now)

    def created(self, client, request, status: int) -> None:
        timeline = self.pending.get(client.key)
        if timeline is None or status not in (C.STATUS_OK, C.STATUS_OK_MATCHED):
            return
        timeline.created = self.clock()
        timeline.creates += 1
        if getattr(request, "kind", None) == C.OBJK_DATAWRITER:
            timeline.writers += 1

    def read_data(self, client) -> None:
        timeline = self.pending.get(client.key)
        if timeline is not None:
            timeline.read = self.clock()
            timeline.reads += 1

    def sample_into_ros(self, client) -> None:
        timeline = self.pending.get(client.key)
        if timeline is not None:
            timeline.first_sample = self.clock()
            self._finish(timeline)

    def forget(self, client) -> None:
        timeline = self.pending.get(client.key)
        if timeline is not None:
            self._finish(timeline)

    def tick(self, now: float) -> None:
        """Report comebacks that will not reach "first sample into ROS" (see module doc)."""
        for timeline in list(self.pending.values()):
            settled = (timeline.writers == 0 and timeline.read is not None
                       and now - timeline.read >= SETTLE_S)
            if settled or now - timeline.origin >= GIVE_UP_S:
                self._finish(timeline)

    # -- results ------------------------------------------------------------------------------

    def _finish(self, timeline: Timeline) -> None:
        if self.pending.get(timeline.key) is timeline:
            del self.pending[timeline.key]
        self.recent.append(timeline.as_dict())
        log.info("%s", timeline.line())

    def snapshot(self) -> List[Dict[str, Any]]:
        return list(self.recent)
