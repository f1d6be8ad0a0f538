# The session-less ping (GET_INFO with header 0x80): whether an agent answers on a transport before
# any session exists, as micro-ROS firmware waits for its agent. (The ping inside a session,
# Session.ping, is in xrce.client.on_demand.) Its own module so that a board that never pings pays
# nothing for it;
# `from xrce.client.session import ping_agent` still works. (The link monitor, xrce.client.recovery,
# sends its pings itself without waiting for them.)

from xrce import DecodeError, const, ticks_add, ticks_diff, ticks_ms, ticks_us
from xrce.client.session import _agent_activity
from xrce.wire.message import header_size, iter_submessages

_INFO = const(6)


def ping_agent(transport, timeout_ms=1000, attempts=1):
    # Session-less GET_INFO ping (header 0x80). Returns the round-trip time in µs, or None.
    #
    # Any INFO reporting an available agent counts as the answer, as with the C client.
    message = b"\x80\x00\x00\x00\x02\x01\x08\x00\x00\x0a\xff\xfd\x02\x00\x00\x00"
    for _ in range(attempts):
        sent = ticks_us()
        transport.send(message)
        deadline = ticks_add(ticks_ms(), timeout_ms)
        while True:
            remaining = ticks_diff(deadline, ticks_ms())
            if remaining <= 0:
                break
            data = transport.recv(remaining)
            if data is not None and _is_pong(data):
                return ticks_diff(ticks_us(), sent)
    return None


def _is_pong(data):
    try:
        if len(data) < 4:
            return False
        for sub_id, flags, s, e in iter_submessages(data, header_size(data[0])):
            if sub_id == _INFO:
                availability = _agent_activity(data, flags, s, e)
                return availability is not None and availability > 0
    except DecodeError:
        pass
    return False

