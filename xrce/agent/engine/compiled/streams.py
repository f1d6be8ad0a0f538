"""The agent's stream objects whose sequence numbers the compiled UDP path owns.

When ``xrce.agent.engine.compiled.fastpath`` hands a client's stream to C (``_fastpath.c``,
``_reliable_in.c``, ``_reliable_out.c``), the client's Python stream object is swapped for one of
these: same interface as the ``xrce.wire.streams`` class it replaces, but its numbers are read from and
written to C, so they have one owner while Python still handles everything C leaves to it
(duplicates, gaps, HEARTBEATs, NACKs). Each has ``detached()`` (or, best-effort, its number read
back) to hand the state back to a plain stream when C forgets the client.
"""

from __future__ import annotations

from typing import Optional

from xrce.wire.streams import InputReliableStream, OutputReliableStream, seq_add, seq_less, seq_sub


class CompiledStream:
    """Stands in for a best-effort ``InputBestEffortStream`` whose sequence number C owns."""

    __slots__ = ("stream_id", "_receiver", "_handle")

    def __init__(self, receiver, handle: int, stream_id: int):
        self.stream_id = stream_id
        self._receiver = receiver
        self._handle = handle

    @property
    def last_handled(self) -> int:
        seq = self._receiver.stream_seq(self._handle, self.stream_id)
        return 0xFFFF if seq is None else seq

    def accept(self, seq: int) -> bool:
        return self._receiver.stream_accept(self._handle, self.stream_id, seq)

    def reset(self) -> None:
        self._receiver.add_stream(self._handle, self.stream_id, 0xFFFF)


class CompiledReliableStream(InputReliableStream):
    """An ``InputReliableStream`` whose two sequence numbers (``last_handled``,
    ``last_announced``) C owns: C delivers the next message in order when Python holds none
    behind it, and Python's handling of everything else (duplicates, gaps, HEARTBEATs, the
    ACKNACK's contents) reads and moves the same numbers. The out-of-order messages it keeps
    (``stored``) stay Python's."""

    __slots__ = ("_receiver", "_handle")

    def __init__(self, receiver, handle: int, stream: InputReliableStream):
        self._receiver = receiver
        self._handle = handle
        super().__init__(stream.stream_id, stream.window)  # reset() registers it in C
        self.last_handled = stream.last_handled
        self.last_announced = stream.last_announced
        self.duplicates = stream.duplicates

    def _state(self):
        state = self._receiver.reliable_state(self._handle, self.stream_id)
        return (0xFFFF, 0xFFFF) if state is None else state

    @property
    def last_handled(self) -> int:
        return self._state()[0]

    @last_handled.setter
    def last_handled(self, seq: int) -> None:
        self._set(seq, None)

    @property
    def last_announced(self) -> int:
        return self._state()[1]

    @last_announced.setter
    def last_announced(self, seq: int) -> None:
        self._set(None, seq)

    def _set(self, last, announced) -> None:
        state = self._receiver.reliable_state(self._handle, self.stream_id)
        if state is None:  # reset() from the base class's __init__: not registered yet
            self._receiver.add_stream(self._handle, self.stream_id, 0xFFFF, 0xFFFF)
            state = (0xFFFF, 0xFFFF)
        self._receiver.set_reliable_state(self._handle, self.stream_id,
                                          state[0] if last is None else last,
                                          state[1] if announced is None else announced)

    def take_partial(self) -> Optional[bytes]:
        """The message C was putting together from FRAGMENTs, now Python's to continue (None:
        none). What Python leaves unfinished goes back with ``put_partial``."""
        return self._receiver.take_partial(self._handle, self.stream_id)

    def put_partial(self, buffer) -> bool:
        return self._receiver.put_partial(self._handle, self.stream_id, buffer)

    def detached(self) -> InputReliableStream:
        """A plain stream in this one's state, for when C forgets the client."""
        stream = InputReliableStream(self.stream_id, self.window)
        stream.last_handled, stream.last_announced = self._state()
        stream.stored.update(self.stored)
        stream.stored_bytes = self.stored_bytes
        stream.duplicates = self.duplicates
        return stream


