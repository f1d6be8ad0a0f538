"""Payloads of every submessage eProsima uses (XRCE-WIRE.md §2–§10), encoded and decoded in one place.

Each payload class has ``ID``, a ``flags`` attribute, ``encode(w)`` writing the payload into a
CdrWriter whose origin is the message start, and ``decode(r, flags)`` reading it back. ``decode_payload``
dispatches by submessage id. Request and object ids are 16-bit ints sent big-endian (raw byte pairs).
"""

from xrce import constants as C
from xrce.cdr import CdrReader
from xrce.errors import DecodeError, EncodeError
from xrce.objects import BLOB_CLASSES


def _write_id(w, value):
    w.u8((value >> 8) & 0xFF)
    w.u8(value & 0xFF)


def _read_id(r):
    return (r.u8() << 8) | r.u8()


def _write_properties(w, properties):
    w.boolean(properties is not None)
    if properties is not None:
        w.u32(len(properties))
        for name, value in properties:
            w.string(name)
            w.string(value)


def _read_properties(r):
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


class CreateClient(Payload):
    ID = C.CREATE_CLIENT
    FIELDS = ("client_key", "session_id", "mtu", "properties", "cookie", "version", "vendor")
    __slots__ = FIELDS

    def __init__(self, client_key, session_id=C.DEFAULT_SESSION_ID, mtu=508, properties=None,
                 cookie=C.XRCE_COOKIE, version=C.XRCE_VERSION, vendor=C.XRCE_VENDOR_EPROSIMA, flags=1):
        self.client_key = client_key
        self.session_id = session_id
        self.mtu = mtu
        self.properties = properties
        self.cookie = cookie
        self.version = version
        self.vendor = vendor
        self.flags = flags

    def encode(self, w):
        w.raw(self.cookie)
        w.raw(self.version)
        w.raw(self.vendor)
        w.raw(self.client_key)
        w.u8(self.session_id)
        _write_properties(w, self.properties)
        w.u16(self.mtu)

    @classmethod
    def decode(cls, r, flags):
        cookie = r.raw(4)
        version = r.raw(2)
        vendor = r.raw(2)
        key = r.raw(4)
        session_id = r.u8()
        properties = _read_properties(r)
        try:
            mtu = r.u16()
        except DecodeError:  # a pre-2019 client without the mtu field
            mtu = None
        return cls(key, session_id, mtu, properties, cookie, version, vendor, flags)


class StatusAgent(Payload):
    ID = C.STATUS_AGENT
    FIELDS = ("status", "impl_status", "properties", "cookie", "version", "vendor")
    __slots__ = FIELDS

    def __init__(self, status=C.STATUS_OK, impl_status=0, properties=None, cookie=C.XRCE_COOKIE,
                 version=C.XRCE_VERSION, vendor=C.XRCE_VENDOR_EPROSIMA, flags=1):
        self.status = status
        self.impl_status = impl_status
        self.properties = properties
        self.cookie = cookie
        self.version = version
        self.vendor = vendor
        self.flags = flags

    def encode(self, w):
        w.u8(self.status)
        w.u8(self.impl_status)
        w.raw(self.cookie)
        w.raw(self.version)
        w.raw(self.vendor)
        _write_properties(w, self.properties)

    @classmethod
    def decode(cls, r, flags):
        status = r.u8()
        impl = r.u8()
        cookie = r.raw(4)
        version = r.raw(2)
        vendor = r.raw(2)
        return cls(status, impl, _read_properties(r), cookie, version, vendor, flags)


