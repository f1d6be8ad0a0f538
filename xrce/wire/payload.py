"""What every submessage payload shares (XRCE-WIRE.md §2): the ``Payload`` base, the encodings of
request/object ids and property lists, and ``write_submessage``, which appends a payload to a
message.

Each payload class has ``ID``, a ``flags`` attribute, ``encode(w)`` writing the payload into a
CdrWriter whose origin is the message start, and ``decode(r, flags)`` reading it back. The classes
live in ``xrce.wire.session_payloads`` and ``xrce.wire.stream_payloads``; ``xrce.wire.submessages`` decodes whole
messages. A client feature that needs a few payloads (discovery) imports them from their module and
``write_submessage`` from here, so a board does not load the whole codec.
"""

from xrce.wire import constants as C
from xrce import DecodeError


def write_id(w, value):
    # Request and object ids are 16-bit ints sent big-endian (raw byte pairs, no CDR alignment).
    w.u8((value >> 8) & 0xFF)
    w.u8(value & 0xFF)


def read_id(r):
    return (r.u8() << 8) | r.u8()


def write_properties(w, properties):
    w.boolean(properties is not None)
    if properties is not None:
        w.u32(len(properties))
        for name, value in properties:
            w.string(name)
            w.string(value)


def read_properties(r):
    if not r.boolean():
        return None
    count = r.u32()
    if count * 10 > r.remaining():
        raise DecodeError("property count exceeds the payload")
    return [(r.string(), r.string()) for _ in range(count)]


class Payload:
    ID = -1
    __slots__ = ("flags",)

    def __eq__(self, other):
        return type(self) is type(other) and all(
            getattr(self, name) == getattr(other, name) for name in self.FIELDS)

    def __repr__(self):
        return "%s(%s)" % (type(self).__name__, ", ".join(
            "%s=%r" % (name, getattr(self, name)) for name in self.FIELDS))


def write_submessage(mw, payload):
    """Append ``payload`` as a submessage to a MessageWriter."""
    payload.encode(mw.begin_submessage(payload.ID, payload.flags))
    # The eProsima client writes length 16 for CREATE_CLIENT even when properties follow (§3).
    mw.end_submessage(16 if payload.ID == C.CREATE_CLIENT else None)
