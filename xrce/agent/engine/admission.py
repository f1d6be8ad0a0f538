"""Who may open a session: ``--allow-keys KEY[,KEY...]`` and ``--allow-from CIDR[,CIDR...]``.

XRCE has no authentication on the wire: a client key is 4 bytes anyone on the network can send.
An allow-list does not make that secure, but it keeps unknown boards (and a stranger's flood of
made-up keys) from ever getting a session, and with ``--allow-from`` a session only from the
addresses the operator's boards use. The engine asks ``AdmissionPolicy.admits`` when a
CREATE_CLIENT is otherwise valid (xrce.agent.engine.sessions); a refusal is answered ``ERR_DENIED``.
With ``--allow-from``, it asks ``admits_datagram`` of every datagram before any session lookup:
one from outside the list is dropped and counted, whatever client key its header names.

Refusals are logged (``RefusalLog``, also used for the engine's failed CREATEs), at most
``LOG_BURST`` lines per ``LOG_PERIOD_S`` however many arrive, with the count of those not logged
in the next line: a flood of refused CREATE_CLIENTs must not fill the operator's disk through the
log. The operator's own log names the key in clear (as
eProsima's does).
"""

from __future__ import annotations

import ipaddress
import logging
import time

log = logging.getLogger("xrce.agent.admission")

LOG_PERIOD_S = 10.0
LOG_BURST = 5


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


def _link_name(link) -> str:
    # Admission is asked with a link, or with none (a restored client, a direct caller).
    return link.name if link is not None else "link"


class RefusalLog:
    """One kind of refusal logged at most ``burst`` lines per ``period`` seconds however many
    arrive, so that a stranger's flood cannot fill the operator's disk through the log. The
    first ones are logged in full; the next line logged after a quiet window says how many were
    not, and ``flush`` (the agent's close) says it for those left over."""

    def __init__(self, logger, what: str, clock=time.monotonic, burst: int = LOG_BURST,
                 period: float = LOG_PERIOD_S):
        self.logger = logger
        self.what = what  # "refusals": "; 3 more refusals not logged"
        self.clock = clock
        self.burst = burst
        self.period = period
        self._window_start = None
        self._window_lines = 0
        self._suppressed = 0

    def warning(self, message: str, *args) -> None:
        now = self.clock()
        if self._window_start is None or now - self._window_start >= self.period:
            self._window_start, self._window_lines = now, 0
        if self._window_lines >= self.burst:
            self._suppressed += 1
            return
        self._window_lines += 1
        suppressed, self._suppressed = self._suppressed, 0
        if suppressed:
            message += "; %d more %s not logged"
            args += (suppressed, self.what)
        self.logger.warning(message, *args)

    def flush(self) -> None:
        if self._suppressed:
            self.logger.warning("%d more %s not logged", self._suppressed, self.what)
            self._suppressed = 0


class AdmissionPolicy:
    """Both lists are optional; a client must pass every list that is given."""

    def __init__(self, keys=None, networks=None, clock=time.monotonic):
        self.keys = frozenset(keys) if keys else None
        self.networks = tuple(networks) if networks else None
        self.clock = clock
        self.refused = 0
        self.datagrams_refused = 0
        self._refusals = RefusalLog(log, "refusals", clock)
        self._datagram_refusals = RefusalLog(log, "datagrams from outside --allow-from", clock)
        # Source host -> on the list or not: the check runs for every datagram, and parsing an
        # address costs more than the rest of a sample's way through the engine. Bounded: a
        # spoofed flood from many addresses only clears it.
        self._verdicts = {}

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
            reason = self._address_refusal(endpoint) or None
        if reason is None and self.keys is not None and bytes(key) not in self.keys:
            reason = "key not in --allow-keys"
        if reason is None:
            return True
        self.refused += 1
        from xrce.agent.observe.names import endpoint_text

        self._refusals.warning("refused CREATE_CLIENT of key %s from %s %s: %s (ERR_DENIED)",
                               bytes(key).hex(), _link_name(link),
                               endpoint_text(getattr(endpoint, "peer", endpoint)), reason)
        return False

    def admits_datagram(self, link, endpoint, data) -> bool:
        """False for an in-session datagram from outside --allow-from (always True without it):
        the engine drops it before looking up any session. A session whose header carries its
        key (id < 0x80) is otherwise found by that key from any source (as eProsima's agent
        finds it), so a stranger who knows or guesses a key could write into, or delete, an
        allowed board's session. Session-less messages pass: their CREATE_CLIENT gets its
        ERR_DENIED from ``admits``, so that a board set up on the wrong network learns why."""
        if self.networks is None or not data or data[0] & 0x7F == 0:
            return True
        peer = getattr(endpoint, "peer", endpoint)
        host = peer[0] if isinstance(peer, tuple) and peer else None
        verdict = self._verdicts.get(host)
        if verdict is None:
            verdict = self._address_refusal(endpoint)
            if len(self._verdicts) >= 1024:
                self._verdicts.clear()
            self._verdicts[host] = verdict
        if not verdict:  # "" : on the list
            return True
        self.datagrams_refused += 1
        from xrce.agent.observe.names import endpoint_text

        self._datagram_refusals.warning("dropped a datagram of session 0x%02X from %s %s: %s",
                                        data[0], _link_name(link),
                                        endpoint_text(peer), verdict)
        return False

    def _address_refusal(self, endpoint) -> str:
        """Why ``endpoint`` is not on --allow-from; "" when it is."""
        address = endpoint_address(endpoint)
        if address is None:
            return "no IP address to check against --allow-from"
        if not any(address.version == n.version and address in n for n in self.networks):
            return "address %s not in --allow-from" % address
        return ""

    def flush(self) -> None:
        self._refusals.flush()
        self._datagram_refusals.flush()


__all__ = ["AdmissionPolicy", "RefusalLog", "endpoint_address"]