class Create(Payload):
    """CREATE: an object representation by reference, XML or binary, plus its kind-specific tail.

    ``representation`` is a str for reference/XML and a blob object (xrce.objects) for binary.
    ``tail_id`` is the parent ObjectId, or the domain id for a participant.
    """
    ID = C.CREATE
    FIELDS = ("request_id", "object_id", "kind", "fmt", "representation", "tail_id", "flags")
    __slots__ = FIELDS + ("raw_representation",)

    def __init__(self, request_id, object_id, kind, fmt, representation, tail_id=0,
                 flags=C.FLAG_LITTLE_ENDIAN, raw_representation=None):
        self.request_id = request_id
        self.object_id = object_id
        self.kind = kind
        self.fmt = fmt
        self.representation = representation
        self.tail_id = tail_id
        self.flags = flags
        self.raw_representation = raw_representation

    @property
    def reuse(self):
        return bool(self.flags & C.FLAG_REUSE)

    @property
    def replace(self):
        return bool(self.flags & C.FLAG_REPLACE)

    def representation_bytes(self):
        """The string or blob bytes exactly as carried (the agent compares them for REUSE)."""
        if self.raw_representation is not None:
            return self.raw_representation
        if self.fmt == C.REPRESENTATION_IN_BINARY:
            return self.representation.to_blob()
        return self.representation.encode() + b"\x00"

    def encode(self, w):
        _write_id(w, self.request_id)
        _write_id(w, self.object_id)
        w.u8(self.kind)
        w.u8(self.fmt)
        if self.fmt == C.REPRESENTATION_IN_BINARY:
            w.octets(self.representation.to_blob())
        else:
            w.string(self.representation)
        if self.kind == C.OBJK_PARTICIPANT:
            w.i16(self.tail_id)
        elif self.kind in BLOB_CLASSES:
            _write_id(w, self.tail_id)

    @classmethod
    def decode(cls, r, flags):
        request_id = _read_id(r)
        object_id = _read_id(r)
        kind = r.u8()
        fmt = r.u8()
        if fmt not in (C.REPRESENTATION_BY_REFERENCE, C.REPRESENTATION_AS_XML_STRING,
                       C.REPRESENTATION_IN_BINARY):
            raise DecodeError("unknown representation format %d" % fmt)
        raw = r.octets()
        if fmt == C.REPRESENTATION_IN_BINARY:
            blob_cls = BLOB_CLASSES.get(kind)
            if blob_cls is None:
                raise DecodeError("no binary representation for object kind %d" % kind)
            blob_reader = CdrReader(raw, little=bool(flags & C.FLAG_LITTLE_ENDIAN))
            representation = blob_cls.decode(blob_reader)
        else:
            if not raw:
                representation = ""
            elif raw[-1] != 0:
                raise DecodeError("representation string not NUL-terminated")
            else:
                try:
                    representation = raw[:-1].decode()
                except UnicodeError:
                    raise DecodeError("representation string is not UTF-8")
        tail = 0
        if kind == C.OBJK_PARTICIPANT:
            tail = r.i16()
        elif kind in BLOB_CLASSES:
            tail = _read_id(r)
        return cls(request_id, object_id, kind, fmt, representation, tail, flags, raw)


class GetInfo(Payload):
    ID = C.GET_INFO
    FIELDS = ("request_id", "object_id", "info_mask")
    __slots__ = FIELDS

    def __init__(self, request_id=C.REQUEST_ID_PING, object_id=C.OBJECTID_AGENT,
                 info_mask=C.INFO_ACTIVITY, flags=1):
        self.request_id = request_id
        self.object_id = object_id
        self.info_mask = info_mask
        self.flags = flags

    def encode(self, w):
        _write_id(w, self.request_id)
        _write_id(w, self.object_id)
        w.u32(self.info_mask)

    @classmethod
    def decode(cls, r, flags):
        return cls(_read_id(r), _read_id(r), r.u32(), flags)


class Delete(Payload):
    ID = C.DELETE
    FIELDS = ("request_id", "object_id")
    __slots__ = FIELDS

    def __init__(self, request_id, object_id, flags=1):
        self.request_id = request_id
        self.object_id = object_id
        self.flags = flags

    def encode(self, w):
        _write_id(w, self.request_id)
        _write_id(w, self.object_id)

    @classmethod
    def decode(cls, r, flags):
        return cls(_read_id(r), _read_id(r), flags)


class Status(Payload):
    ID = C.STATUS
    FIELDS = ("request_id", "object_id", "status", "impl_status")
    __slots__ = FIELDS

    def __init__(self, request_id, object_id, status=C.STATUS_OK, impl_status=0, flags=1):
        self.request_id = request_id
        self.object_id = object_id
        self.status = status
        self.impl_status = impl_status
        self.flags = flags

    def encode(self, w):
        _write_id(w, self.request_id)
        _write_id(w, self.object_id)
        w.u8(self.status)
        w.u8(self.impl_status)

    @classmethod
    def decode(cls, r, flags):
        return cls(_read_id(r), _read_id(r), r.u8(), r.u8(), flags)


