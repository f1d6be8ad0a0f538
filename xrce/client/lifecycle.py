# The session's own life, never per message: its construction (streams and buffers), creating it
# on the agent (CREATE_CLIENT), logging out, and resuming after the agent lost it (the re-creation
# log itself is kept by xrce.client.entities, which creates what it lists).
#
# On a board the session imports this module for one call and drops it again (_set_up_module in
# xrce.client.session), like xrce.client.entities: apart from each other, so that creating an
# entity, a firmware's largest set-up step, loads only the code it runs: 5.1 KB of garbage per call
# instead of 7.4, and the TurtleBot3 firmware's peak 82.6 -> 80.6 KB (tests/board/test_turtlebot3_heap.py).
# CPython binds these functions on Session (xrce.client.entities.bind).

from xrce import const, ticks_ms
from xrce.wire.cdr import CdrReader
from xrce.client.outbound import _Output
from xrce.wire.message import MessageWriter, header_size
from xrce.wire.streams import (
    InputBestEffortStream, InputReliableStream, OutputBestEffortStream, OutputReliableStream,
)

_DEFAULT_SESSION_ID = const(0x81)
_BUILTIN_BEST_EFFORT = const(0x01)
_BUILTIN_RELIABLE = const(0x80)
_FIRST_REQUEST_ID = const(0x000A)
_STATUS_OK = const(0x00)
_CREATE = const(1)
_DELETE = const(3)
_READ_DATA = const(8)
_FLAG_LITTLE_ENDIAN = const(0x01)
_REUSE_REPLACE = const(0x06)  # FLAG_REUSE | FLAG_REPLACE
# Bytes the C client's slot keeps for its own bookkeeping; we advertise and send the same maximum
# message size (transport MTU − 4, i.e. 508 for 512) so that fragment sizes match on the wire.
_SLOT_OVERHEAD = const(4)
_FIRST_OUTPUT_BUFFER = const(64)


# Here rather than in the package xrce, where it was: only a session's construction draws a key, and
# a board loads this module for that call only, so it keeps no code for it afterwards (the package
# stays loaded for good; this move paid for the package object of xrce.wire, issue 46).
def random_client_key():
    # Four random bytes, never all zero (the agent rejects key 0).
    try:
        import os
        key = os.urandom(4)
    except (ImportError, AttributeError, NotImplementedError):
        import random
        value = random.getrandbits(32)
        key = bytes(((value >> 24) & 0xFF, (value >> 16) & 0xFF, (value >> 8) & 0xFF, value & 0xFF))
    if key == b"\x00\x00\x00\x00":
        key = b"\x00\x00\x00\x01"
    return key


def init(session, transport, key=None, session_id=_DEFAULT_SESSION_ID, history=4, mtu=None,
         best_effort_streams=1, reliable_streams=1, heartbeat_ms=100, max_reassembly=None,
         on_topic=None, auto_recover=True, liveliness_ms=500, on_link_state=None, largest_sample=0):
    if not 0x01 <= session_id <= 0xFF or session_id == 0x80:
        _error("session id must be 0x01..0x7F (keyed) or 0x81..0xFF")
    session.transport = transport
    # Bound once here: the session sends the first bytes of its buffers through it (a board's
    # UdpTransport writes them from the buffer), and looking it up per message would bind it anew.
    session._transport_send_from = getattr(transport, "send_from", None)
    session._sample_reader = CdrReader(b"")  # every sample is decoded through this one
    if key is None:
        key = random_client_key()
    elif isinstance(key, int):
        key = bytes(((key >> 24) & 0xFF, (key >> 16) & 0xFF, (key >> 8) & 0xFF, key & 0xFF))
    if len(key) != 4 or key == b"\x00\x00\x00\x00":
        _error("client key must be 4 bytes and not zero")
    session.key = bytes(key)
    session.session_id = session_id
    session._header_key = session.key if session_id < 0x80 else None
    session.header_size = header_size(session_id)
    session.mtu = transport.mtu if mtu is None else mtu
    session.max_message = session.mtu - _SLOT_OVERHEAD
    session.history = history
    session.heartbeat_ms = heartbeat_ms
    # Fragmented input may span at most this many bytes (the C client's limit is history slots).
    session.max_reassembly = max_reassembly if max_reassembly is not None else 16 * session.mtu
    session.on_topic = on_topic
    session.connected = False

    outputs = session._outputs = {}
    inputs = session._inputs = {}
    # An output buffer starts small and grows (doubling) to the largest message its stream
    # has built, at most about max_message: a firmware sending 60-byte samples keeps 64 bytes,
    # not the 508 a full message could take, and it grows once, not per message.
    for i in range(best_effort_streams):
        sid = _BUILTIN_BEST_EFFORT + i
        outputs[sid] = _Output(sid, OutputBestEffortStream(sid), _FIRST_OUTPUT_BUFFER)
        inputs[sid] = InputBestEffortStream(sid)
    for i in range(reliable_streams):
        sid = _BUILTIN_RELIABLE + i
        outputs[sid] = _Output(sid, OutputReliableStream(sid, history), _FIRST_OUTPUT_BUFFER)
        inputs[sid] = InputReliableStream(sid, history)
    if largest_sample:
        size_output_buffers(session, largest_sample)
    session.best_effort = _BUILTIN_BEST_EFFORT if best_effort_streams else None
    session.reliable = _BUILTIN_RELIABLE if reliable_streams else None

    session._control = MessageWriter(64)  # stream-0 messages: ACKNACK, HEARTBEAT, TIMESTAMP, ...
    session.last_request_id = _FIRST_REQUEST_ID - 1
    session._object_counters = {}
    session._statuses = {}
    session._readers = {}
    session.create_status = None
    session._pong_in_session = False
    session._delete_status = None
    session._demand = None  # time sync's and the ping's state (xrce.client.on_demand)
    session._reassembly = None
    session._next_heartbeat = {}
    session._last_heard = ticks_ms()
    session._session_unknown = False
    # What to re-create after the agent lost the session (xrce.client.recovery, _restore below): a
    # CREATE's (object id, body) and a READ_DATA's body by reader id; the request ids are new then.
    session._creations = []
    session._read_requests = {}
    session.link = None
    if auto_recover:
        from xrce.client.recovery import LinkMonitor
        session.link = LinkMonitor(session, liveliness_ms, on_state=on_link_state)
    session.time_rtt_ns = 0  # round trip of the exchange time_offset_ns (a property) came from
    session.time_synced = False
    session.last_rtt_us = None
    session.last_statuses = {}
    # Counters for observability and tests.
    session.messages_in = 0
    session.messages_out = 0
    session.decode_errors = 0
    session.dropped_messages = 0
    session.stale_timestamps = 0
    session.dropped_writes = 0


