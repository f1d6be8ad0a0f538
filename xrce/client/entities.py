# Creating entities, never per message: the request bodies and binary representations, the object
# ids, READ_DATA and its cancelling, deleting entities, and the re-creation log (which
# xrce.client.lifecycle replays after a lost session; it also constructs, creates and deletes the
# session itself).
#
# On a board the session imports this module for one call and drops it again (_set_up_module in
# xrce.client.session, as xrce.msgs drops its _plan), so its code is garbage as soon as the call
# returns: a firmware creates its entities once and then keeps none of this. Each call pays the
# import instead (bench/micropython/client_footprint.py, docs/MICROPYTHON.md), which set-up can afford.
# CPython binds these functions on Session at import (``bind``): there they cost nothing per call.
#
# The functions here call each other directly, never through the session: on a board each session
# attribute served from here imports the module once more.

from xrce import const
from xrce.wire.cdr import CdrWriter

_STATUS_NONE = const(0xFF)
_CREATE = const(1)
_DELETE = const(3)
_READ_DATA = const(8)
_FLAG_LITTLE_ENDIAN = const(0x01)
_REUSE_REPLACE = const(0x06)  # FLAG_REUSE | FLAG_REPLACE
_STREAM_NONE = const(0x00)
_OBJK_PARTICIPANT = const(0x01)
_OBJK_TOPIC = const(0x02)
_OBJK_PUBLISHER = const(0x03)
_OBJK_SUBSCRIBER = const(0x04)
_OBJK_DATAWRITER = const(0x05)
_OBJK_DATAREADER = const(0x06)
_OBJK_REPLIER = const(0x08)
_REPRESENTATION_IN_BINARY = const(3)
_QOS_RELIABLE = const(0x0001)
_QOS_KEEP_LAST = const(0x0002)
_QOS_TRANSIENT_LOCAL = const(0x0008)
_MAX_SAMPLES_UNLIMITED = const(0xFFFF)

# The session attributes served from here, one space-separated string looked up as " name " (on a
# board every string of a tuple would be an object of its own).
_NAMES = (" create_participant create_topic create_publisher create_subscriber create_datawriter"
          " create_datareader create_writer create_reader endpoint_qos set_reader_callback read_data"
          " new_object_id delete_entity cancel_data _create ")


# Session.__getattr__ on a board: the function ``name`` bound to ``session`` for one call; any
# other name goes on to xrce.client.on_demand.
def session_attr(session, name):
    if " " not in name and " %s " % name in _NAMES:
        function = globals()[name]
        if name == "endpoint_qos":
            return function  # a static method
        return lambda *args, **kwargs: function(session, *args, **kwargs)
    from xrce.client.on_demand import session_attr as on_demand

    return on_demand(session, name)


# CPython: the functions become Session's own methods, with xrce.client.lifecycle's (the constructor
# among them).
def bind(cls):
    from xrce.client import lifecycle
    from xrce.client.session import _LIFECYCLE

    for name in _NAMES.split():
        function = globals()[name]
        setattr(cls, name, staticmethod(function) if name == "endpoint_qos" else function)
    for name in _LIFECYCLE.split():
        setattr(cls, name, getattr(lifecycle, name))
    cls.__init__ = lifecycle.init
    from xrce.client import on_demand

    on_demand.bind(cls)


def new_object_id(session, kind):
    counters = session._object_counters
    index = counters.get(kind, 0) + 1
    if index > 0xFFF:
        from xrce.client.session import SessionError

        raise SessionError("object index must be 0..4095")
    counters[kind] = index
    return (index << 4) | kind


# ------------------------------------------------------------------ request bodies

# A payload starts 4-aligned in its message and the ids take 4 bytes, so a body written from
# offset 4 of a scratch buffer aligns exactly as it will in any message.
def _body_writer():
    return CdrWriter(bytearray(48), 4, 0)


def _body(w):
    return bytes(memoryview(w.buf)[4:w.pos])  # one copy (see CdrWriter.getvalue)


# A CREATE's body starts with the object kind and, but for a participant (domain id), ends with
# the parent's object id: _forget reads them there.
def create_body(kind, fmt, blob, tail_id):
    # blob: the representation's bytes (fmt binary) or the XML/reference text.
    w = _body_writer()
    w.u8(kind)
    w.u8(fmt)
    if fmt == _REPRESENTATION_IN_BINARY:
        w.u32(len(blob))  # sequence<octet>
        w.raw(blob)
    else:
        w.string(blob)
    if kind == _OBJK_PARTICIPANT:
        w._put("<h", 2, tail_id)  # int16: the writer's i16 lives in xrce.wire.cdr_more
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


