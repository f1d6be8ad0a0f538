# XRCE message header and submessage framing (XRCE-WIRE.md §1, §2).
#
# Decoding splits a message into ``(id, flags, start, end)`` spans over the original buffer, so the
# hot path (WRITE_DATA/DATA) never copies a payload it only forwards. ``MessageWriter`` appends
# submessages to a reusable buffer, 4-aligned from the message start.

import struct

from xrce import DecodeError, EncodeError, IS_MICROPYTHON, const
from xrce.wire import cdr

# xrce.wire.constants names these too; local constants fold into the code and spare a board that module.
_CREATE_CLIENT = const(0)
_SESSION_ID_WITHOUT_KEY_MASK = const(0x80)
_SUBHEADER_SIZE = const(4)

# WRITE_DATA and DATA: a sample longer than 64 KiB is written with length 0, "to the end of the
# message", as the eProsima C client does; such a message only ever travels in FRAGMENTs.
_OPEN_ENDED = (7, 9)

_HEADER_SIZE_NO_KEY = const(4)
_HEADER_SIZE_WITH_KEY = const(8)


def header_size(session_id):
    return _HEADER_SIZE_WITH_KEY if session_id < _SESSION_ID_WITHOUT_KEY_MASK else _HEADER_SIZE_NO_KEY


# Header and decode_header live in xrce/wire/message_header.py and load on first use: the agent decodes
# headers, a client checks the few header bytes it needs inline and never pays for them.
def __getattr__(name):
    if name == "Header" or name == "decode_header":
        from xrce.wire import message_header

        value = getattr(message_header, name)
        globals()[name] = value
        return value
    raise AttributeError(name)


def iter_submessages(buf, start, end=None):
    # Yield ``(submessage_id, flags, payload_start, payload_end)`` for the submessages in buf[start:end].
    #
    # Submessage headers sit at 4-aligned offsets from the message start (offset 0 of buf); parsing
    # stops when fewer than 4 bytes remain. A length running past the end is a DecodeError. The
    # CREATE_CLIENT length is not trusted (the eProsima client writes 16 even with properties), so its
    # span runs to the end of the message.
    end = len(buf) if end is None else end
    pos = start
    while end - pos >= _SUBHEADER_SIZE:
        sub_id = buf[pos]
        flags = buf[pos + 1]
        length = buf[pos + 2] | (buf[pos + 3] << 8)
        payload_start = pos + _SUBHEADER_SIZE
        payload_end = payload_start + length
        if sub_id == _CREATE_CLIENT:
            payload_end = end
        elif payload_end > end:
            raise DecodeError("submessage %d length %d runs past the message end" % (sub_id, length))
        yield sub_id, flags, payload_start, payload_end
        pos = (payload_end + 3) & ~3


class MessageWriter(cdr.CdrWriter):
    # Builds one message in a reusable buffer: a CdrWriter whose origin is the message start (as
    # both eProsima peers align), which ``begin`` starts with a header and ``begin_submessage`` /
    # ``end_submessage`` frame payloads in. ``begin_submessage`` returns the writer itself, to write
    # the payload with.

    if not IS_MICROPYTHON:  # a board ignores __slots__ and would keep the tuple
        __slots__ = ("_sub_start",)

    def __init__(self, capacity=512):
        cdr.CdrWriter.__init__(self, bytearray(capacity), 0, 0)
        self._sub_start = -1

    def begin(self, session_id, stream_id, seq, key=None):
        # Write the header (XRCE-WIRE.md §1) and start the message after it.
        buf = self.buf
        buf[0] = session_id
        buf[1] = stream_id
        self.set_seq(seq)
        size = _HEADER_SIZE_NO_KEY
        if session_id < _SESSION_ID_WITHOUT_KEY_MASK:
            if key is None or len(key) != 4:
                raise EncodeError("a session id below 0x80 needs a 4-byte client key")
            buf[4:8] = key
            size = _HEADER_SIZE_WITH_KEY
        self.reset(size, 0)
        return self

    def set_seq(self, seq):
        self.buf[2] = seq & 0xFF
        self.buf[3] = (seq >> 8) & 0xFF

    def begin_submessage(self, sub_id, flags):
        self.align(4)
        self.reserve(_SUBHEADER_SIZE)
        pos = self.pos
        self.buf[pos] = sub_id
        self.buf[pos + 1] = flags
        self._sub_start = pos
        self.pos = pos + _SUBHEADER_SIZE
        return self

    def end_submessage(self, length=None):
        # Patch the length of the open submessage (``length`` overrides the measured one).
        if length is None:
            length = self.pos - self._sub_start - _SUBHEADER_SIZE
        if length > 0xFFFF:
            if self.buf[self._sub_start] not in _OPEN_ENDED:
                raise EncodeError("submessage payload longer than 65535 bytes")
            length = 0  # a sample running to the end of the message, sent in FRAGMENTs (§8)
        struct.pack_into("<H", self.buf, self._sub_start + 2, length)
        self._sub_start = -1

    def pad_to_4(self):
        self.align(4)

    def view(self):
        return memoryview(self.buf)[:self.pos]
