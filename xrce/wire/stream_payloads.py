"""Payloads that travel on the streams: WRITE_DATA, DATA and READ_DATA (XRCE-WIRE.md §6), ACKNACK,
HEARTBEAT and RESET (§7), FRAGMENT (§8), TIMESTAMP and TIMESTAMP_REPLY (§9).

The payload conventions are in ``xrce.wire.payload``; ``xrce.wire.submessages`` re-exports every class.
"""

from xrce.wire import constants as C
from xrce import DecodeError
from xrce.wire.payload import Payload, read_id, write_id


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
        write_id(w, self.request_id)
        write_id(w, self.object_id)
        w.raw(self.data)

    @classmethod
    def decode(cls, r, flags):
        return cls(read_id(r), read_id(r), r.rest(), flags)


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
        write_id(w, self.request_id)
        write_id(w, self.object_id)
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
        request_id = read_id(r)
        object_id = read_id(r)
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
