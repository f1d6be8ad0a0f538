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

import struct

from xrce import DecodeError, const, epoch_ns, ticks_diff, ticks_us

_TIMESTAMP = const(14)

# The names each source serves, as one space-separated string, looked up as " name ": on a board
# every string of a tuple would be an object of its own.
_SERVICES = (" create_requester create_replier create_service_client create_service_server"
             " send_request send_reply ")
_HERE = " sync_time epoch_ms ping run_until_confirm_delivery "


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


def _link_state(session):
    # 'connected', 'silent' (the agent is quiet, pings are out) or 'lost' (re-creating).
    link = session.link
    if link is None:
        return "connected" if session.connected else "lost"
    from xrce.client.recovery import LINK_STATE_NAMES

    return LINK_STATE_NAMES[link.state]


# ------------------------------------------------------------------ time sync

# NTP-style offset of the agent's clock from one TIMESTAMP/TIMESTAMP_REPLY exchange
# (XRCE-WIRE.md §5); Session.epoch_ns applies it.
def sync_time(session, timeout_ms=1000, attempts=1):
    # True when the offset was updated.
    session.flush()
    for _ in range(attempts):
        originate = epoch_ns()
        session._sync_originate = originate
        w = session._begin_control(_TIMESTAMP)
        w._put("<i", 4, originate // 1000000000)  # int32: the writer's i32 lives in xrce.cdr_more
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


def epoch_ms(session):
    return session.epoch_ns() // 1000000


# ------------------------------------------------------------------ ping in the session

def ping(session, timeout_ms=1000, attempts=1):
    # GET_INFO inside the session: True only if the agent still knows this session. (The
    # session-less ping is xrce.client.ping.ping_agent.)
    session.flush()
    for _ in range(attempts):
        session._pong_in_session = False
        sent = ticks_us()
        session._send_ping()
        if session._wait(timeout_ms, lambda: session._pong_in_session):
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
