"""Who may open a session: ``--allow-keys KEY[,KEY...]`` and ``--allow-from CIDR[,CIDR...]``.

XRCE has no authentication on the wire: a client key is 4 bytes anyone on the network can send.
An allow-list does not make that secure, but it keeps unknown boards (and a stranger's flood of
made-up keys) from ever getting a session, and with ``--allow-from`` a session only from the
addresses the operator's boards use. The engine asks ``AdmissionPolicy.admits`` when a
CREATE_CLIENT is otherwise valid (xrce.agent.session); a refusal is answered ``ERR_DENIED``.

Refusals are logged, at most ``LOG_BURST`` lines per ``LOG_PERIOD_S`` however many arrive, with
the count of those not logged in the next line: a flood of refused CREATE_CLIENTs must not fill
the operator's disk through the log. The operator's own log names the key in clear (as
eProsima's does).
"""

from __future__ import annotations

import ipaddress
import logging
import time

log = logging.getLogger("xrce.agent.admission")

LOG_PERIOD_S = 10.0
LOG_BURST = 5


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


def endpoint_address(endpoint):
    """The IP address a link endpoint came from (a UDP ``(host, port, ...)`` or a TCP connection
    with its ``peer``), None for an endpoint without one (a serial port). An IPv4 address an
    IPv6 socket reports as ``::ffff:a.b.c.d`` is that IPv4 address."""
    peer = getattr(endpoint, "peer", endpoint)
    if not isinstance(peer, tuple) or not peer:
        return None
    try:
        address = ipaddress.ip_address(str(peer[0]).split("%", 1)[0])
    except ValueError:
        return None
    if address.version == 6 and address.ipv4_mapped is not None:
        return address.ipv4_mapped
    return address


class AdmissionPolicy:
    """Both lists are optional; a client must pass every list that is given."""

    def __init__(self, keys=None, networks=None, clock=time.monotonic):
        self.keys = frozenset(keys) if keys else None
        self.networks = tuple(networks) if networks else None
        self.clock = clock
        self.refused = 0
        self._window_start = None
        self._window_lines = 0
        self._suppressed = 0

    @classmethod
    def from_args(cls, args):
        keys = getattr(args, "allow_keys", None)
        networks = getattr(args, "allow_from", None)
        if not keys and not networks:
            return None
        return cls(keys, networks)

    def describe(self) -> str:
        parts = []
        if self.keys is not None:
            parts.append("%d allowed key(s)" % len(self.keys))
        if self.networks is not None:
            parts.append("clients from %s only" % ", ".join(str(n) for n in self.networks))
        return "; ".join(parts)

    def admits(self, key: bytes, link, endpoint) -> bool:
        reason = None
        if self.networks is not None:
            address = endpoint_address(endpoint)
            if address is None:
                reason = "no IP address to check against --allow-from"
            elif not any(address.version == n.version and address in n for n in self.networks):
                reason = "address %s not in --allow-from" % address
        if reason is None and self.keys is not None and bytes(key) not in self.keys:
            reason = "key not in --allow-keys"
        if reason is None:
            return True
        self.refused += 1
        self._log_refusal(key, link, endpoint, reason)
        return False

    def _log_refusal(self, key, link, endpoint, reason) -> None:
        now = self.clock()
        if self._window_start is None or now - self._window_start >= LOG_PERIOD_S:
            self._window_start, self._window_lines = now, 0
        if self._window_lines >= LOG_BURST:
            self._suppressed += 1
            return
        self._window_lines += 1
        suppressed, self._suppressed = self._suppressed, 0
        from xrce.agent.observability import endpoint_text

        log.warning("refused CREATE_CLIENT of key %s from %s %s: %s (ERR_DENIED)%s",
                    bytes(key).hex(), getattr(link, "name", "link"), endpoint_text(
                        getattr(endpoint, "peer", endpoint)), reason,
                    "; %d more refusals not logged" % suppressed if suppressed else "")


__all__ = ["AdmissionPolicy", "endpoint_address", "parse_keys", "parse_networks"]
