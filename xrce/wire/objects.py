"""Object ids and object representations (XRCE-WIRE.md §4).

Binary representations are CDR blobs with their own alignment origin (the blob start). Each blob
class encodes and decodes symmetrically; ``to_blob``/``from_blob`` give the bytes carried in CREATE.
"""

from xrce.wire.cdr import CdrReader, CdrWriter
from xrce.wire.constants import (
    OBJK_DATAREADER, OBJK_DATAWRITER, OBJK_PARTICIPANT, OBJK_PUBLISHER, OBJK_REPLIER,
    OBJK_REQUESTER, OBJK_SUBSCRIBER, OBJK_TOPIC, QOS_KEEP_LAST, QOS_RELIABLE, QOS_TRANSIENT_LOCAL,
)
from xrce import DecodeError, EncodeError


def object_id(index, kind):
    """16-bit object id: a 12-bit index and a 4-bit kind."""
    if not 0 <= index <= 0xFFF:
        raise EncodeError("object index must be 0..4095")
    return (index << 4) | (kind & 0x0F)


def object_kind(oid):
    return oid & 0x0F


def with_kind(oid, kind):
    return (oid & 0xFFF0) | kind


def _opt_string(w, value):
    w.boolean(value is not None)
    if value is not None:
        w.string(value)


def _read_opt_string(r):
    return r.string() if r.boolean() else None


def _write_id(w, oid):
    w.u8(oid >> 8)
    w.u8(oid & 0xFF)


def _read_id(r):
    return (r.u8() << 8) | r.u8()


class _Blob:
    KIND = 0

    def to_blob(self):
        w = CdrWriter(bytearray(32))
        self.encode(w)
        return w.getvalue()

    @classmethod
    def from_blob(cls, data, little=True):
        r = CdrReader(data, little=little)
        obj = cls.decode(r)
        return obj

    def __eq__(self, other):
        return type(self) is type(other) and all(
            getattr(self, name) == getattr(other, name) for name in self.__slots__)

    def __repr__(self):
        return "%s(%s)" % (type(self).__name__, ", ".join(
            "%s=%r" % (name, getattr(self, name)) for name in self.__slots__))


class ParticipantBin(_Blob):
    """``domain_reference`` is unused by eProsima; ``name`` travels in the qos-profile slot."""
    KIND = OBJK_PARTICIPANT
    __slots__ = ("domain_reference", "name")

    def __init__(self, name=None, domain_reference=None):
        self.name = name
        self.domain_reference = domain_reference

    def encode(self, w):
        _opt_string(w, self.domain_reference)
        _opt_string(w, self.name)

    @classmethod
    def decode(cls, r):
        domain_reference = _read_opt_string(r)
        return cls(_read_opt_string(r), domain_reference)


class TopicBin(_Blob):
    KIND = OBJK_TOPIC
    __slots__ = ("topic_name", "type_reference", "type_name")

    def __init__(self, topic_name, type_name=None, type_reference=None):
        self.topic_name = topic_name
        self.type_name = type_name
        self.type_reference = type_reference

    def encode(self, w):
        w.string(self.topic_name)
        _opt_string(w, self.type_reference)
        _opt_string(w, self.type_name)

    @classmethod
    def decode(cls, r):
        topic_name = r.string()
        type_reference = _read_opt_string(r)
        return cls(topic_name, _read_opt_string(r), type_reference)


class PubSubBin(_Blob):
    """Publisher/subscriber: optional name and optional QoS (partitions, group data)."""
    KIND = OBJK_PUBLISHER
    __slots__ = ("name", "partitions", "group_data", "has_qos")

    def __init__(self, name=None, partitions=None, group_data=None, has_qos=False):
        self.name = name
        self.partitions = partitions
        self.group_data = group_data
        self.has_qos = has_qos or partitions is not None or group_data is not None

    def encode(self, w):
        _opt_string(w, self.name)
        w.boolean(self.has_qos)
        if self.has_qos:
            w.boolean(self.partitions is not None)
            if self.partitions is not None:
                w.u32(len(self.partitions))
                for p in self.partitions:
                    w.string(p)
            w.boolean(self.group_data is not None)
            if self.group_data is not None:
                w.octets(self.group_data)

    @classmethod
    def decode(cls, r):
        name = _read_opt_string(r)
        partitions = group_data = None
        has_qos = r.boolean()
        if has_qos:
            if r.boolean():
                count = r.u32()
                if count > r.remaining():
                    raise DecodeError("partition count exceeds the blob")
                partitions = [r.string() for _ in range(count)]
            if r.boolean():
                group_data = r.octets()
        return cls(name, partitions, group_data, has_qos)


