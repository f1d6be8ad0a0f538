# Best-effort and reliable stream state (XRCE-WIRE.md §1, §7), shared by client and agent.
#
# These classes hold sequence numbers and history only; building, sending and parsing messages is
# the caller's job. ``history`` must be a power of two (slot = seq mod history). A reliable sender
# retransmits exactly the sequence numbers a NACK names (the eProsima agent's policy; the eProsima
# client resends everything unacknowledged, which is wire-compatible but wasteful).

from xrce import EncodeError, IS_MICROPYTHON, const, ticks_diff

_SEQ_INITIAL = const(0xFFFF)  # "last sent/handled" before the first message, so the first seq is 0
_NACK_BITS = const(16)
_HALF = const(0x8000)


# 16-bit serial-number arithmetic (XRCE-WIRE.md §1), identical on both sides. Here rather than in a
# module of their own: a module costs a board its object, dictionary and names.
def seq_add(seq, delta):
    return (seq + delta) & 0xFFFF


def seq_sub(a, b):
    # Distance from b forward to a, in 0..65535.
    return (a - b) & 0xFFFF


def seq_less(a, b):
    # True if a precedes b in serial-number order.
    if a == b:
        return False
    return (a < b and b - a < _HALF) or (a > b and a - b > _HALF)


def is_reliable(stream_id):
    return stream_id >= 0x80


def _check_history(history):
    if history < 1 or history & (history - 1):
        raise EncodeError("stream history must be a power of two, got %r" % (history,))


class OutputBestEffortStream:
    if not IS_MICROPYTHON:  # a board ignores __slots__ and would keep the tuple
        __slots__ = ("stream_id", "last_sent")

    def __init__(self, stream_id):
        self.stream_id = stream_id
        self.last_sent = _SEQ_INITIAL

    def reset(self):
        self.last_sent = _SEQ_INITIAL

    def next_seq(self):
        self.last_sent = seq_add(self.last_sent, 1)
        return self.last_sent


class InputBestEffortStream:
    if not IS_MICROPYTHON:  # a board ignores __slots__ and would keep the tuple
        __slots__ = ("stream_id", "last_handled")

    def __init__(self, stream_id):
        self.stream_id = stream_id
        self.last_handled = _SEQ_INITIAL

    def reset(self):
        self.last_handled = _SEQ_INITIAL

    def accept(self, seq):
        # True for a strictly newer message; older and duplicate ones are dropped.
        if seq_less(self.last_handled, seq):
            self.last_handled = seq
            return True
        return False


class OutputReliableStream:
    # Sent messages kept until acknowledged; at most ``history`` in flight.
    #
    # An agent ``commit``s each message as bytes, dropped once acknowledged. A client ``keep``s the
    # buffer a message was built in with its length (``sizes``) and keeps the buffer once the
    # message is acknowledged, to build a later one in (xrce.client.outbound.Outbound._commit): no copy
    # and no allocation per message, and ``on_acknack(..., session)`` sends retransmissions at once
    # instead of returning a list.

    if not IS_MICROPYTHON:  # a board ignores __slots__ and would keep the tuple
        __slots__ = ("stream_id", "history", "last_sent", "last_acknowledged", "slots", "sizes",
                     "resent_at", "retransmissions", "suppressed", "stored_bytes")

    def __init__(self, stream_id, history):
        _check_history(history)
        self.stream_id = stream_id
        self.history = history
        self.slots = [None] * history
        self.sizes = [0] * history  # keep(): the length of a slot's unacknowledged message, or 0
        self.resent_at = [None] * history
        self.retransmissions = 0
        self.suppressed = 0
        self.reset()

    def reset(self, keep_buffers=False):
        self.last_sent = _SEQ_INITIAL
        self.last_acknowledged = _SEQ_INITIAL
        self.stored_bytes = 0  # bytes of the messages kept for retransmission (an agent's budget)
        for i in range(self.history):
            if not keep_buffers:
                self.slots[i] = None
            self.sizes[i] = 0
            self.resent_at[i] = None

    def in_flight(self):
        return seq_sub(self.last_sent, self.last_acknowledged)

    def has_room(self):
        return self.in_flight() < self.history

    def next_seq(self):
        # The sequence number the next message will carry, or None while the window is full.
        if not self.has_room():
            return None
        return seq_add(self.last_sent, 1)

    def commit(self, seq, message):
        # Record ``message`` (bytes, header already carrying ``seq``) as sent.
        if seq != seq_add(self.last_sent, 1) or not self.has_room():
            raise EncodeError("reliable stream out of order or full")
        self.slots[seq & (self.history - 1)] = message
        self.resent_at[seq & (self.history - 1)] = None
        self.last_sent = seq
        self.stored_bytes += len(message)

    def keep(self, buf, length):
        # ``buf[:length]`` is the next sequence number's message; returns the buffer the slot held.
        if not self.has_room():
            raise EncodeError("reliable stream out of order or full")
        seq = seq_add(self.last_sent, 1)
        slot = seq & (self.history - 1)
        free = self.slots[slot]
        self.slots[slot] = buf
        self.sizes[slot] = length
        self.resent_at[slot] = None
        self.last_sent = seq
        return free

    def pending(self):
        return self.last_sent != self.last_acknowledged

    def heartbeat(self):
        # ``(first_unacked, last_unacked)`` while anything is unacknowledged, else None.
        if self.last_sent == self.last_acknowledged:
            return None
        return seq_add(self.last_acknowledged, 1), self.last_sent

    def on_acknack(self, first_unacked, nack_bitmap, now_ms=0, holdoff_ms=0, session=None):
        # Free what ``first_unacked`` acknowledges; return the messages to retransmit, in order
        # (with ``session``, a client's: send them through its ``_send_from`` and return ()).
        #
        # A message is retransmitted at the first NACK that names it (so recovery is immediate, as
        # both eProsima peers do), but not again within ``holdoff_ms`` of that retransmission: a
        # receiver ACKNACKs every duplicate it gets, and on a lossy, reordering link answering each of
        # those NACKs again multiplies the traffic into a retransmission storm.
        # An ACKNACK that acknowledges more than was ever sent is stale or forged: ignore the ack.
        if not seq_less(seq_add(self.last_sent, 1), first_unacked):
            while seq_less(self.last_acknowledged, seq_add(first_unacked, -1)):
                self.last_acknowledged = seq_add(self.last_acknowledged, 1)
                slot = self.last_acknowledged & (self.history - 1)
                if self.sizes[slot]:
                    self.sizes[slot] = 0  # a kept buffer (keep) stays for a later message
                elif self.slots[slot] is not None:
                    self.stored_bytes -= len(self.slots[slot])
                    self.slots[slot] = None
        if not nack_bitmap:
            return ()
        resend = [] if session is None else ()
        for i in range(_NACK_BITS):
            if nack_bitmap & (1 << i):
                seq = seq_add(first_unacked, i)
                if seq_less(self.last_acknowledged, seq) and not seq_less(self.last_sent, seq):
                    slot = seq & (self.history - 1)
                    message = self.slots[slot]
                    if message is None or (session is not None and not self.sizes[slot]):
                        continue
                    last = self.resent_at[slot]
                    if holdoff_ms and last is not None and ticks_diff(now_ms, last) < holdoff_ms:
                        self.suppressed += 1
                        continue
                    self.resent_at[slot] = now_ms
                    self.retransmissions += 1
                    if session is None:
                        resend.append(message)
                    else:
                        session._send_from(message, self.sizes[slot])
        return resend

