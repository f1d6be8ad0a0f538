"""Where boards can reach the agent: the addresses its IP links listen on, for the banner.

A board's code names the agent by address (``AGENT = ("192.168.1.10", 8888)``); an agent bound to
0.0.0.0 (or ::) listens on every interface of the host, so the banner lists the host's own
addresses: IPv4 ones as the discovery port announces them (``links.udp.local_ipv4_addresses``),
IPv6 ones from ``/proc/net/if_inet6`` (Linux; elsewhere the banner says "all interfaces" without
them). A discovery port is no place to connect to and is left out.
"""

from __future__ import annotations

import ipaddress
import socket

MAX_LISTED = 6


def _ipv4_addresses() -> list:
    from xrce.agent.links.udp import local_ipv4_addresses  # the discovery port's answer too

    return [socket.inet_ntoa(address) for address in local_ipv4_addresses()]


def _ipv6_addresses() -> list:
    found = []
    try:
        with open("/proc/net/if_inet6") as table:
            for line in table:
                fields = line.split()
                if fields:
                    found.append(str(ipaddress.IPv6Address(bytes.fromhex(fields[0]))))
    except (OSError, ValueError):
        pass
    return found


def host_addresses(ipv6: bool) -> list:
    """The host's addresses a board could use: loopback and link-local last (a link-local IPv6
    address needs its interface named, which board code rarely does)."""
    try:
        addresses = _ipv6_addresses() if ipv6 else _ipv4_addresses()
    except (OSError, ImportError):  # no fcntl (not a Unix)
        return []
    seen = list(dict.fromkeys(addresses))

    def remote_first(text):
        address = ipaddress.ip_address(text)
        return (address.is_loopback or address.is_link_local, seen.index(text))
    return sorted(seen, key=remote_first)


def _endpoint(host: str, port: int) -> str:
    return ("[%s]:%d" if ":" in host else "%s:%d") % (host, port)


def reach_text(link) -> str | None:
    """``udp4 192.168.1.10:8888, 127.0.0.1:8888`` for an IP link, None for any other."""
    host, port = getattr(link, "host", None), getattr(link, "port", None)
    if link.name == "discovery" or not isinstance(host, str) or not isinstance(port, int):
        return None
    if host not in ("0.0.0.0", "::"):
        return "%s %s" % (link.name, _endpoint(host, port))
    addresses = host_addresses(host == "::")
    if not addresses:
        return "%s port %d on all interfaces" % (link.name, port)
    listed = ", ".join(_endpoint(a, port) for a in addresses[:MAX_LISTED])
    if len(addresses) > MAX_LISTED:
        listed += ", ..."
    return "%s %s (all interfaces)" % (link.name, listed)


def banner_suffix(links) -> str:
    """``; boards reach it at udp4 192.168.1.10:8888, ...`` or nothing (serial links)."""
    reach = [text for text in (reach_text(link) for link in links) if text]
    return "; boards reach it at " + "; ".join(reach) if reach else ""
