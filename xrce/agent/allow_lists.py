"""The words of the allow-lists: client keys (``--allow-keys``, a fleet file's ``key``) and IP
addresses or networks (``--allow-from``, a fleet file's ``address``), parsed once for both, so
that a board is named the same way wherever the operator names it. Standard library only: the
command line and the fleet file read them before anything else loads."""

from __future__ import annotations

import ipaddress


def parse_keys(text: str) -> frozenset:
    """``"0xAABBCCDD,11223344"`` -> the keys as their 4 wire bytes (big-endian, as micro-ROS
    sends the uint32 it is given and as the agent's log prints them). ValueError on a bad key."""
    keys = set()
    for item in text.split(","):
        item = item.strip()
        digits = item[2:] if item[:2].lower() == "0x" else item
        if not digits or len(digits) > 8:
            raise ValueError("%r is not a client key (up to 8 hex digits, e.g. 0xAABBCCDD)" % item)
        try:
            value = int(digits, 16)
        except ValueError:
            raise ValueError("%r is not a client key (up to 8 hex digits, e.g. 0xAABBCCDD)"
                             % item) from None
        if value == 0:
            raise ValueError("client key 0 is invalid in XRCE")
        keys.add(value.to_bytes(4, "big"))
    return frozenset(keys)


def parse_networks(text: str) -> tuple:
    """``"10.0.0.0/24,fd00::/8,192.168.1.7"`` -> ip_network objects. ValueError on a bad one."""
    networks = []
    for item in text.split(","):
        item = item.strip()
        try:
            networks.append(ipaddress.ip_network(item, strict=False))
        except ValueError:
            raise ValueError("%r is not an address or CIDR network" % item) from None
    return tuple(networks)
