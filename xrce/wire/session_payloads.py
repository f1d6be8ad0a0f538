"""Payloads that open a session and manage its objects: CREATE_CLIENT and STATUS_AGENT
(XRCE-WIRE.md §3), CREATE, DELETE and STATUS (§4, §5), GET_INFO and INFO with its locators (§10).

The payload conventions are in ``xrce.wire.payload``; ``xrce.wire.submessages`` re-exports every class.
"""

from xrce.wire import constants as C
from xrce.wire.cdr import CdrReader
from xrce import DecodeError, EncodeError
from xrce.wire.objects import BLOB_CLASSES
from xrce.wire.payload import Payload, read_id, read_properties, write_id, write_properties


def _write_cookie_version_vendor(w, cookie, version, vendor):
    # The "XRCE" cookie, protocol version and vendor id: the start of CREATE_CLIENT and of
    # STATUS_AGENT after its status (§3), and the agent's configuration in INFO (§10).
    w.raw(cookie)
    w.raw(version)
    w.raw(vendor)


def _read_cookie_version_vendor(r):
    return r.raw(4), r.raw(2), r.raw(2)


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
        _write_cookie_version_vendor(w, self.cookie, self.version, self.vendor)
        w.raw(self.client_key)
        w.u8(self.session_id)
        write_properties(w, self.properties)
        w.u16(self.mtu)

    @classmethod
    def decode(cls, r, flags):
        cookie, version, vendor = _read_cookie_version_vendor(r)
        key = r.raw(4)
        session_id = r.u8()
        properties = read_properties(r)
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
        _write_cookie_version_vendor(w, self.cookie, self.version, self.vendor)
        write_properties(w, self.properties)

    @classmethod
    def decode(cls, r, flags):
        status = r.u8()
        impl = r.u8()
        cookie, version, vendor = _read_cookie_version_vendor(r)
        return cls(status, impl, read_properties(r), cookie, version, vendor, flags)


class Create(Payload):
    """CREATE: an object representation by reference, XML or binary, plus its kind-specific tail.

    ``representation`` is a str for reference/XML and a blob object (xrce.wire.objects) for binary.
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
        write_id(w, self.request_id)
        write_id(w, self.object_id)
        w.u8(self.kind)
        w.u8(self.fmt)
        if self.fmt == C.REPRESENTATION_IN_BINARY:
            w.octets(self.representation.to_blob())
        else:
            w.string(self.representation)
        if self.kind == C.OBJK_PARTICIPANT:
            w.i16(self.tail_id)
        elif self.kind in BLOB_CLASSES:
            write_id(w, self.tail_id)

    @classmethod
    def decode(cls, r, flags):
        request_id = read_id(r)
        object_id = read_id(r)
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
            tail = read_id(r)
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
        write_id(w, self.request_id)
        write_id(w, self.object_id)
        w.u32(self.info_mask)

    @classmethod
    def decode(cls, r, flags):
        return cls(read_id(r), read_id(r), r.u32(), flags)


class Delete(Payload):
    ID = C.DELETE
    FIELDS = ("request_id", "object_id")
    __slots__ = FIELDS

    def __init__(self, request_id, object_id, flags=1):
        self.request_id = request_id
        self.object_id = object_id
        self.flags = flags

    def encode(self, w):
        write_id(w, self.request_id)
        write_id(w, self.object_id)

    @classmethod
    def decode(cls, r, flags):
        return cls(read_id(r), read_id(r), flags)


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
        write_id(w, self.request_id)
        write_id(w, self.object_id)
        w.u8(self.status)
        w.u8(self.impl_status)

    @classmethod
    def decode(cls, r, flags):
        return cls(read_id(r), read_id(r), r.u8(), r.u8(), flags)


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
        write_id(w, self.request_id)
        write_id(w, self.object_id)
        w.u8(self.status)
        w.u8(self.impl_status)
        w.boolean(self.config is not None)
        if self.config is not None:
            w.u8(C.OBJK_AGENT)
            for part in self.config:
                w.raw(part)
            write_properties(w, self.properties)
        w.boolean(self.availability is not None)
        if self.availability is not None:
            w.u8(C.OBJK_AGENT)
            w.i16(self.availability)
            w.u32(len(self.locators))
            for locator in self.locators:
                locator.encode(w)

    @classmethod
    def decode(cls, r, flags):
        request_id = read_id(r)
        object_id = read_id(r)
        status = r.u8()
        impl = r.u8()
        config = properties = availability = None
        locators = []
        if r.boolean():
            if r.u8() != C.OBJK_AGENT:
                raise DecodeError("INFO configuration is not an agent's")
            config = _read_cookie_version_vendor(r)
            properties = read_properties(r)
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
