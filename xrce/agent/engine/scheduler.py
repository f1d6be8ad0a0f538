"""When the agent's timed work runs, and which thread the engine's loop is: the wake-ups of the
engine (XRCE-WIRE.md §10).

Nothing is polled: the timed work (``Agent.tick``: HEARTBEATs, liveliness, paced delivery) runs
from one loop timer (``loop.call_at``) set for the earliest time something is due. Any part that
makes something due asks ``wake_at``; reliable output asks ``heartbeat_soon``. The parts that run
on the middleware's thread too ask ``on_loop_thread`` before they touch the loop's objects.
"""

from __future__ import annotations

import asyncio
import math
import threading
from typing import Callable, Optional

NEVER = math.inf


class Scheduler:
    """The engine's loop, its thread, and the one timer of its timed work.

    ``on_due`` runs when the timer fires (the agent's ``tick``). ``clock`` is the agent's clock
    (tests substitute a fake one: ``Agent.clock`` hands it to every part)."""

    def __init__(self, clock: Callable[[], float], heartbeat_period: float,
                 on_due: Callable[[], None], loop: Optional[asyncio.AbstractEventLoop] = None):
        self.clock = clock
        self.heartbeat_period = heartbeat_period
        self.loop = loop
        self.thread = threading.get_ident()  # the thread the loop runs on, once started
        self._on_due = on_due
        self._timer: Optional[asyncio.TimerHandle] = None
        self.due = NEVER  # when the timer fires; NEVER while none is set

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        """The engine runs on ``loop``, from the calling thread (``Agent.start``)."""
        if self.loop is None:
            self.loop = loop
        self.thread = threading.get_ident()

    def on_loop_thread(self) -> bool:
        return threading.get_ident() == self.thread

    @property
    def next_wakeup(self) -> Optional[float]:
        return None if self._timer is None else self.due

    def wake_at(self, due: float) -> None:
        """Run the timed work at ``due`` (agent clock) unless it is already set to run sooner."""
        if due >= self.due or self.loop is None:
            return
        if threading.get_ident() != self.thread:
            # Output sent from the middleware's thread (datapath): the loop owns its timers.
            self.loop.call_soon_threadsafe(self.wake_at, due)
            return
        if self._timer is not None:
            self._timer.cancel()
        self.due = due
        delay = due - self.clock()
        self._timer = self.loop.call_at(self.loop.time() + (delay if delay > 0 else 0.0),
                                        self._fire)

    def heartbeat_soon(self) -> None:
        """Reliable output went out: its HEARTBEAT round is due one period from now."""
        due = self.clock() + self.heartbeat_period
        if due < self.due:
            self.wake_at(due)

    def _fire(self) -> None:
        self._timer = None
        self.due = NEVER
        self._on_due()

    def cancel(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self._timer = None
        self.due = NEVER
