"""Output on a client's streams: numbering, the reliable window, fragmentation (XRCE-WIRE.md §3, §8).

``StreamOutput.send_on_stream`` sends one submessage alone in a message on a client's stream:
stream none as it is, best-effort numbered (and dropped when larger than the client's mtu),
reliable numbered and kept in the window for retransmission, or cut into FRAGMENTs that go out as
ACKNACKs free room (``send_pending``). ``send_status`` answers a request on the built-in stream of
its reliability. ``data_message`` encodes a reader's DATA the way ``send_on_stream`` takes it.

Where the compiled UDP path sends on a stream too (``xrce.agent.engine.compiled.streams``), its
stream object keeps the numbers: what waits here holds C back (``_hold``), and the history C saw
acknowledged is given back to the client's budget as the window is looked at.
"""

from __future__ import annotations

import logging
from collections import deque
from typing import Optional

from xrce.wire import constants as C
from xrce.agent.engine.client import ClientProxy
from xrce.agent.engine.limits import STREAM_WINDOW
from xrce.wire.message import header_size
from xrce.wire.streams import OutputBestEffortStream, OutputReliableStream, is_reliable
from xrce.wire.submessages import Create, Fragment, Heartbeat, Status, encode_message

log = logging.getLogger("xrce.agent")


class StreamOutput:
    """Messages out on a client's numbered streams.

    Collaborators: ``output`` (whole messages out), ``budget`` (the bytes the windows and what
    waits for them hold), ``scheduler`` (a HEARTBEAT soon after reliable output), ``timelines``
    (a CREATE's STATUS is a step of a client's recovery) and ``stats``.
    """

    def __init__(self, output, budget, scheduler, timelines, stats):
        # Bound once: DataPath.pump sends every sample through send_on_stream.
        self._send_client = output.send_client
        self._send_stream0 = output.send_stream0
        self._heartbeat_soon = scheduler.heartbeat_soon
        self.budget = budget
        self.timelines = timelines
        self.stats = stats

    def send_status(self, client: ClientProxy, request, status: int, stream_id: int) -> None:
        """The STATUS answering ``request`` (a CREATE, DELETE or READ_DATA), on the built-in
        stream of the request's reliability."""
        reply_stream = C.BUILTIN_RELIABLE if is_reliable(stream_id) else C.BUILTIN_BEST_EFFORT
        if not self.send_on_stream(client, reply_stream,
                                   Status(request.request_id, request.object_id, status)):
            self.stats.status_lost += 1
        if self.timelines.pending and isinstance(request, Create):
            self.timelines.created(client, request, status)

    def send_on_stream(self, client: ClientProxy, stream_id: int, payload,
                        message: Optional[bytes] = None) -> bool:
        """Send one submessage alone in a message on ``stream_id`` (``message``: that message
        already encoded with sequence number 0, e.g. by ``data_message``).

        False only when a reliable window has no room (the caller decides whether to keep it);
        best-effort output larger than the mtu is dropped, counted, and reported as handled.
        """
        if stream_id == C.STREAM_NONE:
            if message is not None:
                self._send_client(client, message)
            else:
                self._send_stream0(client, payload)
            return True
        if message is None:
            message = encode_message(client.session_id, stream_id, 0, client.header_key, [payload])
        if not is_reliable(stream_id):
            if len(message) > client.mtu:
                self.stats.oversize_dropped += 1  # a reader's: named once in pump
                log.debug("client %s: %d-byte best-effort message exceeds mtu %d, dropped",
                          client.key.hex(), len(message), client.mtu)
                return True
            stream = client.out_best_effort.get(stream_id)
            if stream is None:
                stream = client.out_best_effort[stream_id] = OutputBestEffortStream(stream_id)
            self._send_client(client, _with_seq(message, stream.next_seq()))
            return True
        stream = client.out_reliable.get(stream_id)
        if stream is None:
            stream = client.out_reliable[stream_id] = OutputReliableStream(stream_id, STREAM_WINDOW)
        pending = client.out_pending.get(stream_id)
        if pending:
            # A long message is still going out in fragments, which must stay consecutive: a
            # reader's DATA waits in its queue; a reply (STATUS, …) waits behind the fragments.
            if payload is None:
                return False
            pending.append(message)
            self.budget.charge(client, len(message))
            return True
        if len(message) <= client.mtu:
            seq = stream.next_seq()
            if seq is None:
                if stream.__class__ is not OutputReliableStream:
                    self.release_acknowledged(client, stream)
                if payload is None:
                    return False  # a reader's DATA stays in its queue (blocked_readers)
                # A reply (a STATUS) answers a request already acknowledged: dropping it would
                # leave the client waiting for ever (rmw_microxrcedds blocks on each CREATE's
                # STATUS) while readers' samples fill the window. It waits for room, ahead of
                # the readers, which only get room once what is pending has gone.
                client.out_pending[stream_id] = deque((message,))
                _hold(stream, True)
                self.budget.charge(client, len(message))
                return True
            message = _with_seq(message, seq)
            stream.commit(seq, message)
            self.budget.charge(client, len(message))
            if stream.__class__ is not OutputReliableStream:
                self.release_acknowledged(client, stream)
            self._send_client(client, message)
            self._heartbeat_soon()
            return True
        return self._send_fragmented(client, stream, message)

    def release_acknowledged(self, client: ClientProxy, stream) -> None:
        """Give the bytes of the history the compiled path acknowledged back to the client's
        budget (``compiled.streams.CompiledOutputStream``: freed as the window is looked at)."""
        freed = stream.release()
        if freed:
            self.budget.charge(client, -freed)

    def _send_fragmented(self, client: ClientProxy, stream: OutputReliableStream,
                         message: bytes) -> bool:
        """Cut ``message`` into FRAGMENTs, as many as it takes: those the window has room for go
        now, the rest as ACKNACKs free room (``send_pending``). Other output of the stream
        waits behind them; a reader's later samples wait in its queue meanwhile."""
        head = header_size(message[0])
        inner = memoryview(message)[head:]
        chunk = client.mtu - head - 4
        count = (len(inner) + chunk - 1) // chunk
        fragments = deque()
        for index in range(count):
            last = index == count - 1
            flags = C.FLAG_LITTLE_ENDIAN | (C.FLAG_LAST_FRAGMENT if last else 0)
            fragments.append(encode_message(client.session_id, stream.stream_id, 0,
                                            client.header_key,
                                            [Fragment(inner[index * chunk:(index + 1) * chunk],
                                                      flags)]))
        self.stats.fragments_out += count
        client.out_pending[stream.stream_id] = fragments
        _hold(stream, True)
        self.budget.charge(client, sum(len(f) for f in fragments))
        self.send_pending(client, stream)
        return True

    def send_pending(self, client: ClientProxy, stream: OutputReliableStream) -> None:
        """Send what waits for the window of ``stream`` while it has room."""
        pending = client.out_pending.get(stream.stream_id)
        if not pending:
            return
        sent = False
        while pending:
            seq = stream.next_seq()
            if seq is None:
                break
            message = _with_seq(pending.popleft(), seq)
            stream.commit(seq, message)  # its bytes move from the queue to the window
            self._send_client(client, message)
            sent = True
        if stream.__class__ is not OutputReliableStream:
            self.release_acknowledged(client, stream)
        if not pending:
            del client.out_pending[stream.stream_id]
            _hold(stream, False)
        elif sent:
            # The window is full with more to come: ask for the ACKNACK that frees it now,
            # rather than a heartbeat period later (a 256 KiB sample is ~530 fragments).
            span = stream.heartbeat()
            self.stats.heartbeats_out += 1
            self._send_stream0(client, Heartbeat(span[0], span[1], stream.stream_id))
        if sent:
            self._heartbeat_soon()


