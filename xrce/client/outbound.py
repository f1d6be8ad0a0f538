# What a client session writes at message rate: requests and samples into the open message of their
# stream, and the output path they all go through, lean enough for a board. The bodies and binary
# object representations of the entities it creates are in xrce.client.entities, which a board
# loads only while it creates them.
#
# The general codec (xrce/wire/submessages.py, xrce/wire/objects.py) has one class per submessage and per
# object kind, each with encode and decode and a repr: what the agent needs, and ~22 KB of heap on
# a board that would only ever use a few encoders. These functions write the same bytes for the
# cases a client produces; tests/client/test_client_encoders.py checks them against the general codec, so
# the wire format still has one reference. Comments, not docstrings: a board keeps docstrings.

from xrce import XrceError, const, ticks_add, ticks_ms
from xrce.wire.message import MessageWriter

_STREAM_NONE = const(0x00)
_WRITE_DATA = const(7)
_FLAG_LITTLE_ENDIAN = const(0x01)


# One tuple for the module: written in put_request, it would be built anew for every sample.
_BUFFERS = (bytes, bytearray, memoryview)


class SessionError(XrceError):
    # The session is not usable for the requested operation (not created, window full, ...). Defined
    # here, below the session (xrce.client.session re-exports it), as the output path raises it too.
    pass


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
    if isinstance(body, _BUFFERS):
        w.raw(body)
    else:
        saved = w.origin
        w.origin = w.pos  # a sample is aligned from its own first byte (§14)
        try:
            body.encode(w)
        finally:
            w.origin = saved