class Locator:
    """TransportLocator: ``fmt`` SMALL/MEDIUM/LARGE with raw ``address`` bytes and ``port``, or
    STRING with ``address`` a str."""
    __slots__ = ("fmt", "address", "port")
    _ADDRESS_SIZE = {C.LOCATOR_SMALL: 2, C.LOCATOR_MEDIUM: 4, C.LOCATOR_LARGE: 16}

    def __init__(self, fmt, address, port=0):
        self.fmt = fmt
        self.address = address
        self.port = port

    def encode(self, w):
        w.u8(self.fmt)
        if self.fmt == C.LOCATOR_STRING:
            w.string(self.address)
            return
        size = self._ADDRESS_SIZE.get(self.fmt)
        if size is None or len(self.address) != size:
            raise EncodeError("bad locator")
        w.raw(self.address)
        if self.fmt == C.LOCATOR_SMALL:
            w.u8(self.port)
        elif self.fmt == C.LOCATOR_MEDIUM:
            w.u16(self.port)
        else:
            w.u32(self.port)

    @classmethod
    def decode(cls, r):
        fmt = r.u8()
        if fmt == C.LOCATOR_STRING:
            return cls(fmt, r.string())
        size = cls._ADDRESS_SIZE.get(fmt)
        if size is None:
            raise DecodeError("unknown locator format %d" % fmt)
        address = r.raw(size)
        port = r.u8() if fmt == C.LOCATOR_SMALL else r.u16() if fmt == C.LOCATOR_MEDIUM else r.u32()
        return cls(fmt, address, port)

    def __eq__(self, other):
        return isinstance(other, Locator) and (self.fmt, self.address, self.port) == (
            other.fmt, other.address, other.port)

    def __repr__(self):
        return "Locator(%d, %r, %d)" % (self.fmt, self.address, self.port)


class Info(Payload):
    """INFO about the agent: its configuration and activity (availability, locators)."""
    ID = C.INFO
    FIELDS = ("request_id", "object_id", "status", "impl_status", "config", "availability",
              "locators")
    __slots__ = FIELDS + ("properties",)

    def __init__(self, request_id, object_id=C.OBJECTID_AGENT, status=C.STATUS_OK, impl_status=0,
                 config=(C.XRCE_COOKIE, C.XRCE_VERSION, C.XRCE_VENDOR_EPROSIMA), availability=1,
                 locators=(), properties=None, flags=1):
        self.request_id = request_id
        self.object_id = object_id
        self.status = status
        self.impl_status = impl_status
        self.config = config  # (cookie, version, vendor) or None
        self.availability = availability  # None when there is no activity part
        self.locators = list(locators)
        self.properties = properties
        self.flags = flags

    def encode(self, w):
        _write_id(w, self.request_id)
        _write_id(w, self.object_id)
        w.u8(self.status)
        w.u8(self.impl_status)
        w.boolean(self.config is not None)
        if self.config is not None:
            w.u8(C.OBJK_AGENT)
            for part in self.config:
                w.raw(part)
            _write_properties(w, self.properties)
        w.boolean(self.availability is not None)
        if self.availability is not None:
            w.u8(C.OBJK_AGENT)
            w.i16(self.availability)
            w.u32(len(self.locators))
            for locator in self.locators:
                locator.encode(w)

    @classmethod
    def decode(cls, r, flags):
        request_id = _read_id(r)
        object_id = _read_id(r)
        status = r.u8()
        impl = r.u8()
        config = properties = availability = None
        locators = []
        if r.boolean():
            if r.u8() != C.OBJK_AGENT:
                raise DecodeError("INFO configuration is not an agent's")
            config = (r.raw(4), r.raw(2), r.raw(2))
            properties = _read_properties(r)
        if r.boolean():
            if r.u8() != C.OBJK_AGENT:
                raise DecodeError("INFO activity is not an agent's")
            availability = r.i16()
            count = r.u32()
            if count * 3 > r.remaining():
                raise DecodeError("locator count exceeds the payload")
            locators = [Locator.decode(r) for _ in range(count)]
        return cls(request_id, object_id, status, impl, config, availability, locators, properties,
                   flags)


class WriteData(Payload):
    """WRITE_DATA (client → agent) with FORMAT_DATA: the bare serialized sample follows."""
    ID = C.WRITE_DATA
    FIELDS = ("request_id", "object_id", "data")
    __slots__ = FIELDS

    def __init__(self, request_id, object_id, data, flags=C.FLAG_LITTLE_ENDIAN | C.FORMAT_DATA):
        self.request_id = request_id
        self.object_id = object_id
        self.data = data
        self.flags = flags

    def encode(self, w):
        _write_id(w, self.request_id)
        _write_id(w, self.object_id)
        w.raw(self.data)

    @classmethod
    def decode(cls, r, flags):
        return cls(_read_id(r), _read_id(r), r.rest(), flags)


