"""Messages out of the agent, whatever part sends them: counted, traced at ``-v 6``, shown to the
capture tap, and handed to the client's link (XRCE-WIRE.md §1)."""

from __future__ import annotations

import logging
from typing import Any, Callable, Hashable, Optional

from xrce.wire import constants as C, names as wire_names
from xrce.agent.log_levels import TRACE
from xrce import DecodeError
from xrce.wire.message import header_size, iter_submessages
from xrce.wire.submessages import encode_message

log = logging.getLogger("xrce.agent")


class Output:
    """Sends whole messages: to an endpoint (``send_raw``: replies outside a session), to a
    client (``send_client``: counted per client too) or as one submessage on a client's stream
    none (``send_stream0``). Streams with sequence numbers are ``StreamOutput``'s
    (xrce.agent.engine.stream_output)."""

    def __init__(self, stats):
        self.stats = stats
        # Called as tap(direction, link, endpoint, message) for every message in ("in") and out
        # ("out"), e.g. by a capture file (xrce.agent.observe.capture); None costs one test.
        # ``Agent.tap`` sets it.
        self.tap: Optional[Callable[[str, Any, Hashable, bytes], None]] = None
        # The clients (by key) whose reliable input owes an ACKNACK, and what sends it
        # (Acknowledgments, which sets both): anything else sent to such a client goes after its
        # ACKNACK, so no reply the client reacts to can outrun the acknowledgment its history
        # waits for.
        self.owed: dict = {}
        self.settle: Optional[Callable[[Any], None]] = None

    def send_raw(self, link, endpoint: Hashable, message: bytes) -> None:
        stats = self.stats
        stats.messages_out += 1
        stats.bytes_out += len(message)
        if log.isEnabledFor(TRACE):
            trace("out", link, endpoint, message, header_size(message[0]))
        if self.tap is not None:
            self.tap("out", link, endpoint, message)
        link.send(endpoint, message)

    def send_client(self, client, message: bytes) -> None:
        if self.owed and client.key in self.owed:
            self.settle(client)
        client.messages_out += 1
        client.bytes_out += len(message)
        self.send_raw(client.link, client.endpoint, message)

    def send_stream0(self, client, payload) -> None:
        self.send_client(client, encode_message(
            client.session_id, C.STREAM_NONE, 0, client.header_key, [payload]))


def trace(direction: str, link, endpoint: Hashable, data: bytes, start: int) -> None:
    """One message at the TRACE level: its header, its submessages by name, its bytes."""
    try:
        names = [wire_names.SUBMESSAGE_NAMES.get(sub_id, str(sub_id))
                 for sub_id, _, _, _ in iter_submessages(data, start)]
    except DecodeError:
        names = ["<malformed>"]
    log.log(TRACE, "%s %s %r session 0x%02X stream 0x%02X seq %d: %s | %s", direction, link.name,
            endpoint, data[0], data[1], data[2] | (data[3] << 8), " ".join(names), data.hex())
