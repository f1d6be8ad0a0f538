# Ending things: deleting the session (Session.delete), single entities (Session.delete_entity),
# cancelling a reader's delivery (Session.cancel_data) and waiting until every reliable message is
# acknowledged (Session.run_until_confirm_delivery, which a firmware's loop does not need: its streams
# deliver as it spins). Loaded on first use (see Session.__getattr__); a firmware that creates its
# entities once and keeps them never pays for these.

from xrce import const
from xrce.client import wire

_DELETE = const(3)
_REQUEST_ID_LOGOUT_OBJECTID_CLIENT = b"\x00\x02\xff\xfe"
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


def delete(session, attempts=10, timeout_ms=1000):
    # DELETE of the client (logout) until the agent's STATUS; True when confirmed.
    session.flush()
    session._begin_control(_DELETE).raw(_REQUEST_ID_LOGOUT_OBJECTID_CLIENT)
    session._control.end_submessage()
    message = session._control.getvalue()
    session._delete_status = None
    for _ in range(attempts):
        session._send(message)
        if session._wait(timeout_ms, lambda: session._delete_status is not None):
            break
    session.connected = False
    return session._delete_status is not None


def run_until_confirm_delivery(session, timeout_ms=1000):
    # Flush and wait until every reliable message sent has been acknowledged.
    session.flush()
    return session._wait(timeout_ms, lambda: _all_delivered(session))


def _all_delivered(session):
    for out in session._outputs.values():
        if out.reliable and out.state.pending():
            return False
    return True