# Datawriter (reader False) or datareader: topic id, QoS flags and history depth, and the user
# data xrce.client.type_hash declares (None: none).
def endpoint_blob(topic_id, flags, depth, reader, data=None):
    w = CdrWriter(bytearray(16 if data is None else 24 + len(data)))
    w.u8(topic_id >> 8)
    w.u8(topic_id & 0xFF)
    w.u8(1)
    w.u16(flags)
    w.u8(depth is not None)
    if depth is not None:
        w.u16(depth)
    w.u8(0)  # deadline
    w.u8(0)  # lifespan
    if data is None:
        w.u8(0)  # user data
    else:
        w.u8(1)
        w.u32(len(data))
        for byte in data:
            w.u8(byte)
    w.u8(0)  # ownership strength / time-based filter
    if reader:
        w.u8(0)  # content filter
    return w.getvalue()


def ros_topic_name(name, prefix="rt"):
    # '/chatter' or 'chatter' → 'rt/chatter' (micro-ROS' naming of ROS topics in DDS).
    return prefix + (name if name.startswith("/") else "/" + name)


# ------------------------------------------------------------------ entities

def _create(session, kind, blob, tail_id, object_id_, stream_id, flags, xml=None, ref=None):
    # ``blob``: the binary representation, unused when an ``xml`` or ``ref`` text is given.
    fmt = _REPRESENTATION_IN_BINARY
    if xml is not None or ref is not None:
        # XML and reference creation cost a board nothing until used.
        from xrce.client.representations import textual
        fmt, blob = textual(xml, ref)
    oid = new_object_id(session, kind) if object_id_ is None else object_id_
    rid = session.next_request_id()
    body = create_body(kind, fmt, blob, tail_id)
    session._buffer(stream_id, _CREATE, _FLAG_LITTLE_ENDIAN | flags, rid, oid, body)
    session._statuses[rid] = _STATUS_NONE
    if session.link is not None:
        _forget(session, oid)
        session._creations.append((oid, body))
    return oid


def create_participant(session, domain_id=0, name=None, xml=None, ref=None, object_id=None,
                       stream_id=None, flags=_REUSE_REPLACE):
    # A participant (a ROS node on the agent). Returns its object id; the request is buffered.
    return _create(session, _OBJK_PARTICIPANT, participant_blob(name), domain_id, object_id,
                   stream_id, flags, xml, ref)


def create_topic(session, participant_id, topic_name=None, type_name=None, xml=None, ref=None,
                 object_id=None, stream_id=None, flags=_REUSE_REPLACE):
    blob = topic_blob(topic_name, type_name) if xml is None and ref is None else None
    return _create(session, _OBJK_TOPIC, blob, participant_id, object_id, stream_id, flags, xml, ref)


def create_publisher(session, participant_id, xml=None, object_id=None, stream_id=None,
                     flags=_REUSE_REPLACE):
    return _create(session, _OBJK_PUBLISHER, PUBSUB_BLOB, participant_id, object_id, stream_id,
                   flags, xml)


def create_subscriber(session, participant_id, xml=None, object_id=None, stream_id=None,
                      flags=_REUSE_REPLACE):
    return _create(session, _OBJK_SUBSCRIBER, PUBSUB_BLOB, participant_id, object_id, stream_id,
                   flags, xml)


def endpoint_qos(reliable=True, keep_last=True, depth=10, transient_local=False):
    # ``(flags, history depth)`` for ``create_datawriter``/``create_datareader``, which also
    # take an ``xrce.wire.objects.EndpointQos`` for QoS beyond these.
    flags = (_QOS_RELIABLE if reliable else 0) | (_QOS_KEEP_LAST if keep_last else 0)
    if transient_local:
        flags |= _QOS_TRANSIENT_LOCAL
    return flags, depth if depth else None


def _endpoint(session, kind, tail_id, topic_id, qos, xml, ref, object_id_, stream_id, flags):
    blob = None
    if xml is None and ref is None:
        if qos is None:
            qos = endpoint_qos()
        if isinstance(qos, tuple):
            blob = endpoint_blob(topic_id, qos[0], qos[1], kind == _OBJK_DATAREADER)
        else:  # a full EndpointQos (deadline, lifespan, user data): the general codec
            from xrce.client.representations import endpoint_blob as full_qos_blob
            blob = full_qos_blob(kind, topic_id, qos)
    return _create(session, kind, blob, tail_id, object_id_, stream_id, flags, xml, ref)


def create_datawriter(session, publisher_id, topic_id=None, qos=None, xml=None, ref=None,
                      object_id=None, stream_id=None, flags=_REUSE_REPLACE):
    return _endpoint(session, _OBJK_DATAWRITER, publisher_id, topic_id, qos, xml, ref, object_id,
                     stream_id, flags)


def create_datareader(session, subscriber_id, topic_id=None, qos=None, xml=None, ref=None,
                      object_id=None, stream_id=None, flags=_REUSE_REPLACE):
    return _endpoint(session, _OBJK_DATAREADER, subscriber_id, topic_id, qos, xml, ref, object_id,
                     stream_id, flags)


# ROS-flavoured helpers: one call per publisher/subscription, as rmw_microxrcedds does.

