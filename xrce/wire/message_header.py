# The XRCE message header as an object (XRCE-WIRE.md §1), for the agent and the tools.
#
# Importable as xrce.wire.message.Header and xrce.wire.message.decode_header, whose __getattr__ loads this
# module on first use; a client never does. It imports nothing from xrce.wire.message, so the two do not
# import each other: the header's size follows from its first byte by the rule decode_header applies
# (xrce.wire.message.header_size states it for the client, which never loads this module).

from xrce import DecodeError

_SESSION_ID_WITHOUT_KEY_MASK = 0x80
HEADER_SIZE_NO_KEY = 4
HEADER_SIZE_WITH_KEY = 8


class Header:
    __slots__ = ("session_id", "stream_id", "seq", "key", "size")

    def __init__(self, session_id, stream_id, seq, key=None):
        self.session_id = session_id
        self.stream_id = stream_id
        self.seq = seq
        self.key = key
        self.size = HEADER_SIZE_WITH_KEY if session_id < _SESSION_ID_WITHOUT_KEY_MASK else HEADER_SIZE_NO_KEY

    def __eq__(self, other):
        return (isinstance(other, Header) and self.session_id == other.session_id
                and self.stream_id == other.stream_id and self.seq == other.seq and self.key == other.key)

    def __repr__(self):
        return "Header(session=0x%02X, stream=0x%02X, seq=%d, key=%r)" % (
            self.session_id, self.stream_id, self.seq, self.key)


def decode_header(buf, length=None):
    # Header of the message in ``buf[:length]``; DecodeError if it is shorter than its header.
    n = len(buf) if length is None else length
    if n < HEADER_SIZE_NO_KEY:
        raise DecodeError("message shorter than its header")
    session_id = buf[0]
    key = None
    if session_id < _SESSION_ID_WITHOUT_KEY_MASK:
        if n < HEADER_SIZE_WITH_KEY:
            raise DecodeError("keyed message shorter than its header")
        key = bytes(buf[4:8])
    return Header(session_id, buf[1], buf[2] | (buf[3] << 8), key)
