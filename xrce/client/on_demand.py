# Session methods that load on first use: the rest of the minimum core, which every firmware
# that syncs time or pings pays for only once it does (time sync and the agent's clock in ms, the
# ping inside the session, waiting for delivery), and the link state; services live in
# xrce.client.services, loaded by their first call. Session.__getattr__ hands every name that
# neither it nor xrce.client.lifecycle and xrce.client.entities (set-up and teardown, loaded per
# call on a board) has to ``session_attr``; neither this table nor these functions are in the
# session module, where a board would pay for them used or not.
#
# One module, not one per feature: a board pays each loaded module's own objects and names (module,
# globals, imports, file name) on top of its code, and a firmware that syncs time also pings (the
# minimum core of a session).

import time

from xrce import DecodeError, const, ticks_add, ticks_diff, ticks_ms, ticks_us
from xrce import epoch_ns as _wall_ns

_TIMESTAMP = const(14)

# The names each source serves, as one space-separated string, looked up as " name ": on a board
# every string of a tuple would be an object of its own.
_SERVICES = (" create_requester create_replier create_service_client create_service_server"
             " send_request send_reply ")
_HERE = " sync_time epoch_ns epoch_ms ping run_until_confirm_delivery "


def session_attr(session, name):
    if " " in name:
        raise AttributeError(name)
    word = " %s " % name
    if word in _HERE:
        function = globals()[name]
    elif word in _SERVICES:
        # Imported by full name: on MicroPython `from xrce.client import services` looks the module
        # up as an attribute of the package first, and the package's __getattr__ (the session
        # module's, for ping_agent) raises AttributeError instead of letting the import go on.
        import xrce.client.services as module

        function = getattr(module, name)
    elif name == "time_offset_ns":
        function = property(_time_offset_ns)
    elif name == "link_state":
        # A property on the class like the methods: a firmware may read it on every pass, and on a
        # board each name Session lacks first loads xrce.client.entities for one call.
        function = property(_link_state)
    else:
        raise AttributeError(name)
    # Set on the class: later look-ups find a method (or link_state's property) there, which a
    # board calls without allocating (send_request and send_reply run at message rate), without a
    # closure kept per method and without Session.__getattr__ loading xrce.client.entities.
    setattr(type(session), name, function)
    return getattr(session, name)


def bind(cls):
    """CPython: every name served here becomes Session's own at import, as xrce.client.entities'
    are, so ``help(Session)`` and ``inspect.signature(Session.create_service_server)`` find them
    before any first use (a board, which pays per loaded module, keeps loading them on demand)."""
    import xrce.client.services as services

    for name in (_HERE + _SERVICES).split():
        setattr(cls, name, globals()[name] if " %s " % name in _HERE else getattr(services, name))
    cls.time_offset_ns = property(_time_offset_ns)
    cls.link_state = property(_link_state)


def _link_state(session):
    # 'connected', 'silent' (the agent is quiet, pings are out) or 'lost' (re-creating).
    link = session.link
    if link is None:
        return "connected" if session.connected else "lost"
    from xrce.client.recovery import LINK_STATE_NAMES

    return LINK_STATE_NAMES[link.state]


# ------------------------------------------------------------------ time sync

# NTP-style offset of the agent's clock from one TIMESTAMP/TIMESTAMP_REPLY exchange
# (XRCE-WIRE.md §5). Nanoseconds since the epoch are big integers on a 32-bit port (small ones stop
# at 2**30), so after the first exchange nothing here forms one: the client's clock is read from
# ticks_us() onwards from the wall clock read once (time.time_ns() allocates), seconds are counted
# from a base (a multiple of 65536 s: the client's at its first reading, the agent's at its first
# reply) and kept apart from nanoseconds, stamps are read from the reply two bytes at a time, and
# every value lives in one list per session (``session._demand``) filled in place. Only what a
# user asks for as one number (epoch_ns, epoch_ms, time_offset_ns) is a big integer again: that
# allocates, when asked.