class Data(WriteData):
    """DATA (agent → client): same layout as WRITE_DATA."""
    ID = C.DATA


def sample_ids(buf, start, end):
    """``(request_id, object_id)`` of a WRITE_DATA/DATA payload in ``buf[start:end]``; its sample
    starts at ``start + 4``. The agent's per-sample path uses this instead of building a WriteData."""
    if end - start < 4:
        raise DecodeError("WRITE_DATA shorter than its request and object ids")
    return (buf[start] << 8) | buf[start + 1], (buf[start + 2] << 8) | buf[start + 3]


class DeliveryControl:
    __slots__ = ("max_samples", "max_elapsed_time", "max_bytes_per_second", "min_pace_period")

    def __init__(self, max_samples=C.MAX_SAMPLES_UNLIMITED, max_elapsed_time=0,
                 max_bytes_per_second=0, min_pace_period=0):
        self.max_samples = max_samples
        self.max_elapsed_time = max_elapsed_time
        self.max_bytes_per_second = max_bytes_per_second
        self.min_pace_period = min_pace_period

    def __eq__(self, other):
        return isinstance(other, DeliveryControl) and all(
            getattr(self, n) == getattr(other, n) for n in self.__slots__)

    def __repr__(self):
        return "DeliveryControl(%d, %d, %d, %d)" % (
            self.max_samples, self.max_elapsed_time, self.max_bytes_per_second, self.min_pace_period)


class ReadData(Payload):
    ID = C.READ_DATA
    FIELDS = ("request_id", "object_id", "stream_id", "data_format", "content_filter", "delivery")
    __slots__ = FIELDS

    def __init__(self, request_id, object_id, stream_id, delivery=None, content_filter=None,
                 data_format=C.FORMAT_DATA, flags=1):
        self.request_id = request_id
        self.object_id = object_id
        self.stream_id = stream_id
        self.delivery = delivery
        self.content_filter = content_filter
        self.data_format = data_format
        self.flags = flags

    def encode(self, w):
        _write_id(w, self.request_id)
        _write_id(w, self.object_id)
        w.u8(self.stream_id)
        w.u8(self.data_format)
        w.boolean(self.content_filter is not None)
        if self.content_filter is not None:
            w.string(self.content_filter)
        w.boolean(self.delivery is not None)
        if self.delivery is not None:
            d = self.delivery
            w.u16(d.max_samples)
            w.u16(d.max_elapsed_time)
            w.u16(d.max_bytes_per_second)
            w.u16(d.min_pace_period)

    @classmethod
    def decode(cls, r, flags):
        request_id = _read_id(r)
        object_id = _read_id(r)
        stream_id = r.u8()
        data_format = r.u8()
        content_filter = r.string() if r.boolean() else None
        delivery = None
        if r.boolean():
            delivery = DeliveryControl(r.u16(), r.u16(), r.u16(), r.u16())
        return cls(request_id, object_id, stream_id, delivery, content_filter, data_format, flags)


class AckNack(Payload):
    ID = C.ACKNACK
    FIELDS = ("first_unacked", "nack_bitmap", "stream_id")
    __slots__ = FIELDS

    def __init__(self, first_unacked, nack_bitmap, stream_id, flags=1):
        self.first_unacked = first_unacked
        self.nack_bitmap = nack_bitmap
        self.stream_id = stream_id
        self.flags = flags

    def encode(self, w):
        w.u16(self.first_unacked)
        w.u8((self.nack_bitmap >> 8) & 0xFF)
        w.u8(self.nack_bitmap & 0xFF)
        w.u8(self.stream_id)

    @classmethod
    def decode(cls, r, flags):
        first = r.u16()
        bitmap = (r.u8() << 8) | r.u8()
        return cls(first, bitmap, r.u8(), flags)


class Heartbeat(Payload):
    ID = C.HEARTBEAT
    FIELDS = ("first_unacked", "last_unacked", "stream_id")
    __slots__ = FIELDS

    def __init__(self, first_unacked, last_unacked, stream_id, flags=1):
        self.first_unacked = first_unacked
        self.last_unacked = last_unacked
        self.stream_id = stream_id
        self.flags = flags

    def encode(self, w):
        w.u16(self.first_unacked)
        w.u16(self.last_unacked)
        w.u8(self.stream_id)

    @classmethod
    def decode(cls, r, flags):
        return cls(r.u16(), r.u16(), r.u8(), flags)


