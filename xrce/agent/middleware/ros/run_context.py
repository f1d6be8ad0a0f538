"""What the ROS middleware's parts get from outside the middleware: the asyncio loop they run
on, and what the engine sets on its middleware after building it (``Middleware.engine_lock``,
``Middleware.on_mismatch``). ``RosMiddleware`` makes one ``RunContext`` and hands it to each part
that needs any of it; its ``engine_lock`` and ``on_mismatch`` properties write here."""

from __future__ import annotations

import asyncio

from xrce.agent.middleware import EntityKey
from xrce.agent.middleware.ros.domain import log


class RunContext:
    def __init__(self):
        self._loop: asyncio.AbstractEventLoop | None = None
        self.engine_lock = None  # the engine's lock (Middleware.engine_lock), None until set
        self.on_mismatch = None  # on_mismatch(entity, text) (Middleware.on_mismatch)

    def loop(self) -> asyncio.AbstractEventLoop:
        """The loop every public method of the middleware runs on: the running one, at first use."""
        if self._loop is None:
            self._loop = asyncio.get_running_loop()
        return self._loop

    def start(self) -> None:
        self._loop = asyncio.get_running_loop()

    def report_mismatch(self, entity: EntityKey, text: str) -> None:
        """A board endpoint cannot talk to a ROS peer: to the engine's hook, else the log."""
        hook = self.on_mismatch
        if hook is not None:
            hook(entity, text)
        else:
            log.warning("%r: %s", entity, text)