class Outbound:
    # What ``xrce.client.session.Session`` sends on its streams: requests go into the open message
    # of their stream, which is sent when full or on flush.

    def write(self, writer_id, data, stream_id=None):
        # Buffer one sample (a generated message object or its serialized bytes).
        #
        # Reliable samples larger than a message are fragmented; when the window is full the session
        # spins (bounded by 1 s) to make room. Returns the request id, or 0 if the sample was dropped.
        return self._write_sample(writer_id, data, None, stream_id)

    def _write_sample(self, object_id_, data, prefix, stream_id):
        if self.link is not None and not self.connected:
            # The link is lost (re-creating the session): nothing written now can arrive, and a
            # best-effort message sent between CREATE_CLIENT and its answer would reach the new
            # session with a sequence number far ahead of the restarted stream's, so the agent
            # dropped every sample until the stream caught up (issue 12: 3.5-7 s at 20 Hz).
            self.dropped_writes += 1
            return 0
        rid = self.next_request_id()
        # FORMAT_DATA (0) in the flags
        if not self._buffer(stream_id, _WRITE_DATA, _FLAG_LITTLE_ENDIAN, rid, object_id_, data, prefix):
            self.dropped_writes += 1
            return 0
        return rid

    def _buffer(self, stream_id, sub_id, flags, request_id, object_id_, body, prefix=None):
        # Append a request submessage (see ``put_request``) to its stream's open message; True
        # when it is buffered or sent.
        if stream_id is None:
            stream_id = self.reliable
        out = self._outputs.get(stream_id)
        if out is None:
            raise SessionError("no output stream 0x%02X" % stream_id)
        for _ in range(2):
            if not out.has_content and not self._begin_with_room(out):
                return False
            mark = out.pos
            put_request(out.begin_submessage(sub_id, flags), request_id, object_id_, body, prefix)
            out.end_submessage()
            end = out.pos
            if end <= self.max_message:
                out.has_content = True
                return True
            out.pos = mark
            mark = (mark + 3) & ~3  # where the submessage itself starts
            if not out.has_content or self.header_size + end - mark > self.max_message:
                break
            self._close_message(out)  # the open message is full: send it and retry in a fresh one
        if not out.reliable:
            return False  # a best-effort message cannot be fragmented (the C client refuses too)
        # Too big for any message: fragment the submessage just written at ``mark``..``end``.
        from xrce.client.fragments import write_fragmented
        return write_fragmented(self, out, mark, end)

    def _begin_with_room(self, out, timeout_ms=1000):
        # Open a new message on ``out``. A reliable stream whose window is full spins up to
        # ``timeout_ms`` for room; False if none came.
        if out.reliable:
            seq = out.state.next_seq()
            if seq is None:
                if not self.connected:
                    return False  # a lost link frees no room until the session is re-created
                self._wait(timeout_ms, out.state.has_room)
                if out.has_content:
                    return True  # a callback run while waiting opened a message: append to it
                seq = out.state.next_seq()
                if seq is None:
                    return False
        else:
            seq = 0  # best-effort messages get their sequence number when sent
        out.begin(self.session_id, out.stream_id, seq, self._header_key)
        out.has_content = False
        return True

    def _close_message(self, out):
        # Send the open message of ``out`` (trailing padding to 4, as the C client).
        if not out.has_content:
            return
        out.pad_to_4()
        if out.reliable:
            self._commit(out)
            self._schedule_heartbeat(out.stream_id)
        else:
            out.set_seq(out.state.next_seq())
            self._send_from(out.buf, out.pos)
        out.has_content = False

    def _commit(self, out):
        # Send the reliable message built in ``out`` and keep it for retransmission: the history
        # keeps the very buffer it was built in, and the writer goes on in the one that slot held
        # (its message acknowledged). No copy, so nothing is allocated per message once every slot
        # has its buffer (Session.size_output_buffers gives them theirs at set-up).
        length = out.pos
        buf = out.buf
        if buf is out.big:
            # Begun in the large buffer (a sample too big for a message came after other content)
            # but cut back to one message: back to the buffer it was begun in (rare: 2 views).
            buf = out.home
            buf[0:length] = memoryview(out.big)[0:length]
            out.home = None
        free = out.state.keep(buf, length)
        # A slot without a buffer yet (the history not sized): one the size of this message, which
        # the next one grows if it must.
        out.buf = free if free is not None else bytearray(length)
        self._send_from(buf, length)

    def flush(self):
        # Send every stream's open message. (Over the keys: on a board .values() would allocate a
        # view on every pass of the firmware's loop.)
        outputs = self._outputs
        for stream_id in outputs:
            out = outputs[stream_id]
            if out.has_content:
                self._close_message(out)

    def _begin_control(self, sub_id, session_id=None, key=None):
        # Start a stream-0 message with one submessage; returns the writer for its payload.
        mw = self._control
        if session_id is None:
            session_id, key = self.session_id, self._header_key
        mw.begin(session_id, _STREAM_NONE, 0, key)
        return mw.begin_submessage(sub_id, _FLAG_LITTLE_ENDIAN)

    def _send(self, message):
        self.messages_out += 1
        self.transport.send(message)

    def _send_from(self, buf, length):
        # Send ``buf[:length]``: through the transport's send_from when it has one (UdpTransport: a
        # board's socket writes the bytes from the buffer itself), else through a view of them.
        self.messages_out += 1
        send_from = self._transport_send_from
        if send_from is not None:
            send_from(buf, length)
        else:
            self.transport.send(memoryview(buf)[:length])

    def _send_control(self):
        control = self._control
        control.end_submessage()
        self._send_from(control.buf, control.pos)

    def _schedule_heartbeat(self, stream_id):
        if stream_id not in self._next_heartbeat:
            self._next_heartbeat[stream_id] = ticks_add(ticks_ms(), self.heartbeat_ms)


class _Output(MessageWriter):
    # An output stream: the message open on it and its sequence state (xrce.wire.streams). No __slots__
    # (for this class and LinkMonitor, the client-only ones): MicroPython ignores them and would
    # only keep the tuple of names (headline -112 B for both).

    def __init__(self, stream_id, state, capacity):
        MessageWriter.__init__(self, capacity)
        self.stream_id = stream_id
        self.state = state
        self.reliable = stream_id >= 0x80
        self.has_content = False
        self.big = None  # a reliable stream's buffer for a sample larger than a message
        self.home = None  # the buffer a message moved to ``big`` from was begun in

    def reserve(self, n):
        # A sample that does not fit a message's buffer goes on in ``big`` (the message so far
        # copied there, the buffer kept to come back to) rather than growing a buffer the history
        # would keep (xrce.client.fragments cuts it from ``big``); anything else grows as a
        # CdrWriter's buffer does.
        big = self.big
        buf = self.buf
        end = self.pos + n
        if end > len(buf) and big is not None and buf is not big and end <= len(big):
            big[0:self.pos] = memoryview(buf)[0:self.pos]
            self.home = buf
            self.buf = big
        else:
            MessageWriter.reserve(self, n)