_NS = const(1000000000)
# Longer than this since the clock was last read (ticks_us() wraps after 2**30 µs, ~17 min), the
# wall clock is read again (that reading allocates); without one, ticks_ms() carries it (_carry).
_REANCHOR_MS = const(500000)

# session._demand, made at the first time sync or ping:
_BASE = const(0)  # the client's seconds count from _BASE << 16
_TICKS = const(1)  # ticks_us() and ticks_ms() when the clock was last read
_MS = const(2)
_NOW_S = const(3)  # what it read: seconds from the base, nanoseconds
_NOW_NS = const(4)
_T0_S = const(5)  # originate stamp of the exchange waited for
_T0_NS = const(6)
_PENDING = const(7)
_AGENT_BASE = const(8)  # the agent's seconds count from _AGENT_BASE << 16
# Twice the offset, agent minus client (halved when asked for: time_offset_ns):
# ((_TWICE_HI << 17) + _TWICE_S) s + _TWICE_NS ns, _TWICE_HI the bases' difference.
_TWICE_HI = const(9)
_TWICE_S = const(10)
_TWICE_NS = const(11)
_SYNC_DONE = const(12)  # the waits' conditions, made once (a lambda per call would allocate)
_PONG_DONE = const(13)
_T1_S = const(14)  # the reply's stamps: agent receive, agent transmit, client originate
_T1_NS = const(15)
_T2_S = const(16)
_T2_NS = const(17)
_ORIGINATE_S = const(18)
_ORIGINATE_NS = const(19)


def _new_state(session):
    # Called as ``session._demand or _new_state(session)``: on a board a function whose lambdas
    # capture its variables allocates their cells on every call, whether it makes them or not.
    type(session)._on_timestamp_reply = on_timestamp_reply
    demand = session._demand = [None] * 20
    demand[_PENDING] = False
    demand[_TWICE_HI] = demand[_TWICE_S] = demand[_TWICE_NS] = 0
    demand[_SYNC_DONE] = lambda: not demand[_PENDING]
    demand[_PONG_DONE] = lambda: session._pong_in_session
    return demand


def _anchor(demand):
    if not (hasattr(time, "time_ns") or hasattr(time, "time")):
        _carry(demand)
        return
    # The wall clock read between two tick readings that agree: a port whose ticks step in
    # milliseconds (the WebAssembly one) would otherwise set the clock up to a step behind.
    for _ in range(3):
        before = ticks_us()
        now_ns = _wall_ns()
        taken = ticks_diff(ticks_us(), before)
        if taken < 1000:
            break
    _anchor_at(demand, now_ns, ticks_add(before, taken >> 1))


def _anchor_at(demand, now_ns, ticks=None):
    # The clock set from a wall-clock reading (nanoseconds since the epoch) taken at ``ticks``.
    seconds, ns = divmod(now_ns, _NS)
    if demand[_BASE] is None:
        demand[_BASE] = seconds >> 16
    demand[_NOW_S] = seconds - (demand[_BASE] << 16)
    demand[_NOW_NS] = ns
    demand[_TICKS] = ticks_us() if ticks is None else ticks
    demand[_MS] = ticks_ms()


def _carry(demand):
    # No wall clock: the clock starts at ticks_ms() (every clock on the board then agrees, as far as
    # ticks_ms() has not wrapped) and runs on from its last reading by what has passed since. That
    # is ticks_us()'s difference plus some whole number of its 2**30 µs wraps: the number that
    # brings it within half a wrap of what ticks_ms() says passed, which is exact to the
    # microsecond as long as ticks_ms() has not wrapped by half (2**29 ms, ~6 days) in between.
    ms = ticks_ms()
    us = ticks_us()
    if demand[_BASE] is None:
        demand[_BASE] = 0
        demand[_NOW_S] = ms // 1000
        demand[_NOW_NS] = (ms % 1000) * 1000000
    else:
        gone = ticks_diff(us, demand[_TICKS])
        gone += ((ticks_diff(ms, demand[_MS]) * 1000 - gone + (1 << 29)) >> 30) << 30
        _advance(demand, gone)
    demand[_TICKS] = us
    demand[_MS] = ms