class CompiledOutputStream(OutputReliableStream):
    """An ``OutputReliableStream`` whose numbers C owns (``_reliable_out.c``): C sends a reader's
    DATA on the stream itself (``_reader_out.c``) and moves the acknowledged point for the
    client's plain ACKNACKs while the window has room; Python takes its sequence numbers from C
    (``next_seq`` reserves one) and moves the acknowledged point through C for everything else
    (NACKs, a full window, HEARTBEATs). The history is split by sender: a message Python sent
    stays in Python's slots, one C sent in C's (``message`` reads either for a retransmission).
    Every look at the window (``in_flight``) first frees the slots C acknowledged, so a slot is
    never reused before it is freed; the bytes so freed are given back to the client's budget by
    the engine (``release``)."""

    __slots__ = ("_receiver", "_handle", "_released", "_freed")

    def __init__(self, receiver, handle: int, stream: OutputReliableStream, probing: bool):
        self._receiver = receiver
        self._handle = handle
        self._released = stream.last_acknowledged
        self._freed = 0
        receiver.add_out_stream(handle, stream.stream_id, stream.history, stream.last_sent,
                                stream.last_acknowledged)
        receiver.set_probing(handle, probing)
        super().__init__(stream.stream_id, stream.history)  # reset() writes through to C
        _copy_output(stream, self)

    def _numbers(self):
        state = self._receiver.out_state(self._handle, self.stream_id)
        return (self._released, self._released) if state is None else state

    @property
    def last_sent(self) -> int:
        return self._numbers()[0]

    @last_sent.setter
    def last_sent(self, seq: int) -> None:  # reset() and _copy_output only
        self._receiver.set_out_state(self._handle, self.stream_id, seq, -1)

    @property
    def last_acknowledged(self) -> int:
        return self._numbers()[1]

    @last_acknowledged.setter
    def last_acknowledged(self, seq: int) -> None:
        self._released = seq  # Python moves it only with the slot it frees (on_acknack, reset)
        self._receiver.set_out_state(self._handle, self.stream_id, -1, seq)

    def next_seq(self):
        """The sequence number of Python's next message, taken from C at once (C may send on
        the stream meanwhile); None while the window is full."""
        self._release()
        seq = self._receiver.out_reserve(self._handle, self.stream_id)
        if seq is not None:
            self.resent_at[seq & (self.history - 1)] = None
        return seq

    def commit(self, seq, message):
        slot = seq & (self.history - 1)
        self.slots[slot] = message
        self.resent_at[slot] = None
        self.stored_bytes += len(message)

    def message(self, seq: int):
        """The unacknowledged message ``seq``, Python's or C's; None if there is none."""
        message = self.slots[seq & (self.history - 1)]
        if message is None:
            message = self._receiver.out_message(self._handle, self.stream_id, seq)
        return message

    def _release(self) -> None:
        acknowledged = self.last_acknowledged
        freed = 0
        mask = self.history - 1
        while seq_less(self._released, acknowledged):
            self._released = seq_add(self._released, 1)
            slot = self._released & mask
            if self.slots[slot] is not None:
                freed += len(self.slots[slot])
                self.slots[slot] = None
        self.stored_bytes -= freed
        self._freed += freed

    def in_flight(self) -> int:
        self._release()
        sent, acknowledged = self._numbers()
        return seq_sub(sent, acknowledged)

    def release(self) -> int:
        """Free the history C acknowledged; the bytes freed since the last call (the engine
        gives them back to the client's budget)."""
        self._release()
        freed, self._freed = self._freed, 0
        return freed

    def on_acknack(self, first_unacked, nack_bitmap, now_ms=0, holdoff_ms=0, session=None):
        # OutputReliableStream.on_acknack's rules, with each message read from its sender's
        # history: move the acknowledged point (C frees its own slots), then resend each NACKed
        # message at most once per hold-off.
        freed = self._freed
        self._release()
        self._freed = freed  # the caller charges the change of stored_bytes across this call
        sent, acknowledged = self._numbers()
        if not seq_less(seq_add(sent, 1), first_unacked) and \
                seq_less(acknowledged, seq_add(first_unacked, -1)):
            self._receiver.set_out_state(self._handle, self.stream_id, -1,
                                         seq_add(first_unacked, -1))
            self._release()  # Python's slots up to there
            self._freed = freed
            acknowledged = self._released
        if not nack_bitmap:
            return ()
        resend = []
        for i in range(16):
            if nack_bitmap & (1 << i):
                seq = seq_add(first_unacked, i)
                if seq_less(acknowledged, seq) and not seq_less(sent, seq):
                    message = self.message(seq)
                    if message is None:
                        continue
                    slot = seq & (self.history - 1)
                    last = self.resent_at[slot]
                    if holdoff_ms and last is not None and now_ms - last < holdoff_ms:
                        self.suppressed += 1
                        continue
                    self.resent_at[slot] = now_ms
                    self.retransmissions += 1
                    resend.append(message)
        return resend

    def hold(self, held: bool) -> None:
        """Python has output waiting for this stream's window: C sends nothing meanwhile."""
        self._receiver.set_out_held(self._handle, self.stream_id, held)

    def detached(self) -> OutputReliableStream:
        """A plain stream in this one's state (after ``release``), C's unacknowledged messages
        copied in, for when C forgets the client."""
        self._release()
        stream = OutputReliableStream(self.stream_id, self.history)
        _copy_output(self, stream)
        sent, acknowledged = self._numbers()
        seq = acknowledged
        while seq_less(seq, sent):
            seq = seq_add(seq, 1)
            slot = seq & (self.history - 1)
            if stream.slots[slot] is None:
                message = self._receiver.out_message(self._handle, self.stream_id, seq)
                if message is not None:
                    stream.slots[slot] = message
                    stream.stored_bytes += len(message)
        return stream


class CompiledOutputBestEffort:
    """Stands in for an ``OutputBestEffortStream`` whose sequence number C owns, once C may send
    a reader's DATA on it (``_reader_out.c``)."""

    __slots__ = ("_receiver", "_handle", "stream_id")

    def __init__(self, receiver, handle: int, stream):
        self._receiver = receiver
        self._handle = handle
        self.stream_id = stream.stream_id
        receiver.add_out_best_effort(handle, stream.stream_id, stream.last_sent)

    @property
    def last_sent(self) -> int:
        seq = self._receiver.out_best_effort_next(self._handle, self.stream_id, False)
        return 0xFFFF if seq is None else seq

    def next_seq(self) -> int:
        seq = self._receiver.out_best_effort_next(self._handle, self.stream_id)
        return 0 if seq is None else seq

    def reset(self) -> None:
        self._receiver.add_out_best_effort(self._handle, self.stream_id, 0xFFFF)


def _copy_output(source: OutputReliableStream, target: OutputReliableStream) -> None:
    target.slots[:] = source.slots
    target.sizes[:] = source.sizes
    target.resent_at[:] = source.resent_at
    target.retransmissions = source.retransmissions
    target.suppressed = source.suppressed
    target.stored_bytes = source.stored_bytes
    target.last_sent = source.last_sent
    target.last_acknowledged = source.last_acknowledged

