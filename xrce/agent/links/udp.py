"""UDP links of the agent: the UDP v4/v6 server and the discovery responder (XRCE-WIRE.md §10).

One XRCE message per datagram, no framing. The link contract is in ``xrce.agent.links``.
"""

from __future__ import annotations

import asyncio
import fcntl
import socket
import struct

from xrce.wire import constants as C
from xrce.agent.links import MAX_MESSAGE_SIZE, Link, log
from xrce import DecodeError, EncodeError
from xrce.wire.message import decode_header, iter_submessages
from xrce.wire.submessages import GetInfo, Info, Locator, decode_payload, encode_message

# Asked of the kernel for UDP sockets so bursts from many clients survive a busy loop iteration;
# Linux silently caps it at net.core.rmem_max / wmem_max.
UDP_SOCKET_BUFFER = 4 * 1024 * 1024
DISCOVERY_PORT = 7400
DISCOVERY_MULTICAST_GROUP = "239.255.0.2"
_UDP_READ_BATCH = 64  # datagrams taken per readiness event of a UDP socket
_SIOCGIFADDR = 0x8915  # Linux <bits/ioctls.h>


class _DatagramHandler(asyncio.DatagramProtocol):
    def __init__(self, on_datagram):
        self._on_datagram = on_datagram

    def datagram_received(self, data, addr):
        self._on_datagram(data, addr)

    def error_received(self, exc):
        # ICMP errors (port unreachable after a client went away) arrive here on Linux.
        log.debug("udp: socket error %s", exc)


def _open_udp_socket(family, host, port, reuse_address=False):
    sock = socket.socket(family, socket.SOCK_DGRAM)
    try:
        if reuse_address:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        for option in (socket.SO_RCVBUF, socket.SO_SNDBUF):
            try:
                sock.setsockopt(socket.SOL_SOCKET, option, UDP_SOCKET_BUFFER)
            except OSError as exc:
                log.debug("udp: cannot enlarge the socket buffers: %s", exc)
        sock.bind((host, port))
        sock.setblocking(False)
    except BaseException:
        sock.close()
        raise
    return sock


def _send_datagram(link, sock, endpoint, data):
    """sendto on the socket itself, not through the asyncio transport: the transport treats any
    error other than OSError as fatal and closes the socket, which would cut off every client."""
    if sock is None:
        link.stats.drops += 1
        return False
    try:
        sock.sendto(data, endpoint)
    except (OSError, ValueError, TypeError) as exc:
        # BlockingIOError too: the kernel's send buffer is full, and UDP may lose it anyway.
        link.stats.drops += 1
        log.debug("%s: cannot send to %r: %s", link.name, endpoint, exc)
        return False
    link.stats.messages_out += 1
    link.stats.bytes_out += len(data)
    return True


class UdpServer(Link):
    """UDP v4/v6: one XRCE message per datagram; replies go to the datagram's source address."""

    sends_from_any_thread = True  # sendto() on the socket itself (_send_datagram)

    def __init__(self, receiver, port, *, family=socket.AF_INET, host=None):
        super().__init__(receiver)
        self.family = family
        self.name = "udp4" if family == socket.AF_INET else "udp6"
        self.host = host if host is not None else ("0.0.0.0" if family == socket.AF_INET else "::")
        self.requested_port = port
        self.port = None
        self._loop = None
        self._sock = None
        self.fastpath = None  # xrce.agent.engine.compiled.fastpath.FastPath when the compiled path reads the socket

    async def start(self):
        # The socket is read directly rather than through create_datagram_endpoint: asyncio's
        # datagram transport takes one datagram per readiness event, a poll per message, which
        # was a third of the agent's time per message under load (bench/run.py).
        self._loop = asyncio.get_running_loop()
        sock = _open_udp_socket(self.family, self.host, self.requested_port)
        self.port = sock.getsockname()[1]
        self._sock = sock
        # After the middleware started: the compiled path looks for rcl. A receiver that is not
        # the agent's engine (a test's echo) has none to offer.
        attach = getattr(self.receiver, "attach_compiled_path", None)
        self.fastpath = attach(self, sock) if attach is not None else None  # its own thread reads
        if self.fastpath is None:
            self._loop.add_reader(sock.fileno(), self._read_ready)

    def describe(self):
        return "%s agent on port %d" % (self.name, self.port)

    def _read_ready(self):
        sock = self._sock
        stats = self.stats
        for _ in range(_UDP_READ_BATCH):  # bounded: TCP and serial links share the loop
            try:
                data, addr = sock.recvfrom(MAX_MESSAGE_SIZE)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                # ICMP errors (port unreachable after a client went away) arrive here on Linux.
                log.debug("%s: socket error %s", self.name, exc)
                continue
            stats.bytes_in += len(data)
            self._deliver(addr, data)

    def send(self, endpoint, data):
        return _send_datagram(self, self._sock, endpoint, data)

    async def close(self):
        if self._sock is not None:
            if self.fastpath is not None:
                self.fastpath.close()
                self.fastpath = None
            else:
                self._loop.remove_reader(self._sock.fileno())
            self._sock.close()
            self._sock = None


# ------------------------------------------------------------------------------------- discovery