def _advance(demand, elapsed):
    # demand[_NOW_S], demand[_NOW_NS] moved on by ``elapsed`` µs.
    ns = demand[_NOW_NS] + (elapsed % 1000000) * 1000
    seconds = demand[_NOW_S] + elapsed // 1000000
    if ns >= _NS:
        ns -= _NS
        seconds += 1
    demand[_NOW_S] = seconds
    demand[_NOW_NS] = ns


def board_ns():
    # xrce.epoch_ns() on a board without a wall clock: nanoseconds on its monotonic clock.
    global _board
    clock = _board
    if clock is None:
        clock = _board = [None] * 5
    _now(clock)
    return ((clock[_BASE] << 16) + clock[_NOW_S]) * _NS + clock[_NOW_NS]


_board = None


def _now(demand):
    # Read the client's clock into demand[_NOW_S], demand[_NOW_NS].
    if demand[_BASE] is None:
        _anchor(demand)
        return
    ticks = ticks_us()
    ms = ticks_ms()
    elapsed = ticks_diff(ticks, demand[_TICKS])
    if elapsed < 0 or ticks_diff(ms, demand[_MS]) > _REANCHOR_MS:
        _anchor(demand)
        return
    _advance(demand, elapsed)
    demand[_TICKS] = ticks
    demand[_MS] = ms


def _begin_exchange(session):
    # The originate stamp of a new exchange, remembered as the one waited for.
    demand = session._demand or _new_state(session)
    _now(demand)
    demand[_T0_S] = demand[_NOW_S]
    demand[_T0_NS] = demand[_NOW_NS]
    demand[_PENDING] = True
    return demand


def sync_time(session, timeout_ms=1000, attempts=1):
    # True when the offset was updated.
    session.flush()
    for _ in range(attempts):
        demand = _begin_exchange(session)
        w = session._begin_control(_TIMESTAMP)
        # int32 seconds as two 16-bit halves (the payload starts 4-aligned: same bytes as "<i").
        seconds = demand[_T0_S]
        w.u16(seconds & 0xFFFF)
        w.u16((demand[_BASE] + (seconds >> 16)) & 0xFFFF)
        w.u32(demand[_T0_NS])
        session._send_control()
        if session._wait(timeout_ms, demand[_SYNC_DONE]):
            return True
    demand[_PENDING] = False
    return False


def _u16(buf, at, little):
    return buf[at] | (buf[at + 1] << 8) if little else (buf[at] << 8) | buf[at + 1]


def _stamp(demand, slot, buf, at, little, base):
    # The (int32 s, uint32 ns) stamp at ``at`` into demand[slot], demand[slot + 1], its seconds
    # counted from base << 16, read two bytes at a time; returns the seconds' upper half.
    low = 0 if little else 2
    high = _u16(buf, at + 2 - low, little)
    if high & 0x8000:
        high -= 0x10000
    demand[slot] = ((high - base) << 16) + _u16(buf, at + low, little)
    demand[slot + 1] = (_u16(buf, at + 6 - low, little) << 16) | _u16(buf, at + 4 + low, little)
    return high


