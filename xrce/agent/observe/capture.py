"""``--capture FILE``: every message an agent receives or sends, one text line each::

      <unix time, s> <in|out> <link> <endpoint> <message hex>

``CaptureWriter`` is the engine's tap (``Agent.tap``) that writes the file; ``read_capture`` parses
it back and ``decode_capture`` runs each message through the wire decoder
(``xrce.wire.submessages.decode_message``), e.g. to replay a bug report.

Capture files travel (bug reports) and anyone on the network decides what goes into them, so:

- A client key never appears in clear. Wherever it sits in a message (the header of a session with
  a key, the CREATE_CLIENT payload) the file holds the client's 4-byte pseudonym instead
  (``names.client_pseudonym``, whose hex is the tag the stats and /diagnostics show):
  every message still decodes, one client's messages still carry one key, but a capture handed
  around cannot be used to take over a session. Everything else is the bytes on the wire.
- The file is created 0600 (it shows traffic of every client).
- It is bounded: past ``max_bytes`` the file is rotated (``FILE`` -> ``FILE.1`` -> ... ->
  ``FILE.<files-1>``, the oldest dropped), so a flood fills ``max_bytes * files`` at most.
"""

from __future__ import annotations

import os
import time

from xrce.wire import constants as C
from xrce.agent.observe.names import client_pseudonym, endpoint_text
from xrce.wire.message import header_size, iter_submessages

_HEADER_LINE = "# xrce-agent capture: time direction link endpoint hex\n"
_CLIENT_KEY_OFFSET = 8  # in CREATE_CLIENT: cookie (4), version (2), vendor id (2), key (4)


def mask_client_keys(data) -> bytes:
    """``data`` with every client key replaced by that client's pseudonym (module docstring)."""
    if not data:
        return bytes(data)
    masked = bytearray(data)
    size = header_size(masked[0])
    if masked[0] < C.SESSION_ID_WITHOUT_KEY_MASK and len(masked) >= size:
        masked[4:8] = client_pseudonym(masked[4:8])
    try:
        for sub_id, _flags, start, end in iter_submessages(masked, size):
            key_at = start + _CLIENT_KEY_OFFSET
            if sub_id == C.CREATE_CLIENT and end >= key_at + 4:
                masked[key_at:key_at + 4] = client_pseudonym(masked[key_at:key_at + 4])
    except Exception:  # a malformed message: what could be parsed is masked, the rest is as sent
        pass
    return bytes(masked)


def _open_private(path: str):
    """``path`` truncated for writing, readable by its owner only (also when it existed before)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.fchmod(fd, 0o600)
        return os.fdopen(fd, "w", encoding="ascii")
    except BaseException:
        os.close(fd)
        raise


class CaptureWriter:
    """The engine's tap: one line per message (see the module docstring for the format)."""

    def __init__(self, path: str, max_bytes: int, files: int):
        # No defaults here: they are the command line's (observability.CAPTURE_MAX_BYTES, _FILES).
        self.path = path
        self.max_bytes = max_bytes
        self.files = max(1, files)
        self.records = 0
        self.rotations = 0
        self.file = None
        self._open()

    def _open(self) -> None:
        self.file = _open_private(self.path)
        self.file.write(_HEADER_LINE)
        self.size = len(_HEADER_LINE)

    def _rotate(self) -> None:
        self.file.close()
        if self.files == 1:
            os.unlink(self.path)
        else:
            for index in range(self.files - 1, 1, -1):
                older = "%s.%d" % (self.path, index - 1)
                if os.path.exists(older):
                    os.replace(older, "%s.%d" % (self.path, index))
            os.replace(self.path, self.path + ".1")
        self.rotations += 1
        self._open()

    def __call__(self, direction: str, link, endpoint, data) -> None:
        line = "%.6f %s %s %s %s\n" % (time.time(), direction, getattr(link, "name", "link"),
                                       endpoint_text(endpoint), mask_client_keys(data).hex())
        if self.size + len(line) > self.max_bytes and self.size > len(_HEADER_LINE):
            self._rotate()
        self.file.write(line)
        self.size += len(line)
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
    from xrce import DecodeError
    from xrce.wire.submessages import decode_message

    for record in read_capture(path):
        try:
            header, payloads = decode_message(record.data)
        except DecodeError as exc:
            yield record, None, exc
        else:
            yield record, header, payloads


__all__ = ["CaptureWriter", "CapturedMessage", "decode_capture", "mask_client_keys",
           "read_capture"]