class EndpointQos:
    """QoS of a datawriter/datareader as the binary representation carries it."""
    __slots__ = ("flags", "history_depth", "deadline_ms", "lifespan_ms", "user_data")

    def __init__(self, flags=QOS_RELIABLE | QOS_KEEP_LAST, history_depth=None, deadline_ms=None,
                 lifespan_ms=None, user_data=None):
        self.flags = flags
        self.history_depth = history_depth
        self.deadline_ms = deadline_ms
        self.lifespan_ms = lifespan_ms
        self.user_data = user_data

    @property
    def reliable(self):
        return bool(self.flags & QOS_RELIABLE)

    @property
    def keep_last(self):
        return bool(self.flags & QOS_KEEP_LAST)

    @property
    def transient_local(self):
        return bool(self.flags & QOS_TRANSIENT_LOCAL)

    def encode(self, w):
        w.u16(self.flags)
        w.boolean(self.history_depth is not None)
        if self.history_depth is not None:
            w.u16(self.history_depth)
        w.boolean(self.deadline_ms is not None)
        if self.deadline_ms is not None:
            w.u32(self.deadline_ms)
        w.boolean(self.lifespan_ms is not None)
        if self.lifespan_ms is not None:
            w.u32(self.lifespan_ms)
        w.boolean(self.user_data is not None)
        if self.user_data is not None:
            w.octets(self.user_data)

    @classmethod
    def decode(cls, r):
        flags = r.u16()
        depth = r.u16() if r.boolean() else None
        deadline = r.u32() if r.boolean() else None
        lifespan = r.u32() if r.boolean() else None
        user_data = r.octets() if r.boolean() else None
        return cls(flags, depth, deadline, lifespan, user_data)

    def __eq__(self, other):
        return isinstance(other, EndpointQos) and all(
            getattr(self, n) == getattr(other, n) for n in self.__slots__)

    def __repr__(self):
        return "EndpointQos(flags=0x%04X, depth=%r)" % (self.flags, self.history_depth)


class DataWriterBin(_Blob):
    KIND = OBJK_DATAWRITER
    __slots__ = ("topic_id", "qos", "ownership_strength")

    def __init__(self, topic_id, qos=None, ownership_strength=None):
        self.topic_id = topic_id
        self.qos = qos
        self.ownership_strength = ownership_strength

    def encode(self, w):
        _write_id(w, self.topic_id)
        w.boolean(self.qos is not None)
        if self.qos is not None:
            self.qos.encode(w)
            w.boolean(self.ownership_strength is not None)
            if self.ownership_strength is not None:
                w.u64(self.ownership_strength)

    @classmethod
    def decode(cls, r):
        topic_id = _read_id(r)
        qos = strength = None
        if r.boolean():
            qos = EndpointQos.decode(r)
            if r.boolean():
                strength = r.u64()
        return cls(topic_id, qos, strength)


class DataReaderBin(_Blob):
    KIND = OBJK_DATAREADER
    __slots__ = ("topic_id", "qos", "timebased_filter_ms", "content_filter")

    def __init__(self, topic_id, qos=None, timebased_filter_ms=None, content_filter=None):
        self.topic_id = topic_id
        self.qos = qos
        self.timebased_filter_ms = timebased_filter_ms
        self.content_filter = content_filter

    def encode(self, w):
        _write_id(w, self.topic_id)
        w.boolean(self.qos is not None)
        if self.qos is not None:
            self.qos.encode(w)
            w.boolean(self.timebased_filter_ms is not None)
            if self.timebased_filter_ms is not None:
                w.u64(self.timebased_filter_ms)
            _opt_string(w, self.content_filter)

    @classmethod
    def decode(cls, r):
        topic_id = _read_id(r)
        qos = tbf = cf = None
        if r.boolean():
            qos = EndpointQos.decode(r)
            if r.boolean():
                tbf = r.u64()
            cf = _read_opt_string(r)
        return cls(topic_id, qos, tbf, cf)


class RequesterBin(_Blob):
    """Requester and replier share one layout (service name, types, optional topic names)."""
    KIND = OBJK_REQUESTER
    __slots__ = ("service_name", "request_type", "reply_type", "request_topic", "reply_topic")

    def __init__(self, service_name, request_type, reply_type, request_topic=None, reply_topic=None):
        self.service_name = service_name
        self.request_type = request_type
        self.reply_type = reply_type
        self.request_topic = request_topic
        self.reply_topic = reply_topic

    def encode(self, w):
        w.string(self.service_name)
        w.string(self.request_type)
        w.string(self.reply_type)
        _opt_string(w, self.request_topic)
        _opt_string(w, self.reply_topic)

    @classmethod
    def decode(cls, r):
        return cls(r.string(), r.string(), r.string(), _read_opt_string(r), _read_opt_string(r))


class ReplierBin(RequesterBin):
    KIND = OBJK_REPLIER


BLOB_CLASSES = {
    OBJK_PARTICIPANT: ParticipantBin,
    OBJK_TOPIC: TopicBin,
    OBJK_PUBLISHER: PubSubBin,
    OBJK_SUBSCRIBER: PubSubBin,
    OBJK_DATAWRITER: DataWriterBin,
    OBJK_DATAREADER: DataReaderBin,
    OBJK_REQUESTER: RequesterBin,
    OBJK_REPLIER: ReplierBin,
}

# The object kind a CREATE's parent id must have (the agent forces this nibble, §4).
PARENT_KIND = {
    OBJK_TOPIC: OBJK_PARTICIPANT,
    OBJK_PUBLISHER: OBJK_PARTICIPANT,
    OBJK_SUBSCRIBER: OBJK_PARTICIPANT,
    OBJK_REQUESTER: OBJK_PARTICIPANT,
    OBJK_REPLIER: OBJK_PARTICIPANT,
    OBJK_DATAWRITER: OBJK_PUBLISHER,
    OBJK_DATAREADER: OBJK_SUBSCRIBER,
}