def on_timestamp_reply(session, buf, flags, s, e):
    # Agent transmit, agent receive, client originate: (int32 s, uint32 ns) each.
    if e - s < 24:
        raise DecodeError("short TIMESTAMP_REPLY")
    little = flags & 1
    demand = session._demand
    if demand is not None and demand[_PENDING]:  # (a ping alone makes the list, not the clock)
        _stamp(demand, _ORIGINATE_S, buf, s + 16, little, demand[_BASE])
    if (demand is None or not demand[_PENDING] or demand[_ORIGINATE_S] != demand[_T0_S]
            or demand[_ORIGINATE_NS] != demand[_T0_NS]):
        session.stale_timestamps += 1  # a late reply to an earlier attempt: its t3 would be wrong
        return
    _now(demand)
    demand[_PENDING] = False
    agent_base = demand[_AGENT_BASE]
    if agent_base is None:  # the first reply sets it
        agent_base = demand[_AGENT_BASE] = _stamp(demand, _T1_S, buf, s + 8, little, 0)
    _stamp(demand, _T1_S, buf, s + 8, little, agent_base)
    _stamp(demand, _T2_S, buf, s, little, agent_base)
    # t1 - t0 and t2 - t3, their nanoseconds brought into [0, 1 s) so that no sum below leaves the
    # small integers: the round trip is their difference, twice the offset their sum.
    out_s = demand[_T1_S] - demand[_T0_S]
    out_ns = demand[_T1_NS] - demand[_T0_NS]
    if out_ns < 0:
        out_ns += _NS
        out_s -= 1
    back_s = demand[_T2_S] - demand[_NOW_S]
    back_ns = demand[_T2_NS] - demand[_NOW_NS]
    if back_ns < 0:
        back_ns += _NS
        back_s -= 1
    # Never below 0: a clock coarser than the exchange can make it look negative, and a negative
    # bound would only shrink as it ages (no exchange taken again).
    rtt = (out_s - back_s) * _NS + (out_ns - back_ns)
    if rtt < 0:
        rtt = 0
    # The offset is only known to within half the exchange's round trip, and one stalled
    # exchange (a GC pause, a busy link) can be milliseconds off. Like NTP's clock filter,
    # keep the tightest exchange; the bound it gave ages by half at each slower one, so a
    # drifting clock is still followed within a few syncs.
    if session.time_synced and rtt > session.time_rtt_ns:
        session.time_rtt_ns += (session.time_rtt_ns >> 1) + 1
        return
    session.time_rtt_ns = rtt
    out_ns -= _NS - back_ns  # out_ns + back_ns, carried into the seconds without forming it
    if out_ns >= 0:
        out_s += 1
    else:
        out_ns += _NS
    demand[_TWICE_HI] = agent_base - demand[_BASE]
    demand[_TWICE_S] = out_s + back_s
    demand[_TWICE_NS] = out_ns
    session.time_synced = True


def _time_offset_ns(session):
    # The client's clock minus the agent's, in ns (a big integer on a board: allocates), halved
    # rounding toward zero as the C client's int64 division does.
    demand = session._demand
    if demand is None:
        return 0
    twice = ((demand[_TWICE_HI] << 17) + demand[_TWICE_S]) * _NS + demand[_TWICE_NS]
    return (-twice) // 2 if twice < 0 else -(twice // 2)


def epoch_ns(session):
    # Nanoseconds since the epoch on the agent's clock (after ``sync_time``; allocates).
    demand = session._demand
    if demand is None or demand[_BASE] is None:
        return _wall_ns()
    _now(demand)
    return ((demand[_BASE] << 16) + demand[_NOW_S]) * _NS + demand[_NOW_NS] - _time_offset_ns(session)


def epoch_ms(session):
    return session.epoch_ns() // 1000000


# ------------------------------------------------------------------ ping in the session

def ping(session, timeout_ms=1000, attempts=1):
    # GET_INFO inside the session: True only if the agent still knows this session. (The
    # session-less ping is xrce.client.ping.ping_agent.)
    session.flush()
    done = (session._demand or _new_state(session))[_PONG_DONE]
    for _ in range(attempts):
        session._pong_in_session = False
        sent = ticks_us()
        session._send_ping()
        if session._wait(timeout_ms, done):
            session.last_rtt_us = ticks_diff(ticks_us(), sent)
            return True
    return False


# ------------------------------------------------------------------ waiting for delivery

def run_until_confirm_delivery(session, timeout_ms=1000):
    # Flush and wait until every reliable message sent has been acknowledged (a firmware's loop
    # does not need this: its streams deliver as it spins).
    session.flush()
    return session._wait(timeout_ms, lambda: _all_delivered(session))


def _all_delivered(session):
    outputs = session._outputs
    for stream_id in outputs:  # asked on every pass of the wait: no view object (see flush)
        out = outputs[stream_id]
        if out.reliable and out.state.pending():
            return False
    return True
