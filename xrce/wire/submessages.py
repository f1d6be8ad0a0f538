"""The submessage codec (XRCE-WIRE.md §2–§10): every payload by id, and whole messages.

``decode_payload`` dispatches one submessage by id, ``encode_message``/``decode_message`` turn a
list of payloads into a message and back. The payload classes live along the protocol's seams and
are re-exported here, so ``from xrce.wire.submessages import ...`` reaches every one of them:

- ``xrce.wire.payload``: the ``Payload`` base, id and property encodings, ``write_submessage``;
- ``xrce.wire.session_payloads``: CREATE_CLIENT, STATUS_AGENT, CREATE, DELETE, STATUS, GET_INFO, INFO;
- ``xrce.wire.stream_payloads``: WRITE_DATA, DATA, READ_DATA, ACKNACK, HEARTBEAT, RESET, FRAGMENT,
  TIMESTAMP, TIMESTAMP_REPLY.
"""

from xrce.wire import constants as C
from xrce.wire.cdr import CdrReader
from xrce import DecodeError
from xrce.wire.payload import write_submessage
from xrce.wire.session_payloads import (  # noqa: F401 (re-exported)
    Create, CreateClient, Delete, GetInfo, Info, Locator, Status, StatusAgent,
)
from xrce.wire.stream_payloads import (  # noqa: F401 (re-exported)
    AckNack, Data, DeliveryControl, Fragment, Heartbeat, ReadData, Reset, Timestamp, TimestampReply,
    WriteData, sample_ids,
)

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


def encode_message(session_id, stream_id, seq, key, payloads, pad=False):
    """One whole message as bytes; ``pad`` adds the client's trailing padding to a multiple of 4."""
    from xrce.wire.message import MessageWriter
    mw = MessageWriter(64)
    mw.begin(session_id, stream_id, seq, key)
    for payload in payloads:
        write_submessage(mw, payload)
    if pad:
        mw.pad_to_4()
    return mw.getvalue()


def decode_message(buf):
    """``(Header, [payload objects])`` of a whole message; DecodeError on anything malformed."""
    from xrce.wire.message import decode_header, iter_submessages
    header = decode_header(buf)
    payloads = [decode_payload(sub_id, flags, buf, start, end)
                for sub_id, flags, start, end in iter_submessages(buf, header.size)]
    return header, payloads
