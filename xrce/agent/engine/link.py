"""A transport server as the engine sees it (``Link``); the links themselves are ``xrce.agent.links``."""

from __future__ import annotations

from typing import Any, Optional, Protocol, Sequence


class Link(Protocol):
    """A transport server as the engine sees it. Every link has all of these (the links' common
    base, ``xrce.agent.links.Link``, gives the defaults): the engine reads them plainly."""

    name: str
    # True when send() may be called from any thread: the engine then sends a sample from the
    # middleware's thread without waking the loop (asyncio transports are loop-only).
    sends_from_any_thread: bool
    # The compiled receive path reading this link's socket (``engine.compiled.fastpath.FastPath``),
    # which the data path offers what it may take over; None where Python reads (every link but
    # UDP, and UDP without the extension).
    fastpath: Optional[Any]
    # The locators an INFO answering a GET_INFO on this link names (XRCE-WIRE.md §10): none but
    # where a test names some.
    info_locators: Sequence[Any]

    def send(self, endpoint: Any, data: bytes) -> None: ...
