# The XRCE client session: streams, entities, data, services, ping and time sync.
#
# Synchronous and MicroPython-safe. Nothing blocks without a bound: every ``run_until_*`` takes a
# timeout in milliseconds, and ``spin_once`` processes at most one incoming message.
#
# Shape of use (mirrors eProsima's ``uxr_*`` API so that traffic matches the real client)::
#
#     session = Session(UdpTransport("127.0.0.1", 8888))
#     session.create()                                   # CREATE_CLIENT until STATUS_AGENT
#     node = session.create_participant(name="talker")   # buffered on the reliable stream
#     writer = session.create_writer(node, "/chatter", String)
#     session.run_until_all_status(1000)                 # flush, wait for every STATUS
#     session.write(writer, String(data="hi"))
#     session.run_until_confirm_delivery(1000)
#
# Outgoing submessages are appended to the open message of their stream and sent when the message
# is full or on flush (every ``run_until_*``/``spin_once`` flushes first), so several CREATEs share one
# message exactly as with the C client.
#
# A board pays for what it imports: the session-less ping (xrce.client.ping), services
# (xrce.client.services), time sync, the ping inside the session and waiting for delivery
# (xrce.client.on_demand), fragmentation (xrce.client.fragments), agent discovery
# (xrce.client.discovery) and auto-recovery (xrce.client.recovery) load on first use. What a session
# does at set-up, never per message, a board loads for each call and drops again: creating entities,
# READ_DATA and deleting entities (xrce.client.entities); constructing, creating, deleting and
# restoring the session itself (xrce.client.lifecycle). The submessages a session sends are written
# by the lean encoders of xrce.client.outbound, not by the general codec the agent uses.
#
# That makes the one import circle the project keeps on purpose (tests/repo/test_import_graph.py names
# it): services, on_demand and ping build on this module (its sample decoding, its agent-info
# parsing) and import it at their top, while it imports them only inside the functions that first
# need them. The other way round every board would load them with the session. Everything below
# the session (xrce.client.outbound, the wire core) imports nothing from it.

import sys

from xrce import DecodeError, IS_MICROPYTHON, const, ticks_add, ticks_diff, ticks_ms
from xrce.wire.cdr import CdrReader
from xrce.client.outbound import Outbound, SessionError  # noqa: F401  (SessionError: re-exported)

# Wire numbers (xrce/wire/constants.py names them all; these fold into the code on a board).
_SESSION_ID_WITHOUT_KEY_MASK = const(0x80)
_STREAM_NONE = const(0x00)
_CREATE_CLIENT = const(0)
_GET_INFO = const(2)
_STATUS_AGENT = const(4)
_STATUS = const(5)
_INFO = const(6)
_DATA = const(9)
_ACKNACK = const(10)
_HEARTBEAT = const(11)
_FRAGMENT = const(13)
_TIMESTAMP_REPLY = const(15)
_OBJK_REQUESTER = const(0x07)
_OBJK_AGENT = const(0x0D)
_OBJECTID_CLIENT = const(0xFFFE)
_STATUS_OK = const(0x00)
_STATUS_OK_MATCHED = const(0x01)
_STATUS_NONE = const(0xFF)
_REQUEST_ID_LOGOUT = const(0x0002)
_FIRST_REQUEST_ID = const(0x000A)
_INFO_ACTIVITY = const(0x02)


