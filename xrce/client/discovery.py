# Agent discovery (GET_INFO request 0x0009), apart from the session so boards that know their
# agent's address never load it. ``from xrce.client.session import discover_agents`` still works.

from xrce import DecodeError, ticks_add, ticks_diff, ticks_ms
from xrce import constants as C
from xrce.cdr import CdrReader
from xrce.message import MessageWriter, decode_header, iter_submessages
# The two payloads discovery sends and reads, not the whole codec of xrce.submessages.
from xrce.payload import write_submessage
from xrce.session_payloads import GetInfo, Info


def discover_agents(transport, attempts=1, period_ms=1000):
    # ``[(address_bytes, port), ...]`` of the agents that answer a discovery GET_INFO.
    #
    # ``transport`` must reach the agents' discovery port (default 7400), unicast or, with a socket that
    # accepts replies from any source, the multicast group 239.255.0.2.
    mw = MessageWriter(32)
    mw.begin(C.SESSION_ID_NONE_WITHOUT_KEY, C.STREAM_NONE, 0)
    write_submessage(mw, GetInfo(C.REQUEST_ID_DISCOVERY, C.OBJECTID_AGENT,
                                 C.INFO_CONFIGURATION | C.INFO_ACTIVITY))
    message = mw.getvalue()
    found = []
    for _ in range(attempts):
        transport.send(message)
        deadline = ticks_add(ticks_ms(), period_ms)
        while True:
            remaining = ticks_diff(deadline, ticks_ms())
            if remaining <= 0:
                break
            data = transport.recv(remaining)
            if data is None:
                continue
            for locator in _info_locators(data):
                if locator not in found:
                    found.append(locator)
    return found


def _info_locators(data):
    try:
        header = decode_header(data)
        for sub_id, flags, s, e in iter_submessages(data, header.size):
            if sub_id == C.INFO:
                info = Info.decode(CdrReader(data, s, e, 0, bool(flags & 1)), flags)
                if info.config is not None and info.config[1] == C.XRCE_VERSION:
                    return [(loc.address, loc.port) for loc in info.locators if loc.fmt != C.LOCATOR_STRING]
    except DecodeError:
        pass
    return []
