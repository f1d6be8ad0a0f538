"""``--capture FILE``: every message an agent receives or sends, one text line each::

      <unix time, s> <in|out> <link> <endpoint> <message hex>

``CaptureWriter`` is the engine's tap (``Agent.tap``) that writes the file; ``read_capture`` parses
it back and ``decode_capture`` runs each message through the wire decoder
(``xrce.submessages.decode_message``), e.g. to replay a bug report.
"""

from __future__ import annotations

import time

from xrce.agent.observability import endpoint_text


class CaptureWriter:
    """The engine's tap: one line per message (see the module docstring for the format)."""

    def __init__(self, path: str):
        self.path = path
        self.file = open(path, "w", encoding="ascii")
        self.file.write("# xrce-agent capture: time direction link endpoint hex\n")
        self.records = 0

    def __call__(self, direction: str, link, endpoint, data) -> None:
        self.file.write("%.6f %s %s %s %s\n" % (time.time(), direction,
                                                getattr(link, "name", "link"),
                                                endpoint_text(endpoint), bytes(data).hex()))
        self.records += 1

    def flush(self) -> None:
        if not self.file.closed:
            self.file.flush()

    def close(self) -> None:
        if not self.file.closed:
            self.file.close()


class CapturedMessage:
    __slots__ = ("time", "direction", "link", "endpoint", "data")

    def __init__(self, time_s, direction, link, endpoint, data):
        self.time = time_s
        self.direction = direction
        self.link = link
        self.endpoint = endpoint
        self.data = data

    def __repr__(self):
        return "CapturedMessage(%.6f, %r, %r, %r, %s)" % (self.time, self.direction, self.link,
                                                        self.endpoint, self.data.hex())


def read_capture(path: str):
    """Every message of a capture file, in order; ValueError on a line that is not a record."""
    with open(path, encoding="ascii") as lines:
        for number, line in enumerate(lines, 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            parts = line.split(" ")
            if len(parts) != 5 or parts[1] not in ("in", "out"):
                raise ValueError("%s:%d: not a capture record" % (path, number))
            yield CapturedMessage(float(parts[0]), parts[1], parts[2], parts[3],
                                  bytes.fromhex(parts[4]))


def decode_capture(path: str):
    """``(CapturedMessage, header, payloads)`` per record, decoded by the wire core; a message
    that does not decode gives ``(record, None, DecodeError)`` so a bug report still reads."""
    from xrce.errors import DecodeError
    from xrce.submessages import decode_message

    for record in read_capture(path):
        try:
            header, payloads = decode_message(record.data)
        except DecodeError as exc:
            yield record, None, exc
        else:
            yield record, header, payloads


__all__ = ["CaptureWriter", "CapturedMessage", "decode_capture", "read_capture"]