class Session(Outbound):
    # One XRCE client session over a transport (see ``xrce.transports``); writing and the output
    # path come from ``Outbound`` (xrce.client.outbound), set-up from xrce.client.lifecycle and entity
    # creation from xrce.client.entities.

    def __init__(self, *args, **kwargs):
        # Session(transport, key=None, session_id=0x81, history=4, mtu=None, best_effort_streams=1,
        # reliable_streams=1, heartbeat_ms=100, max_reassembly=None, on_topic=None,
        # auto_recover=True, liveliness_ms=500, on_link_state=None, largest_sample=0):
        # xrce.client.lifecycle.init, which CPython binds here. ``largest_sample`` (serialized
        # bytes) sizes the output buffers at once: see lifecycle.size_output_buffers.
        _set_up_module("lifecycle").init(self, *args, **kwargs)

    # ------------------------------------------------------------------ session lifecycle

    def _send_create_client(self):
        header_session = self.session_id & _SESSION_ID_WITHOUT_KEY_MASK
        w = self._begin_control(_CREATE_CLIENT, header_session, self.key if header_session == 0 else None)
        w.raw(b"XRCE\x01\x00\x01\x0F")  # cookie, version 1.0, vendor eProsima
        w.raw(self.key)
        w.u8(self.session_id)
        w.u8(0)  # no properties
        w.u16(self.max_message)
        # The eProsima client writes length 16 for CREATE_CLIENT even when properties follow (§3).
        self._control.end_submessage(16)
        self._send(self._control.view())

    def _send_ping(self):
        # GET_INFO in the session (a control message: always the same bytes).
        w = self._begin_control(_GET_INFO)
        w.raw(b"\x00\x0a\xff\xfd")  # REQUEST_ID_PING, OBJECTID_AGENT
        w.u32(_INFO_ACTIVITY)
        self._send_control()

    def close(self):
        self.transport.close()

    # ------------------------------------------------------------------ request ids

    def next_request_id(self):
        rid = self.last_request_id + 1
        if rid > 0xFFFF:
            rid = _FIRST_REQUEST_ID
        self.last_request_id = rid
        return rid

    # xrce.client.entities while hold_set_up() keeps it (a class attribute: never __getattr__'s).
    _held = None

    def hold_set_up(self, hold=True):
        # On a board each entity creation loads xrce.client.entities and leaves its code (~5 KB)
        # as garbage when it returns. Held, the module is loaded once and kept until
        # hold_set_up(False): a firmware creating its entities in a row holds ~3.6 KB through
        # set-up instead of making ~5 KB of garbage per call (and spends no time reloading it).
        # Nothing to do on CPython, where the functions are Session's own.
        self._held = _set_up_module("entities") if hold and IS_MICROPYTHON else None

    def __getattr__(self, name):
        # Set-up and teardown (xrce.client.lifecycle, xrce.client.entities) for one call on a
        # board; then time sync, the ping in the session, waiting for delivery, services and the
        # link state, which cost a board nothing until first used (xrce.client.on_demand).
        if " " not in name:
            word = " %s " % name
            if word in _LIFECYCLE:
                function = getattr(_set_up_module("lifecycle"), name)
                return lambda *args, **kwargs: function(self, *args, **kwargs)
            if word in _ON_DEMAND:
                from xrce.client.on_demand import session_attr
                return session_attr(self, name)
        return (self._held or _set_up_module("entities")).session_attr(self, name)

    # ------------------------------------------------------------------ running

    def _wait(self, timeout_ms, done):
        # Process input until ``done()`` or ``timeout_ms``; True if done.
        start = ticks_ms()
        while True:
            if done():
                return True
            now = ticks_ms()
            remaining = timeout_ms - ticks_diff(now, start)
            if remaining <= 0:
                return False
            wait = remaining
            pending = self._next_heartbeat
            for stream_id in pending:  # keys: a board allocates a view object for .values()
                until = ticks_diff(pending[stream_id], now)
                if until < wait:
                    wait = until if until > 0 else 0
            if self.link is not None and wait > self.heartbeat_ms:
                wait = self.heartbeat_ms  # let the link monitor ping or reconnect on time
            data = self.transport.recv(wait)
            if data is not None:
                self.handle_message(data)
            self._periodic(ticks_ms())

    def spin_once(self, timeout_ms=0):
        # Flush, then wait up to ``timeout_ms`` for one incoming message and process it.
        self.flush()
        data = self.transport.recv(timeout_ms)
        if data is not None:
            self.handle_message(data)
        self._periodic(ticks_ms())
        return data is not None

    def _periodic(self, now):
        # Heartbeats that are due, then the link monitor. Called on every pass of a firmware's loop,
        # so it allocates nothing: the streams are walked as the outputs' keys (a board makes a heap
        # object for a view or a snapshot of the pending ones), which also lets a stream's entry be
        # dropped on the way.
        pending = self._next_heartbeat
        for stream_id in self._outputs if pending else ():
            due = pending.get(stream_id)
            if due is None:
                continue
            state = self._outputs[stream_id].state
            if not state.pending():
                del pending[stream_id]
            elif ticks_diff(now, due) >= 0:
                # The bounds of OutputReliableStream.heartbeat(), without the tuple it returns.
                w = self._begin_control(_HEARTBEAT)
                w.u16((state.last_acknowledged + 1) & 0xFFFF)
                w.u16(state.last_sent)
                w.u8(stream_id)
                self._send_control()
                pending[stream_id] = ticks_add(now, self.heartbeat_ms)
        if self.link is not None:
            self.link.poll(now)

    def run_until_timeout(self, timeout_ms):
        # Flush and process everything that arrives for ``timeout_ms``.
        self.flush()
        self._wait(timeout_ms, _never)

    def run_until_all_status(self, timeout_ms=1000, request_ids=None):
        # Flush, wait for a STATUS for every pending request (or those given); True if all OK.
        #
        # OK_MATCHED counts as success (an entity reused as it was). Requests still unanswered at the
        # timeout stay pending, so a later call waits for them again. ``last_statuses`` holds what
        # this call saw.
        self.flush()
        ids = list(self._statuses) if request_ids is None else list(request_ids)
        statuses = self._statuses

        def done():
            for rid in ids:
                if statuses.get(rid, _STATUS_NONE) == _STATUS_NONE and rid != 0:
                    return False
            return True

        self._wait(timeout_ms, done)
        ok = True
        self.last_statuses = {}
        for rid in ids:
            status = statuses.get(rid, _STATUS_NONE) if rid else _STATUS_OK
            if status != _STATUS_NONE:
                statuses.pop(rid, None)  # answered: collected now; unanswered ones stay pending
            self.last_statuses[rid] = status
            if status != _STATUS_OK and status != _STATUS_OK_MATCHED:
                ok = False
        return ok

    # ------------------------------------------------------------------ input path

    def handle_message(self, buf):
        # Process one incoming message (bytes-like). Malformed input is counted and dropped.
        self.messages_in += 1
        n = len(buf)
        if n < 4 or buf[0] != self.session_id or (self._header_key is not None and (
                n < 8 or bytes(buf[4:8]) != self._header_key)):
            self.dropped_messages += 1
            return
        self._last_heard = ticks_ms()
        stream_id = buf[1]
        try:
            if stream_id == _STREAM_NONE:
                self._process(buf, n)
            elif stream_id < 0x80:
                stream = self._inputs.get(stream_id)
                if stream is None:
                    self.dropped_messages += 1
                elif stream.accept(buf[2] | (buf[3] << 8)):
                    self._process(buf, n)
            else:
                stream = self._inputs.get(stream_id)
                if stream is None:
                    self.dropped_messages += 1
                    return
                seq = buf[2] | (buf[3] << 8)
                if stream.receive_next(seq):  # in order, nothing stored: no list of one
                    self._send_acknack(stream)
                    self._process_reliable(buf)
                    return
                ready = stream.receive(seq, buf)
                self._send_acknack(stream)
                for message in ready:
                    self._process_reliable(message)
        except DecodeError:
            self.decode_errors += 1

    def _send_acknack(self, stream):
        bitmap = stream.nack_bitmap()  # acknack() without its tuple
        w = self._begin_control(_ACKNACK)
        w.u16((stream.last_handled + 1) & 0xFFFF)
        w.u8(bitmap >> 8)
        w.u8(bitmap & 0xFF)
        w.u8(stream.stream_id)
        self._send_control()

    def _process_reliable(self, message):
        start = self.header_size
        if len(message) >= start + 4 and message[start] == _FRAGMENT:
            from xrce.client.fragments import reassemble
            reassemble(self, message)
            return
        self._process(message, len(message))

    def _process(self, buf, end):
        # What a client receives (XRCE-WIRE.md §5), one branch per submessage: one method each
        # would cost a board heap for its code object; anything else is ignored. The submessages
        # are walked as xrce.wire.message.iter_submessages does, inline: a generator and a tuple per
        # submessage would be a board's garbage on every message received.
        pos = self.header_size
        while end - pos >= 4:
            sub_id = buf[pos]
            flags = buf[pos + 1]
            s = pos + 4
            e = s + (buf[pos + 2] | (buf[pos + 3] << 8))
            if e > end:
                raise DecodeError("submessage past the message end")
            pos = (e + 3) & ~3
            if sub_id == _DATA:
                if s == e:  # length 0: a sample > 64 KiB, to the end of the reassembled message
                    self._on_data(buf, flags, s, end)
                    return
                self._on_data(buf, flags, s, e)
            elif sub_id == _ACKNACK or sub_id == _HEARTBEAT:
                if e - s < 5:
                    raise DecodeError("short ACKNACK or HEARTBEAT")
                stream_id = buf[s + 4]
                if flags & 1:
                    first, second = buf[s] | (buf[s + 1] << 8), buf[s + 2] | (buf[s + 3] << 8)
                else:
                    first, second = (buf[s] << 8) | buf[s + 1], (buf[s + 2] << 8) | buf[s + 3]
                if sub_id == _ACKNACK:
                    # first unacknowledged, NACK bitmap (always big-endian) of one of our streams
                    out = self._outputs.get(stream_id)
                    if out is not None and out.reliable:
                        out.state.on_acknack(first, (buf[s + 2] << 8) | buf[s + 3], ticks_ms(),
                                             self.heartbeat_ms // 2, self)
                else:
                    # first and last sequence numbers the agent still holds for one of its streams
                    stream = self._inputs.get(stream_id)
                    if stream is not None and stream_id >= 0x80:
                        ready = stream.on_heartbeat(first, second)
                        self._send_acknack(stream)
                        for message in ready:
                            self._process_reliable(message)
            elif sub_id == _STATUS:
                if e - s < 6:
                    raise DecodeError("short STATUS")
                rid = (buf[s] << 8) | buf[s + 1]
                if rid == _REQUEST_ID_LOGOUT and ((buf[s + 2] << 8) | buf[s + 3]) == _OBJECTID_CLIENT:
                    self._delete_status = buf[s + 4]
                elif rid in self._statuses:  # only requests someone waits for (not re-creations)
                    self._statuses[rid] = buf[s + 4]
            elif sub_id == _INFO:
                availability = _agent_activity(buf, flags, s, e)
                if availability is not None and availability > 0:
                    if buf[s + 5] == 1:  # implementation status
                        self._pong_in_session = True
                    elif self.connected:
                        self._session_unknown = True  # an agent answers, no longer knowing this session
            elif sub_id == _TIMESTAMP_REPLY:
                # xrce.client.on_demand's, which the first sync_time sets on the class (an import
                # here would allocate per reply on a board).
                if self._demand is None:
                    self.stale_timestamps += 1
                else:
                    self._on_timestamp_reply(buf, flags, s, e)
            elif sub_id == _STATUS_AGENT:
                if e - s < 1:
                    raise DecodeError("empty STATUS_AGENT")
                self.create_status = buf[s]

    def _on_data(self, buf, flags, s, e):
        if e - s < 4:
            raise DecodeError("short DATA")
        rid = (buf[s] << 8) | buf[s + 1]
        oid = (buf[s + 2] << 8) | buf[s + 3]
        if rid in self._statuses:
            self._statuses[rid] = _STATUS_OK  # a DATA answers its READ_DATA (§5)
        reader = self._readers.get(oid)
        if self.on_topic is not None:
            self.on_topic(self, oid, rid, buf[1], memoryview(buf)[s + 4:e])
        if reader is None:
            return
        callback, msg_class = reader
        if oid & 0x0F >= _OBJK_REQUESTER:
            from xrce.client.services import deliver
            deliver(oid & 0x0F, callback, msg_class, memoryview(buf)[s + 4:e])
        elif msg_class is None:
            callback(bytes(memoryview(buf)[s + 4:e]))
        else:
            # The session's one reader over the message itself: no view, no reader per sample.
            r = self._sample_reader
            r.buf = buf
            r.pos = r.origin = s + 4
            r.end = e
            try:
                if type(msg_class) is type:
                    sample = msg_class.decode(r)
                else:  # an instance (create_reader's ``into``): decoded in place
                    _decode_into(msg_class, r)
                    sample = msg_class
                unread = e - r.pos
            except DecodeError:  # past the sample's end
                unread = -1
            r.buf = b""  # the datagram is not kept alive until the next one
            if not 0 <= unread <= 3:  # more than alignment padding unread: another definition
                from xrce.client.type_drift import drifted
                drifted(self, oid, msg_class, unread)  # raises DecodeError for a sample past its end
            callback(sample)


def _never():
    return False


def _decode_into(msg, r):
    # xrce.msgs._into.decode_into, imported by the first sample an ``into`` reader gets; then this
    # name is that function (an import per sample would look the module up each time).
    global _decode_into
    from xrce.msgs._into import decode_into

    _decode_into = decode_into
    decode_into(msg, r)


def _decode_sample(msg_class, data):
    if msg_class is None:
        return bytes(data)
    return msg_class.decode(CdrReader(data))


def _agent_activity(buf, flags, s, e):
    # The availability (int16) an agent's INFO payload in ``buf[s:e]`` reports, or None (the
    # implementation status is ``buf[s + 5]``). Read byte by byte: a reader, its bytes and a tuple
    # would be a board's garbage on every ping answered.
    p = s + 7  # related request (4), status, implementation status, then the optional config
    if p > e or buf[p - 1] > 1:
        raise DecodeError("bad INFO")
    if buf[p - 1]:  # the agent's configuration: kind, cookie, version, vendor, properties
        p += 10
        if p > e or buf[p - 1] > 1:
            raise DecodeError("bad INFO")
        if buf[p - 1]:  # properties: discovery's INFO reader skips them
            from xrce.client.discovery import info_activity

            return info_activity(buf, flags, s, e)[1]
    if p >= e or buf[p] > 1:
        raise DecodeError("bad INFO")
    if not buf[p]:
        return None
    if p + 1 >= e or buf[p + 1] != _OBJK_AGENT:  # the activity of an agent
        raise DecodeError("bad INFO")
    p += 2
    p += p & 1  # an int16, aligned from the message start
    if p + 2 > e:
        raise DecodeError("bad INFO")
    value = (buf[p] | (buf[p + 1] << 8)) if flags & 1 else ((buf[p] << 8) | buf[p + 1])
    return value - 0x10000 if value & 0x8000 else value


# The session attributes xrce.client.lifecycle serves (a string looked up as " name ": on a board
# each string of a tuple would be an object of its own). Told apart here, so that neither module
# loads the other for a call.
_LIFECYCLE = " create delete _reset_streams _restore size_output_buffers "
# xrce.client.on_demand's own, which it then sets on the class: their first look-up (a firmware's
# first time sync, typically before any entity) goes there without loading xrce.client.entities,
# which passes on the names it does not serve (the services') itself.
_ON_DEMAND = " sync_time epoch_ns epoch_ms time_offset_ns ping run_until_confirm_delivery link_state "


# xrce.client.<name> (entities, lifecycle) for one call: a board drops it again, as xrce.msgs drops
# its _plan, so its code is garbage once the call returns (a firmware creates its session and
# entities at set-up, not per message).
def _set_up_module(name):
    dotted = "xrce.client." + name
    __import__(dotted)
    module = sys.modules[dotted]
    if IS_MICROPYTHON:
        del sys.modules[dotted]
        sys.modules["xrce.client"].__dict__.pop(name, None)
    return module


def __getattr__(name):
    # The session-less ping and agent discovery live in their own modules; this keeps
    # `from xrce.client.session import ping_agent` working without every board paying for them.
    if name == "ros_topic_name":
        return _set_up_module("entities").ros_topic_name
    if name == "ping_agent":
        from xrce.client.ping import ping_agent
        return ping_agent
    if name == "discover_agents":
        from xrce.client.discovery import discover_agents
        return discover_agents
    raise AttributeError(name)


if not IS_MICROPYTHON:
    _set_up_module("entities").bind(Session)
