"""Samples from a ROS domain's executor thread to the engine (``-m dds``): delivered right there
under the engine's lock when it is free, else through the asyncio loop, bounded, drop-oldest
(measurements in ``xrce.agent.middleware.ros.domain``'s docstring)."""

from __future__ import annotations

import asyncio
import collections

from xrce.agent.middleware import DataCallback
from xrce.agent.middleware.ros.domain import ENCAPSULATION_SIZE, log


class ReaderHandoff:
    """Samples from the executor thread to ``on_data``: right there under the engine's lock when
    that lock is free and nothing is queued, else on the loop, bounded, drop-oldest."""

    __slots__ = ("loop", "on_data", "lock", "queue", "scheduled", "closed", "delivered",
                 "dropped")

    def __init__(self, loop: asyncio.AbstractEventLoop, on_data: DataCallback, depth: int,
                 lock=None):
        self.loop = loop
        self.on_data = on_data
        self.lock = lock  # the engine's (Middleware.engine_lock); None: always through the loop
        self.queue: collections.deque = collections.deque(maxlen=depth)
        self.scheduled = False
        self.closed = False
        self.delivered = 0
        self.dropped = 0

    def push(self, raw: bytes) -> None:
        """Subscription callback (executor thread)."""
        if self.closed:
            return
        pending = self.queue
        # Never wait for the lock: the loop holds it while it waits for this thread (entity
        # creation). Not while samples are queued either, or this one would overtake them.
        lock = self.lock
        if lock is not None and not self.scheduled and not pending and \
                lock.acquire(blocking=False):
            try:
                self.delivered += 1
                self.on_data(raw[ENCAPSULATION_SIZE:])
            except Exception:
                log.exception("on_data failed")
            finally:
                lock.release()
            return
        if len(pending) == pending.maxlen:
            self.dropped += 1
        pending.append(raw[ENCAPSULATION_SIZE:])
        # Ordering with drain(): drain clears the flag before popping, so a sample appended
        # while it runs is either popped by it or schedules a new drain.
        if not self.scheduled:
            self.scheduled = True
            try:
                self.loop.call_soon_threadsafe(self.drain)
            except RuntimeError:  # loop closed: the agent is going away
                self.closed = True

    def drain(self) -> None:
        """Loop thread: deliver at most one queue's worth, then yield to other loop work. Under
        the engine's lock throughout, so that push() cannot deliver a sample between two of
        these."""
        if self.lock is None:
            self._drain()
            return
        with self.lock:
            self._drain()

    def _drain(self) -> None:
        self.scheduled = False
        pending = self.queue
        budget = pending.maxlen
        while pending and not self.closed:
            if budget == 0:
                self.scheduled = True
                self.loop.call_soon(self.drain)
                return
            budget -= 1
            body = pending.popleft()
            self.delivered += 1
            try:
                self.on_data(body)
            except Exception:
                log.exception("on_data failed")