def local_ipv4_addresses():
    """The primary IPv4 address of every local interface that has one, in interface index order."""
    addresses = []
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for _index, ifname in socket.if_nameindex():
            request = struct.pack("256s", ifname.encode()[:15])
            try:
                reply = fcntl.ioctl(probe.fileno(), _SIOCGIFADDR, request)
            except OSError:  # no IPv4 address on this interface
                continue
            # struct ifreq: 16-byte name, then struct sockaddr_in (family, port, address).
            address = reply[20:24]
            if address not in addresses:
                addresses.append(address)
    finally:
        probe.close()
    return addresses


def local_ipv6_addresses():
    """Every IPv6 address of the local interfaces (loopback and link-local ones too, as eProsima's
    agent lists them), in interface index order; none where the host has IPv6 off."""
    try:
        with open("/proc/net/if_inet6") as table:
            rows = [line.split() for line in table]
    except OSError:
        return []
    addresses = []
    for row in sorted((r for r in rows if len(r) >= 6), key=lambda r: int(r[1], 16)):
        address = bytes.fromhex(row[0])
        if len(address) == 16 and address not in addresses:
            addresses.append(address)
    return addresses


class DiscoveryServer(Link):
    """Answers GET_INFO on the discovery port, unicast, with a locator per local address of the
    agent's own family and its service port (XRCE-WIRE.md §10): MEDIUM ones (IPv4) for a udp4 or
    tcp4 agent, LARGE ones (IPv6) for udp6 or tcp6, as eProsima's agent answers, so a client finds
    an address it can reach the agent at. The requests come on IPv4 (eProsima's clients discover
    over IPv4 only, multicast group 239.255.0.2); an IPv6 agent also takes them on IPv6, unicast,
    on the same port."""

    name = "discovery"

    def __init__(self, agent_port, port=DISCOVERY_PORT, *, host="0.0.0.0",
                 group=DISCOVERY_MULTICAST_GROUP, family=socket.AF_INET):
        super().__init__(receiver=None)
        self.agent_port = agent_port
        self.requested_port = port
        self.port = None
        self.host = host
        self.group = group
        # The agent link's family: the locators' (a link without one, IPv4).
        self.family = socket.AF_INET6 if family == socket.AF_INET6 else socket.AF_INET
        self.joined_group = False
        self._transports = []
        self._sock = None
        self._sock6 = None

    async def start(self):
        loop = asyncio.get_running_loop()
        sock = _open_udp_socket(socket.AF_INET, self.host, self.requested_port, reuse_address=True)
        try:
            membership = struct.pack("4s4s", socket.inet_aton(self.group),
                                     socket.inet_aton("0.0.0.0"))
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, membership)
            self.joined_group = True
        except OSError as exc:
            log.warning("discovery: cannot join multicast group %s (%s); unicast only",
                        self.group, exc)
        self.port = sock.getsockname()[1]
        transport, _ = await loop.create_datagram_endpoint(
            lambda: _DatagramHandler(lambda data, addr: self._on_datagram(data, addr, sock)),
            sock=sock)
        self._transports.append(transport)
        self._sock = sock
        if self.family == socket.AF_INET6:
            sock6 = self._open_ipv6()
            if sock6 is not None:
                transport, _ = await loop.create_datagram_endpoint(
                    lambda: _DatagramHandler(lambda data, addr: self._on_datagram(data, addr, sock6)),
                    sock=sock6)
                self._transports.append(transport)
                self._sock6 = sock6

    def _open_ipv6(self):
        sock = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)  # IPv4 has its own socket
            sock.bind(("::", self.port))
            sock.setblocking(False)
        except OSError as exc:
            sock.close()
            log.info("discovery: no IPv6 socket on port %d (%s); IPv4 only", self.port, exc)
            return None
        return sock

    def describe(self):
        return "discovery on port %d" % self.port

    def discovery_locators(self):
        if self.family == socket.AF_INET6:
            return [Locator(C.LOCATOR_LARGE, address, self.agent_port)
                    for address in local_ipv6_addresses()]
        return [Locator(C.LOCATOR_MEDIUM, address, self.agent_port)
                for address in local_ipv4_addresses()]

    def _on_datagram(self, data, addr, sock=None):
        self.stats.bytes_in += len(data)
        self.stats.messages_in += 1
        try:
            header = decode_header(data)
            first = next(iter_submessages(data, header.size), None)
            payloads = [decode_payload(first[0], first[1], data, first[2], first[3])] \
                if first is not None and first[0] == C.GET_INFO else []
        except (DecodeError, EncodeError, ValueError, IndexError) as exc:
            self.stats.drops += 1
            log.debug("discovery: malformed datagram from %r: %s", addr, exc)
            return
        # The first submessage only, one reply at most (as eProsima): anyone can aim a spoofed
        # datagram of thousands of GET_INFOs here, and each used to get its own INFO.
        if not payloads or not isinstance(payloads[0], GetInfo):
            self.stats.drops += 1
            return
        request = payloads[0]
        info = Info(request.request_id, request.object_id, locators=self.discovery_locators())
        _send_datagram(self, sock or self._sock, addr,
                       encode_message(header.session_id, 0, 0, header.key, [info]))

    def send(self, endpoint, data):
        sock = self._sock6 if len(endpoint) == 4 and self._sock6 is not None else self._sock
        return _send_datagram(self, sock, endpoint, data)

    async def close(self):
        for transport in self._transports:
            transport.close()
        self._transports = []
        self._sock = self._sock6 = None



__all__ = ["UdpServer", "DiscoveryServer", "local_ipv4_addresses", "local_ipv6_addresses",
           "DISCOVERY_PORT"]