def size_output_buffers(session, largest_sample):
    # Give every output stream, now, the buffers a sample of ``largest_sample`` serialized bytes
    # needs, so that neither its first such sample nor its history grows one in the firmware's
    # loop (growing takes a block twice the size in one piece while the old one is live; on a
    # board the TurtleBot3's first /odom asked for 1024 bytes mid-run). A best-effort stream
    # never builds more than a message. A reliable stream's history slots (streams.OutputReliableStream.keep) and the
    # buffer messages are built in get a message's size, or the sample's if smaller; a sample
    # larger than a message is written whole into one more buffer (``big``), which it is cut from
    # into the slots as FRAGMENTs. A buffer never shrinks, and one too small still grows. A
    # firmware calls it while its heap is still in one piece (the TurtleBot3 example: in its
    # constructor), since these are blocks it keeps for good; here, in a set-up module, since it
    # runs once.
    whole = (session.header_size + 8 + largest_sample + 3) & ~3  # subheader, request, object ids
    size = whole if whole < session.max_message else session.max_message
    session.flush()  # nothing open is lost with the buffer it is in
    outputs = session._outputs
    for stream_id in outputs:
        out = outputs[stream_id]
        if len(out.buf) < size:
            out.buf = bytearray(size)
        if not out.reliable:
            continue
        if whole > size and (out.big is None or len(out.big) < whole):
            out.big = bytearray(whole)
        history = out.state
        slots = history.slots
        for i in range(history.history):
            old = slots[i]
            if old is None or len(old) < size:
                new = bytearray(size)
                length = history.sizes[i]
                if length:  # still unacknowledged: a copy of it
                    new[0:length] = memoryview(old)[0:length]
                slots[i] = new


def _error(message):
    from xrce.client.session import SessionError

    raise SessionError(message)


def create(session, attempts=10, timeout_ms=1000):
    # CREATE_CLIENT until a STATUS_AGENT arrives; True if the agent accepted the session.
    session.create_status = None
    for _ in range(attempts):
        session._send_create_client()
        if session._wait(timeout_ms, lambda: session.create_status is not None):
            break
    if session.create_status is None:
        return False
    session.connected = session.create_status == _STATUS_OK
    if session.connected:
        _reset_streams(session)
        session._last_heard = ticks_ms()
    return session.connected


def _reset_streams(session):
    for out in session._outputs.values():
        if out.reliable:
            out.state.reset(True)  # the history's buffers stay for the new session's messages
        else:
            out.state.reset()
        out.has_content = False
    for stream in session._inputs.values():
        stream.reset()
    session._reassembly = None
    session._next_heartbeat = {}


def delete(session, attempts=10, timeout_ms=1000):
    # DELETE of the client (logout) until the agent's STATUS; True when confirmed.
    session.flush()
    session._begin_control(_DELETE).raw(b"\x00\x02\xff\xfe")  # REQUEST_ID_LOGOUT, OBJECTID_CLIENT
    session._control.end_submessage()
    message = session._control.getvalue()
    session._delete_status = None
    for _ in range(attempts):
        session._send(message)
        if session._wait(timeout_ms, lambda: session._delete_status is not None):
            break
    session.connected = False
    return session._delete_status is not None


def _restore(session):
    # The agent accepted our CREATE_CLIENT again (xrce.client.recovery): re-create what we had
    # (REUSE|REPLACE, so an agent that kept them reuses them) under new request ids, and resume.
    session.connected = True
    _reset_streams(session)
    session._last_heard = ticks_ms()
    for object_id, body in session._creations:
        session._buffer(None, _CREATE, _FLAG_LITTLE_ENDIAN | _REUSE_REPLACE, session.next_request_id(),
                        object_id, body)
    for reader_id, body in session._read_requests.items():
        session._buffer(None, _READ_DATA, _FLAG_LITTLE_ENDIAN, session.next_request_id(), reader_id, body)
    session.flush()
