# What a client session writes: the submessages it sends and the binary object representations of
# the entities it creates, lean enough for a board.
#
# The general codec (xrce/submessages.py, xrce/objects.py) has one class per submessage and per
# object kind, each with encode and decode and a repr: what the agent needs, and ~22 KB of heap on
# a board that would only ever use a few encoders. These functions write the same bytes for the
# cases a client produces; tests/test_client_wire.py checks them against the general codec, so
# the wire format still has one reference. Comments, not docstrings: a board keeps docstrings.

from xrce import const, ticks_add, ticks_ms
from xrce.cdr import CdrWriter
from xrce.message import MessageWriter

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


_CREATE = const(1)
_READ_DATA = const(8)
_FLAG_LITTLE_ENDIAN = const(0x01)
_REUSE_REPLACE = const(0x06)  # FLAG_REUSE | FLAG_REPLACE
_OBJK_TOPIC = const(0x02)
_OBJK_PUBLISHER = const(0x03)
_OBJK_SUBSCRIBER = const(0x04)
_OBJK_DATAWRITER = const(0x05)
_OBJK_DATAREADER = const(0x06)
_STATUS_NONE = const(0xFF)
_QOS_RELIABLE = const(0x0001)
_QOS_KEEP_LAST = const(0x0002)
_QOS_TRANSIENT_LOCAL = const(0x0008)
_MAX_SAMPLES_UNLIMITED = const(0xFFFF)

_STREAM_NONE = const(0x00)
_WRITE_DATA = const(7)

def ros_topic_name(name, prefix="rt"):
    # '/chatter' or 'chatter' → 'rt/chatter' (micro-ROS' naming of ROS topics in DDS).
    return prefix + (name if name.startswith("/") else "/" + name)


