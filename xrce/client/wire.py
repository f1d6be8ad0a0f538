# What a client session writes: the submessages it sends and the binary object representations of
# the entities it creates, lean enough for a board.
#
# The general codec (xrce/submessages.py, xrce/objects.py) has one class per submessage and per
# object kind, each with encode and decode and a repr: what the agent needs, and ~22 KB of heap on
# a board that would only ever use a few encoders. These functions write the same bytes for the
# cases a client produces; tests/test_client_wire.py checks them against the general codec, so
# the wire format still has one reference. Comments, not docstrings: a board keeps docstrings.

from xrce import const
from xrce.cdr import CdrWriter

_OBJK_PARTICIPANT = const(1)
_OBJK_REPLIER = const(8)
_REPRESENTATION_IN_BINARY = const(3)


# CREATE, DELETE, READ_DATA and WRITE_DATA: the request and object ids, then a body prepared once
# (bytes) or, for WRITE_DATA, a message encoded in place after an optional prefix (a reply's sample
# identity). A session keeps the bodies of its CREATEs and READ_DATAs to send them again, under new
# request ids, after the agent lost the session; a write allocates nothing here.
def put_request(w, request_id, object_id, body, prefix=None):
    w.u8(request_id >> 8)
    w.u8(request_id & 0xFF)
    w.u8(object_id >> 8)
    w.u8(object_id & 0xFF)
    if prefix is not None:
        w.raw(prefix)
    if isinstance(body, (bytes, bytearray, memoryview)):
        w.raw(body)
    else:
        saved = w.origin
        w.origin = w.pos  # a sample is aligned from its own first byte (§14)
        try:
            body.encode(w)
        finally:
            w.origin = saved


# A payload starts 4-aligned in its message and the ids take 4 bytes, so a body written from
# offset 4 of a scratch buffer aligns exactly as it will in any message.
def _body_writer():
    return CdrWriter(bytearray(48), 4, 0)


def _body(w):
    return bytes(w.buf[4:w.pos])


# A CREATE's body starts with the object kind and, but for a participant (domain id), ends with
# the parent's object id: xrce.client.recovery reads them there.
def create_body(kind, fmt, representation, tail_id):
    # representation: blob bytes (fmt binary) or the XML/reference text.
    w = _body_writer()
    w.u8(kind)
    w.u8(fmt)
    if fmt == _REPRESENTATION_IN_BINARY:
        w.octets(representation)
    else:
        w.string(representation)
    if kind == _OBJK_PARTICIPANT:
        w.i16(tail_id)
    elif kind <= _OBJK_REPLIER:
        w.u8(tail_id >> 8)
        w.u8(tail_id & 0xFF)
    return _body(w)


# READ_DATA's body: the stream to deliver on, FORMAT_DATA, no content filter, and an optional
# DeliveryControl (max_samples, max_elapsed_time, max_bytes_per_second, min_pace_period).
def read_data_body(stream_id, delivery):
    w = _body_writer()
    w.u8(stream_id)
    w.u8(0)
    w.u8(0)
    w.u8(delivery is not None)
    if delivery is not None:
        for value in delivery:
            w.u16(value)
    return _body(w)


# Binary object representations (XRCE-WIRE.md §4): CDR blobs aligned from their own first byte.

def _opt_string(w, value):
    w.u8(value is not None)
    if value is not None:
        w.string(value)


def participant_blob(name):
    w = CdrWriter(bytearray(32))
    w.u8(0)  # no domain reference
    _opt_string(w, name)
    return w.getvalue()


def topic_blob(topic_name, type_name):
    w = CdrWriter(bytearray(64))
    w.string(topic_name)
    w.u8(0)  # no type reference
    _opt_string(w, type_name)
    return w.getvalue()


PUBSUB_BLOB = b"\x00\x00"  # no name, no QoS


# Datawriter (reader False) or datareader: topic id, QoS flags and history depth, nothing else.
def endpoint_blob(topic_id, qos_flags, depth, reader):
    w = CdrWriter(bytearray(16))
    w.u8(topic_id >> 8)
    w.u8(topic_id & 0xFF)
    w.u8(1)
    w.u16(qos_flags)
    w.u8(depth is not None)
    if depth is not None:
        w.u16(depth)
    w.u8(0)  # deadline
    w.u8(0)  # lifespan
    w.u8(0)  # user data
    w.u8(0)  # ownership strength / time-based filter
    if reader:
        w.u8(0)  # content filter
    return w.getvalue()
