# Deleting single entities and cancelling a reader's delivery: Session.delete_entity and
# Session.cancel_data, loaded on first use (see Session.__getattr__); a firmware that creates its
# entities once and keeps them never pays for these.

from xrce.client import wire
from xrce.compat import const

_DELETE = const(3)
_READ_DATA = const(8)
_FLAG_LITTLE_ENDIAN = const(0x01)
_STREAM_NONE = const(0x00)
_STATUS_NONE = const(0xFF)


def delete_entity(session, object_id, stream_id=None):
    # Buffer a DELETE of one entity (the agent deletes its children). Returns the request id.
    rid = session.next_request_id()
    session._buffer(stream_id, _DELETE, _FLAG_LITTLE_ENDIAN, rid, object_id, b"")
    session._statuses[rid] = _STATUS_NONE
    if session.link is not None:
        session.link.forget(object_id)
    return rid


def cancel_data(session, reader_id, stream_id=None):
    # Stop the agent's delivery for this reader (READ_DATA on stream 0, all limits 0).
    rid = session.next_request_id()
    session._buffer(stream_id, _READ_DATA, _FLAG_LITTLE_ENDIAN, rid, reader_id,
                    wire.read_data_body(_STREAM_NONE, (0, 0, 0, 0)))
    session._read_requests.pop(reader_id, None)
    return rid
