"""A transport server as the engine sees it (``Link``); the links themselves are ``xrce.agent.links``."""

from __future__ import annotations

from typing import Any, Protocol


class Link(Protocol):
    """A transport server as the engine sees it."""

    name: str
    sends_from_any_thread: bool

    def send(self, endpoint: Any, data: bytes) -> None: ...
