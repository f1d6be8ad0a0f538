# Time sync (Session.sync_time): NTP-style offset of the agent's clock from one
# TIMESTAMP/TIMESTAMP_REPLY exchange (XRCE-WIRE.md §5). Loaded on first use (see
# xrce.client.on_demand); Session.epoch_ns applies the offset. A firmware that never syncs pays
# nothing for it.

import struct

from xrce import DecodeError, const, epoch_ns

_TIMESTAMP = const(14)


def sync_time(session, timeout_ms=1000, attempts=1):
    # True when the offset was updated.
    session.flush()
    for _ in range(attempts):
        originate = epoch_ns()
        session._sync_originate = originate
        w = session._begin_control(_TIMESTAMP)
        w.i32(originate // 1000000000)
        w.u32(originate % 1000000000)
        session._send_control()
        if session._wait(timeout_ms, lambda: session._sync_originate is None):
            return True
    session._sync_originate = None
    return False


def on_timestamp_reply(session, buf, flags, s, e):
    # Agent transmit, agent receive, client originate: (int32 s, uint32 ns) each.
    if e - s < 24:
        raise DecodeError("short TIMESTAMP_REPLY")
    t = struct.unpack_from("<iIiIiI" if flags & 1 else ">iIiIiI", buf, s)
    t0 = session._sync_originate
    if t0 is None or t[4] * 1000000000 + t[5] != t0:
        session.stale_timestamps += 1  # a late reply to an earlier attempt: its t3 would be wrong
        return
    t3 = epoch_ns()
    session._sync_originate = None
    received = t[2] * 1000000000 + t[3]
    transmitted = t[0] * 1000000000 + t[1]
    # The offset is only known to within half the exchange's round trip, and one stalled
    # exchange (a GC pause, a busy link) can be milliseconds off. Like NTP's clock filter,
    # keep the tightest exchange; the bound it gave ages by half at each slower one, so a
    # drifting clock is still followed within a few syncs.
    rtt = (t3 - t0) - (transmitted - received)
    if session.time_synced and rtt > session.time_rtt_ns:
        session.time_rtt_ns += (session.time_rtt_ns >> 1) + 1
        return
    session.time_rtt_ns = rtt
    twice = (t0 + t3) - (received + transmitted)
    # Halved rounding toward zero, as the C client's int64 division does.
    session.time_offset_ns = -((-twice) // 2) if twice < 0 else twice // 2
    session.time_synced = True