def create_writer(session, participant_id, topic, msg_class, reliable=True, depth=10,
                  transient_local=False, stream_id=None):
    # Topic + publisher + datawriter for a ROS topic ('/chatter') of a generated message class.
    topic_id = create_topic(session, participant_id, ros_topic_name(topic), msg_class.TYPE_NAME,
                            stream_id=stream_id)
    publisher_id = create_publisher(session, participant_id, stream_id=stream_id)
    return create_datawriter(session, publisher_id, topic_id,
                             endpoint_qos(reliable, True, depth, transient_local), stream_id=stream_id)


def create_reader(session, participant_id, topic, msg_class, callback, reliable=True, depth=10,
                  transient_local=False, stream_id=None, data_stream_id=None, into=None):
    # Topic + subscriber + datareader + READ_DATA (unlimited samples) for a ROS topic.
    #
    # ``callback(msg)`` gets decoded ``msg_class`` instances; DATA comes on the reliable input stream
    # for a reliable reader and on the best-effort one otherwise, unless ``data_stream_id`` says.
    # ``into``: a ``msg_class`` instance every sample is decoded into in place and handed to the
    # callback (the same object each time, valid until the next sample): a board then makes no
    # message object per sample.
    topic_id = create_topic(session, participant_id, ros_topic_name(topic), msg_class.TYPE_NAME,
                            stream_id=stream_id)
    subscriber_id = create_subscriber(session, participant_id, stream_id=stream_id)
    reader_id = create_datareader(session, subscriber_id, topic_id,
                                  endpoint_qos(reliable, True, depth, transient_local),
                                  stream_id=stream_id)
    set_reader_callback(session, reader_id, callback, msg_class if into is None else into)
    if data_stream_id is None:
        data_stream_id = session.reliable if reliable else session.best_effort
    read_data(session, reader_id, data_stream_id, stream_id=stream_id)
    return reader_id


# ------------------------------------------------------------------ reading

def set_reader_callback(session, reader_id, callback, msg_class=None):
    # ``callback(data)`` for every DATA of this reader/requester/replier.
    #
    # Datareader: ``data`` is ``msg_class`` decoded, or the raw sample bytes without a class; with
    # an instance for ``msg_class``, that instance with the sample decoded into it.
    # Requester: ``callback(request_id, data)`` with the id ``send_request`` returned.
    # Replier: ``callback(sample_identity, data)``; answer with ``send_reply``.
    session._readers[reader_id] = (callback, msg_class)  # a tuple: no class for a board to load


def read_data(session, reader_id, data_stream_id=None, max_samples=_MAX_SAMPLES_UNLIMITED,
              max_elapsed_time=0, max_bytes_per_second=0, min_pace_period=0, delivery=True,
              stream_id=None):
    # Buffer a READ_DATA asking the agent to deliver samples on ``data_stream_id``.
    control = (max_samples, max_elapsed_time, max_bytes_per_second,
               min_pace_period) if delivery else None
    rid = session.next_request_id()
    if data_stream_id is None:
        data_stream_id = session.reliable
    body = read_data_body(data_stream_id, control)
    session._buffer(stream_id, _READ_DATA, _FLAG_LITTLE_ENDIAN, rid, reader_id, body)
    if session.link is not None:
        session._read_requests[reader_id] = body
    return rid


def cancel_data(session, reader_id, stream_id=None):
    # uxr_buffer_cancel_data: READ_DATA on stream 0, all limits 0. eProsima's agent (and ours)
    # answer it with the reader's next samples on stream 0 until it is read again or deleted.
    rid = session.next_request_id()
    session._buffer(stream_id, _READ_DATA, _FLAG_LITTLE_ENDIAN, rid, reader_id,
                    read_data_body(_STREAM_NONE, (0, 0, 0, 0)))
    session._read_requests.pop(reader_id, None)
    return rid


# ------------------------------------------------------------------ ending things

def delete_entity(session, object_id, stream_id=None):
    # Buffer a DELETE of one entity (the agent deletes its children). Returns the request id.
    rid = session.next_request_id()
    session._buffer(stream_id, _DELETE, _FLAG_LITTLE_ENDIAN, rid, object_id, b"")
    session._statuses[rid] = _STATUS_NONE
    if session.link is not None:
        _forget(session, object_id)
    return rid


# ------------------------------------------------------------------ the re-creation log

def _forget(session, object_id):
    # Drop an entity and everything created under it from the re-creation log. Every creation asks
    # (REPLACE may reuse an id), and almost always about a new id: that is answered without
    # building the lists below (an entity not in the log has no children there either).
    for create in session._creations:
        if create[0] == object_id:
            break
    else:
        return
    gone = [object_id]
    kept = []
    for create in session._creations:
        # The body starts with the kind and, but for a participant, ends with the parent's id.
        oid, body = create
        if oid in gone or (body[0] != _OBJK_PARTICIPANT and (body[-2] << 8 | body[-1]) in gone):
            gone.append(oid)
        else:
            kept.append(create)
    session._creations = kept
    for oid in gone:
        session._read_requests.pop(oid, None)
