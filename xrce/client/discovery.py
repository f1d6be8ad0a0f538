# Agent discovery (GET_INFO request 0x0009), apart from the session so boards that know their
# agent's address never load it. ``from xrce.client.session import discover_agents`` still works.
#
# It writes its one request and reads INFO itself (XRCE-WIRE.md §10) rather than through the general
# codec of xrce.wire.session_payloads: that codec, the constants table and the CDR methods it calls cost
# a board 22.7 KB from .mpy, this module alone ~2 KB. tests/client/test_client_encoders.py checks this reader
# against the general codec's encoder, and the golden discovery capture replays through it.

from xrce import DecodeError, const, ticks_add, ticks_diff, ticks_ms
from xrce.wire.cdr import CdrReader
from xrce.wire.message import header_size, iter_submessages

_INFO = const(6)
_OBJK_AGENT = const(0x0D)
_LOCATOR_SMALL = const(0)
_LOCATOR_MEDIUM = const(1)
_LOCATOR_LARGE = const(2)
_LOCATOR_STRING = const(3)
_XRCE_VERSION = b"\x01\x00"

# Header: no session (0x80), stream 0, seq 0. GET_INFO, little-endian, 8 bytes: request 0x0009
# (discovery), object 0xFFFD (the agent), info mask CONFIGURATION | ACTIVITY.
_GET_INFO_DISCOVERY = b"\x80\x00\x00\x00\x02\x01\x08\x00\x00\x09\xff\xfd\x03\x00\x00\x00"


def discover_agents(transport, attempts=1, period_ms=1000):
    # ``[(address_bytes, port), ...]`` of the agents that answer a discovery GET_INFO.
    #
    # ``transport`` must reach the agents' discovery port (default 7400), unicast or, with a socket that
    # accepts replies from any source, the multicast group 239.255.0.2.
    found = []
    for _ in range(attempts):
        transport.send(_GET_INFO_DISCOVERY)
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


# The address locators of an agent's INFO in one message (none for anything else): agents whose
# XRCE version is not 1.0 are left out, as the C client does.
def _info_locators(data):
    try:
        for sub_id, flags, s, e in iter_submessages(data, header_size(data[0])):
            if sub_id == _INFO:
                _, version, _, locators = read_info(data, flags, s, e)
                if version == _XRCE_VERSION:
                    return locators
    except (DecodeError, IndexError):
        pass
    return []


# ``(implementation status, availability)`` of an INFO whose agent configuration carries properties,
# for the session (xrce.client.session._agent_activity reads the usual INFO itself).
def info_activity(buf, flags, s, e):
    impl_status, _, availability, _ = read_info(buf, flags, s, e)
    return impl_status, availability


# An INFO payload in ``buf[s:e]``: ``(implementation status, XRCE version or None, availability or
# None, [(address_bytes, port), ...])``; string locators are skipped. Raises DecodeError.
def read_info(buf, flags, s, e):
    r = CdrReader(buf, s + 4, e, 0, bool(flags & 1))  # after the request and object ids
    r.u8()  # status
    impl_status = r.u8()
    version = availability = None
    locators = []
    if r.boolean():  # the agent's configuration
        if r.u8() != _OBJK_AGENT:
            raise DecodeError("INFO configuration is not an agent's")
        r.raw(4)  # cookie
        version = r.raw(2)
        r.raw(2)  # vendor
        if r.boolean():  # properties: (name, value) strings
            count = r.u32()
            if count * 10 > r.end - r.pos:
                raise DecodeError("property count exceeds the payload")
            for _ in range(2 * count):
                r.string()
    if r.boolean():  # its activity
        if r.u8() != _OBJK_AGENT:
            raise DecodeError("INFO activity is not an agent's")
        availability = r._get(0, 2)  # int16: the reader's i16 lives in xrce.wire.cdr_more
        count = r.u32()
        if count * 3 > r.end - r.pos:
            raise DecodeError("locator count exceeds the payload")
        for _ in range(count):
            kind = r.u8()
            if kind == _LOCATOR_STRING:
                r.string()
            elif kind == _LOCATOR_SMALL:
                locators.append((r.raw(2), r.u8()))
            elif kind == _LOCATOR_MEDIUM:
                locators.append((r.raw(4), r._get(1, 2)))
            elif kind == _LOCATOR_LARGE:
                locators.append((r.raw(16), r.u32()))
            else:
                raise DecodeError("unknown locator format %d" % kind)
    return impl_status, version, availability, locators
