# Fragmentation (XRCE-WIRE.md §8): samples larger than one message, out and in.
#
# Loaded by the session the first time a reliable sample does not fit a message, or a FRAGMENT
# arrives; a board whose samples always fit never pays for it.

from xrce import DecodeError, const
from xrce.wire.message import iter_submessages

_FRAGMENT = const(13)
_FLAG_LITTLE_ENDIAN = const(0x01)
_FLAG_LAST_FRAGMENT = const(0x02)
_SUBHEADER_SIZE = const(4)


def write_fragmented(session, out, mark, end):
    # Cut the submessage the session just wrote into ``out``'s open message at ``mark``..``end``
    # (header, payload, padding to 4) into FRAGMENTs, each alone in a fresh reliable message of
    # ``out``. Its bytes do not depend on where it starts (a sample aligns from its own first byte,
    # and a submessage starts 4-aligned), so they are cut as they are instead of encoded again.
    # The submessage is in ``out.big`` (outbound._Output: a sample too large for a message's buffer is
    # written there), or in a buffer that grew to hold it, which then becomes ``out.big``; the
    # fragments are built in the history's buffers (OutputReliableStream.keep): no copy of the sample, one
    # view of each fragment's bytes.
    out.pos = end
    out.pad_to_4()
    stop = out.pos
    whole = out.buf
    if whole is out.big:
        out.buf = out.home  # still holds the open message up to ``mark``
    else:
        out.buf = bytearray(session.max_message)
        if out.has_content:
            out.buf[0:mark] = memoryview(whole)[0:mark]
    out.home = None
    out.pos = mark  # the open message, if any, ends where the submessage began
    # Not written over while it is cut: a sample as large written by a callback while a fragment
    # waits for room grows a buffer of its own instead.
    out.big = None
    body = memoryview(whole)
    chunk_size = session.max_message - session.header_size - _SUBHEADER_SIZE
    pos = mark
    ok = True
    while pos < stop:
        end = pos + chunk_size
        last = end >= stop
        if last:
            end = stop
        while True:
            # A callback run while waiting for room may have opened a message: send it first.
            if out.has_content:
                session._close_message(out)
            if not session._begin_with_room(out):
                ok = False  # the remainder is lost; the agent discards the incomplete message
                break
            if not out.has_content:
                break
        if not ok:
            break
        w = out.begin_submessage(_FRAGMENT, _FLAG_LITTLE_ENDIAN | (_FLAG_LAST_FRAGMENT if last else 0))
        w.raw(body[pos:end])
        out.end_submessage()
        session._commit(out)  # fragments are not padded (§2)
        pos = end
    if out.big is None:
        out.big = whole
    if ok:
        session._schedule_heartbeat(out.stream_id)
    return ok


def reassemble(session, message):
    # Append the FRAGMENTs of one in-order reliable message; process the whole on the last one.
    start = session.header_size
    for sub_id, flags, s, e in iter_submessages(message, start):
        if sub_id != _FRAGMENT:
            raise DecodeError("FRAGMENT mixed with other submessages")
        if session._reassembly is None:
            session._reassembly = bytearray(message[:start])
        if len(session._reassembly) + (e - s) > session.max_reassembly:
            session._reassembly = None
            raise DecodeError("fragmented message larger than max_reassembly")
        session._reassembly.extend(message[s:e])
        if flags & _FLAG_LAST_FRAGMENT:
            whole = session._reassembly
            session._reassembly = None
            session._process(whole, len(whole))