class Outbound:
    # What ``xrce.client.session.Session`` sends on its streams: entity creation, READ_DATA,
    # samples, and the output path they all go through.

    def _create(self, kind, blob, tail_id, object_id_, stream_id, flags, xml=None, ref=None):
        # ``blob``: the binary representation, unused when an ``xml`` or ``ref`` text is given.
        fmt = _REPRESENTATION_IN_BINARY
        if xml is not None or ref is not None:
            # XML and reference creation cost a board nothing until used.
            from xrce.client.representations import textual
            fmt, blob = textual(xml, ref)
        oid = self.new_object_id(kind) if object_id_ is None else object_id_
        rid = self.next_request_id()
        body = create_body(kind, fmt, blob, tail_id)
        self._buffer(stream_id, _CREATE, _FLAG_LITTLE_ENDIAN | flags, rid, oid, body)
        self._statuses[rid] = _STATUS_NONE
        if self.link is not None:
            self.link.forget(oid)
            self._creations.append((oid, body))
        return oid

    def create_participant(self, domain_id=0, name=None, xml=None, ref=None, object_id=None,
                           stream_id=None, flags=_REUSE_REPLACE):
        # A participant (a ROS node on the agent). Returns its object id; the request is buffered.
        return self._create(_OBJK_PARTICIPANT, participant_blob(name), domain_id, object_id,
                            stream_id, flags, xml, ref)

    def create_topic(self, participant_id, topic_name=None, type_name=None, xml=None, ref=None,
                     object_id=None, stream_id=None, flags=_REUSE_REPLACE):
        blob = topic_blob(topic_name, type_name) if xml is None and ref is None else None
        return self._create(_OBJK_TOPIC, blob, participant_id, object_id, stream_id, flags, xml, ref)

    def create_publisher(self, participant_id, xml=None, object_id=None, stream_id=None,
                         flags=_REUSE_REPLACE):
        return self._create(_OBJK_PUBLISHER, PUBSUB_BLOB, participant_id, object_id, stream_id,
                            flags, xml)

    def create_subscriber(self, participant_id, xml=None, object_id=None, stream_id=None,
                          flags=_REUSE_REPLACE):
        return self._create(_OBJK_SUBSCRIBER, PUBSUB_BLOB, participant_id, object_id, stream_id,
                            flags, xml)

    @staticmethod
    def endpoint_qos(reliable=True, keep_last=True, depth=10, transient_local=False):
        # ``(flags, history depth)`` for ``create_datawriter``/``create_datareader``, which also
        # take an ``xrce.objects.EndpointQos`` for QoS beyond these.
        flags = (_QOS_RELIABLE if reliable else 0) | (_QOS_KEEP_LAST if keep_last else 0)
        if transient_local:
            flags |= _QOS_TRANSIENT_LOCAL
        return flags, depth if depth else None

    def _endpoint(self, kind, parent_id, topic_id, qos, xml, ref, object_id_, stream_id, flags):
        blob = None
        if xml is None and ref is None:
            if qos is None:
                qos = self.endpoint_qos()
            if isinstance(qos, tuple):
                blob = endpoint_blob(topic_id, qos[0], qos[1], kind == _OBJK_DATAREADER)
            else:  # a full EndpointQos (deadline, lifespan, user data): the general codec
                from xrce.client.representations import endpoint_blob as full_qos_blob
                blob = full_qos_blob(kind, topic_id, qos)
        return self._create(kind, blob, parent_id, object_id_, stream_id, flags, xml, ref)

    def create_datawriter(self, publisher_id, topic_id=None, qos=None, xml=None, ref=None,
                          object_id=None, stream_id=None, flags=_REUSE_REPLACE):
        return self._endpoint(_OBJK_DATAWRITER, publisher_id, topic_id, qos, xml, ref, object_id,
                              stream_id, flags)

    def create_datareader(self, subscriber_id, topic_id=None, qos=None, xml=None, ref=None,
                          object_id=None, stream_id=None, flags=_REUSE_REPLACE):
        return self._endpoint(_OBJK_DATAREADER, subscriber_id, topic_id, qos, xml, ref, object_id,
                              stream_id, flags)

    # ROS-flavoured helpers: one call per publisher/subscription, as rmw_microxrcedds does.

    def create_writer(self, participant_id, topic, msg_class, reliable=True, depth=10,
                      transient_local=False, stream_id=None):
        # Topic + publisher + datawriter for a ROS topic ('/chatter') of a generated message class.
        topic_id = self.create_topic(participant_id, ros_topic_name(topic), msg_class.TYPE_NAME,
                                     stream_id=stream_id)
        publisher_id = self.create_publisher(participant_id, stream_id=stream_id)
        return self.create_datawriter(publisher_id, topic_id,
                                      self.endpoint_qos(reliable, True, depth, transient_local),
                                      stream_id=stream_id)

    def create_reader(self, participant_id, topic, msg_class, callback, reliable=True, depth=10,
                      transient_local=False, stream_id=None, data_stream_id=None):
        # Topic + subscriber + datareader + READ_DATA (unlimited samples) for a ROS topic.
        #
        # ``callback(msg)`` gets decoded ``msg_class`` instances; DATA comes on the reliable input stream
        # for a reliable reader and on the best-effort one otherwise, unless ``data_stream_id`` says.
        topic_id = self.create_topic(participant_id, ros_topic_name(topic), msg_class.TYPE_NAME,
                                     stream_id=stream_id)
        subscriber_id = self.create_subscriber(participant_id, stream_id=stream_id)
        reader_id = self.create_datareader(subscriber_id, topic_id,
                                           self.endpoint_qos(reliable, True, depth, transient_local),
                                           stream_id=stream_id)
        self.set_reader_callback(reader_id, callback, msg_class)
        if data_stream_id is None:
            data_stream_id = self.reliable if reliable else self.best_effort
        self.read_data(reader_id, data_stream_id, stream_id=stream_id)
        return reader_id

    # Reading.

    def set_reader_callback(self, reader_id, callback, msg_class=None):
        # ``callback(data)`` for every DATA of this reader/requester/replier.
        #
        # Datareader: ``data`` is ``msg_class`` decoded, or the raw sample bytes without a class.
        # Requester: ``callback(request_id, data)`` with the id ``send_request`` returned.
        # Replier: ``callback(sample_identity, data)``; answer with ``send_reply``.
        self._readers[reader_id] = (callback, msg_class)  # a tuple: no class for a board to load

    def read_data(self, reader_id, data_stream_id=None, max_samples=_MAX_SAMPLES_UNLIMITED,
                  max_elapsed_time=0, max_bytes_per_second=0, min_pace_period=0, delivery=True,
                  stream_id=None):
        # Buffer a READ_DATA asking the agent to deliver samples on ``data_stream_id``.
        control = (max_samples, max_elapsed_time, max_bytes_per_second,
                   min_pace_period) if delivery else None
        rid = self.next_request_id()
        if data_stream_id is None:
            data_stream_id = self.reliable
        body = read_data_body(data_stream_id, control)
        self._buffer(stream_id, _READ_DATA, _FLAG_LITTLE_ENDIAN, rid, reader_id, body)
        if self.link is not None:
            self._read_requests[reader_id] = body
        return rid

    # Data and the output path: requests go into the open message of their stream, which is sent
    # when full or on flush.

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
        # Append a request submessage (see ``wire.put_request``) to its stream's open message; True
        # when it is buffered or sent.
        if stream_id is None:
            stream_id = self.reliable
        out = self._outputs.get(stream_id)
        if out is None:
            from xrce.client.session import SessionError

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
            message = out.getvalue()
            out.state.commit(out.state.next_seq(), message)
            self._send(message)
            self._schedule_heartbeat(out.stream_id)
        else:
            out.set_seq(out.state.next_seq())
            self._send(out.view())
        out.has_content = False

    def flush(self):
        # Send every stream's open message.
        for out in self._outputs.values():
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

    def _send_control(self):
        self._control.end_submessage()
        self._send(self._control.view())

    def _schedule_heartbeat(self, stream_id):
        if stream_id not in self._next_heartbeat:
            self._next_heartbeat[stream_id] = ticks_add(ticks_ms(), self.heartbeat_ms)


class _Output(MessageWriter):
    # An output stream: the message open on it and its sequence state (xrce.streams). No __slots__
    # (for this class and LinkMonitor, the client-only ones): MicroPython ignores them and would
    # only keep the tuple of names (headline -112 B for both).

    def __init__(self, stream_id, state, capacity):
        MessageWriter.__init__(self, capacity)
        self.stream_id = stream_id
        self.state = state
        self.reliable = stream_id >= 0x80
        self.has_content = False
