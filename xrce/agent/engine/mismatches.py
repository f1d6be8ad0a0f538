"""Board endpoints that cannot reach their peers, named: the part of the engine that turns what
the middleware and the data path find into one WARNING per pair and a count."""

from __future__ import annotations

import logging
import threading
from typing import Optional

from xrce.agent.engine.session import ClientProxy, ObjectEntry
from xrce.agent.observe import entities as words
from xrce.agent.observe.names import address_text, object_id_text

log = logging.getLogger("xrce.agent")

MAX_MISMATCHES_KEPT = 8  # texts kept per endpoint for the stats; all are counted and logged


class Mismatches:
    """Mixin of ``Agent``: board endpoints that cannot reach their peers, named once per pair in
    one WARNING (the board by key and address, the topic, both sides and the fix) and counted in
    ``stats.mismatches``. The middleware finds QoS and type mismatches (``on_mismatch``, from its
    own thread); the data path finds samples too large for a board's stream."""

    def _middleware_mismatch(self, entity, text: str) -> None:
        if self.loop is not None and threading.get_ident() != self._loop_thread:
            try:
                self.loop.call_soon_threadsafe(self._middleware_mismatch, entity, text)
            except RuntimeError:  # the loop has closed: the agent is going
                pass
            return
        client = self.clients.get((entity[0] & 0xFFFFFFFF).to_bytes(4, "big"))
        entry = client.objects.get(entity[1]) if client is not None else None
        self._mismatch(client, entry, text)

    def _mismatch(self, client: Optional[ClientProxy], entry: Optional[ObjectEntry],
                  text: str) -> None:
        self.stats.mismatches += 1
        if client is None or entry is None:  # gone since: still worth the line
            log.warning("mismatch: %s", text)
            return
        kept = entry.info.setdefault("mismatches", [])
        if len(kept) < MAX_MISMATCHES_KEPT:
            kept.append(text)
        log.warning("client %s at %s, %s %s: %s", client.key.hex(),
                    address_text(client.link.name, client.endpoint),
                    words.kind_name(entry.kind), object_id_text(entry.object_id), text)