def _hold(stream: OutputReliableStream, held: bool) -> None:
    """Output waits for the window of a stream C sends on too: C sends nothing there meanwhile
    (what waits goes first)."""
    if stream.__class__ is not OutputReliableStream:
        stream.hold(held)


def _with_seq(message: bytes, seq: int) -> bytes:
    return message[:2] + bytes((seq & 0xFF, seq >> 8)) + message[4:]


_DATA_FLAGS = C.FLAG_LITTLE_ENDIAN | C.FORMAT_DATA
_MAX_SHORT_SAMPLE = 0xFFFF - 4  # what one submessage's 16-bit length holds besides the ids


def data_message(client: ClientProxy, stream_id: int, request_id: int, object_id: int,
                 sample: bytes) -> bytes:
    """The message carrying one DATA (FORMAT_DATA) alone, sequence number 0: the bytes
    ``encode_message(session, stream_id, 0, key, [Data(request_id, object_id, sample)])`` gives
    (a test holds them equal), assembled directly because the generic encoder's objects and CDR
    writer were most of the cost of delivering a sample to a client."""
    # Longer than a submessage length can say: 0, "to the end of the message", as the C client
    # writes such a WRITE_DATA. It only ever travels in FRAGMENTs, alone in its message.
    length = 4 + len(sample) if len(sample) <= _MAX_SHORT_SAMPLE else 0
    head = bytes((client.session_id, stream_id, 0, 0, C.DATA, _DATA_FLAGS, length & 0xFF,
                  length >> 8, request_id >> 8, request_id & 0xFF, object_id >> 8,
                  object_id & 0xFF))
    if client.header_key is not None:
        head = head[:4] + client.header_key + head[4:]
    return head + sample