class Reset(Payload):
    ID = C.RESET
    FIELDS = ()
    __slots__ = ()

    def __init__(self, flags=1):
        self.flags = flags

    def encode(self, w):
        pass

    @classmethod
    def decode(cls, r, flags):
        return cls(flags)


class Fragment(Payload):
    ID = C.FRAGMENT
    FIELDS = ("data", "last")
    __slots__ = ("data",)

    def __init__(self, data, flags=1):
        self.data = data
        self.flags = flags

    @property
    def last(self):
        return bool(self.flags & C.FLAG_LAST_FRAGMENT)

    def encode(self, w):
        w.raw(self.data)

    @classmethod
    def decode(cls, r, flags):
        return cls(r.rest(), flags)


class Timestamp(Payload):
    ID = C.TIMESTAMP
    FIELDS = ("sec", "nsec")
    __slots__ = FIELDS

    def __init__(self, sec, nsec, flags=1):
        self.sec = sec
        self.nsec = nsec
        self.flags = flags

    @classmethod
    def from_ns(cls, ns):
        return cls(ns // 1000000000, ns % 1000000000)

    def ns(self):
        return self.sec * 1000000000 + self.nsec

    def encode(self, w):
        w.i32(self.sec)
        w.u32(self.nsec)

    @classmethod
    def decode(cls, r, flags):
        return cls(r.i32(), r.u32(), flags)


class TimestampReply(Payload):
    """Stamps in nanoseconds since the epoch: agent transmit, agent receive, client originate."""
    ID = C.TIMESTAMP_REPLY
    FIELDS = ("transmit_ns", "receive_ns", "originate_ns")
    __slots__ = FIELDS

    def __init__(self, transmit_ns, receive_ns, originate_ns, flags=1):
        self.transmit_ns = transmit_ns
        self.receive_ns = receive_ns
        self.originate_ns = originate_ns
        self.flags = flags

    def encode(self, w):
        for ns in (self.transmit_ns, self.receive_ns, self.originate_ns):
            w.i32(ns // 1000000000)
            w.u32(ns % 1000000000)

    @classmethod
    def decode(cls, r, flags):
        stamps = []
        for _ in range(3):
            sec = r.i32()
            stamps.append(sec * 1000000000 + r.u32())
        return cls(stamps[0], stamps[1], stamps[2], flags)


PAYLOAD_CLASSES = {
    cls.ID: cls for cls in (CreateClient, StatusAgent, Create, GetInfo, Delete, Status, Info,
                            WriteData, ReadData, Data, AckNack, Heartbeat, Reset, Fragment,
                            Timestamp, TimestampReply)
}


def decode_payload(sub_id, flags, buf, start, end):
    """Decode one submessage payload; alignment is counted from buf[0], the message start."""
    cls = PAYLOAD_CLASSES.get(sub_id)
    if cls is None:
        raise DecodeError("unknown submessage id %d" % sub_id)
    r = CdrReader(buf, start, end, 0, bool(flags & C.FLAG_LITTLE_ENDIAN))
    return cls.decode(r, flags)


def write_submessage(mw, payload):
    """Append ``payload`` as a submessage to a MessageWriter."""
    payload.encode(mw.begin_submessage(payload.ID, payload.flags))
    # The eProsima client writes length 16 for CREATE_CLIENT even when properties follow (§3).
    mw.end_submessage(16 if payload.ID == C.CREATE_CLIENT else None)


def encode_message(session_id, stream_id, seq, key, payloads, pad=False):
    """One whole message as bytes; ``pad`` adds the client's trailing padding to a multiple of 4."""
    from xrce.message import MessageWriter
    mw = MessageWriter(64)
    mw.begin(session_id, stream_id, seq, key)
    for payload in payloads:
        write_submessage(mw, payload)
    if pad:
        mw.pad_to_4()
    return mw.getvalue()


def decode_message(buf):
    """``(Header, [payload objects])`` of a whole message; DecodeError on anything malformed."""
    from xrce.message import decode_header, iter_submessages
    header = decode_header(buf)
    payloads = [decode_payload(sub_id, flags, buf, start, end)
                for sub_id, flags, start, end in iter_submessages(buf, header.size)]
    return header, payloads