class InputReliableStream:
    # Accepts ``last_handled < seq <= last_handled + window``; hands messages out in order.

    if not IS_MICROPYTHON:  # a board ignores __slots__ and would keep the tuple
        __slots__ = ("stream_id", "window", "last_handled", "last_announced", "stored", "duplicates",
                     "stored_bytes")

    def __init__(self, stream_id, window):
        _check_history(window)
        self.stream_id = stream_id
        self.window = window
        self.stored = {}
        self.duplicates = 0
        self.reset()

    def reset(self):
        self.last_handled = _SEQ_INITIAL
        self.last_announced = _SEQ_INITIAL
        self.stored.clear()
        self.stored_bytes = 0  # bytes of the out-of-order messages held (an agent's budget)

    def receive(self, seq, message):
        # Messages now deliverable in order (possibly none); duplicates and out-of-window dropped.
        if not seq_less(self.last_handled, seq) or seq_sub(seq, self.last_handled) > self.window:
            self.duplicates += 1
            return ()
        if seq_less(self.last_announced, seq):
            self.last_announced = seq
        if seq != seq_add(self.last_handled, 1):
            if seq in self.stored:
                self.duplicates += 1
            else:
                self.stored[seq] = bytes(message)
                self.stored_bytes += len(message)
            return ()
        self.last_handled = seq
        out = [message]
        self._pop_consecutive(out)
        return out

    def receive_next(self, seq):
        # ``receive`` for the common case without its list: True, and ``seq`` handled, when it is the
        # next in order and nothing is stored (the caller then processes that message itself);
        # False otherwise, with nothing changed (call ``receive``).
        if self.stored or seq != seq_add(self.last_handled, 1):
            return False
        self.last_handled = seq
        if seq_less(self.last_announced, seq):
            self.last_announced = seq
        return True

    def _pop_consecutive(self, out):
        stored = self.stored
        while stored:
            nxt = seq_add(self.last_handled, 1)
            message = stored.pop(nxt, None)
            if message is None:
                break
            self.stored_bytes -= len(message)
            self.last_handled = nxt
            out.append(message)

    def on_heartbeat(self, first_unacked, last_unacked):
        # Note what the sender has sent; skip what it no longer holds. Returns deliverable messages.
        if seq_less(self.last_announced, last_unacked):
            self.last_announced = last_unacked
        if not seq_less(seq_add(self.last_handled, 1), first_unacked):
            return ()  # nothing skipped: no list (a client gets a HEARTBEAT every few messages)
        # The sender gave up on messages before first_unacked: they will never come.
        out = []
        skip_to = seq_add(first_unacked, -1)
        for seq in list(self.stored):
            if not seq_less(skip_to, seq):
                self.stored_bytes -= len(self.stored.pop(seq))
        self.last_handled = skip_to
        self._pop_consecutive(out)
        return out

    def acknack(self):
        # ``(first_unacked, nack_bitmap)`` for an ACKNACK of this stream.
        return seq_add(self.last_handled, 1), self.nack_bitmap()

    def nack_bitmap(self):
        # The NACK bitmap of ``acknack`` alone: no tuple (first_unacked is last_handled + 1).
        first = seq_add(self.last_handled, 1)
        bitmap = 0
        for i in range(_NACK_BITS):
            seq = seq_add(first, i)
            if seq_less(self.last_announced, seq):
                break
            if seq not in self.stored:
                bitmap |= 1 << i
        return bitmap
