"""The agent's transport servers: UDP, TCP, serial, pseudoterminal and discovery, on one asyncio loop.

Every link has a ``name``, a ``stats`` (``LinkStats``) and ``send(endpoint, data) -> bool``, and hands
each complete XRCE message it receives to ``receiver.receive(link, endpoint, data)`` (the protocol
engine). What an endpoint is depends on the link:

- UDP: the datagram's source address tuple;
- TCP: the ``TcpConnection`` object of the stream;
- serial / multiserial / pseudoterminal: ``(port_name, remote_serial_address)``.

A malformed datagram or frame, or an exception raised by the receiver, is logged and counted as a
drop; nothing raises into the event loop. The byte framers themselves live in
``xrce.transports.framing`` (shared with the client).

If the receiver has an ``endpoint_closed(link, endpoint)`` method, it is called when a TCP
connection or a serial port goes away, so the engine can forget the sessions mapped to it.
"""

from __future__ import annotations

import asyncio
import fcntl
import glob
import logging
import os
import socket
import struct
import termios
import tty

from xrce import constants as C
from xrce.errors import DecodeError, EncodeError
from xrce.submessages import GetInfo, Info, Locator, decode_message, encode_message
from xrce.transports.crc import get_crc
from xrce.transports.framing import (
    MAX_FRAME_PAYLOAD,
    FrameDecoder,
    LengthPrefixDecoder,
    encode_frame,
    encode_length_prefixed,
)

log = logging.getLogger("xrce.agent.servers")

# Like eProsima's SERVER_BUFFER_SIZE: the largest message any link accepts.
MAX_MESSAGE_SIZE = 65535
# Asked of the kernel for UDP sockets so bursts from many clients survive a busy loop iteration;
# Linux silently caps it at net.core.rmem_max / wmem_max.
UDP_SOCKET_BUFFER = 4 * 1024 * 1024
DEFAULT_TCP_MAX_CONNECTIONS = 100
# Bytes queued towards one slow TCP peer or serial port before further replies are dropped: the
# reliable streams resend what matters, and memory stays bounded whatever the peer does.
MAX_PENDING_OUTPUT = 256 * 1024
SERIAL_AGENT_ADDRESS = 0
DEFAULT_BAUDRATE = 115200
DEFAULT_REOPEN_INTERVAL = 0.2  # seconds between attempts to reopen a vanished serial device
DISCOVERY_PORT = 7400
DISCOVERY_MULTICAST_GROUP = "239.255.0.2"
_READ_CHUNK = 65536
_UDP_READ_BATCH = 64  # datagrams taken per readiness event of a UDP socket
_SIOCGIFADDR = 0x8915  # Linux <bits/ioctls.h>


class LinkStats:
    """Traffic counters of one link. ``drops`` counts messages or frames thrown away for any reason
    (malformed, oversize, unreachable peer, receiver error, output queue full)."""

    __slots__ = ("bytes_in", "bytes_out", "messages_in", "messages_out", "drops")

    def __init__(self):
        self.bytes_in = 0
        self.bytes_out = 0
        self.messages_in = 0
        self.messages_out = 0
        self.drops = 0

    def as_dict(self):
        return {name: getattr(self, name) for name in self.__slots__}

    def __repr__(self):
        return "LinkStats(%s)" % ", ".join("%s=%d" % item for item in self.as_dict().items())


class Link:
    """Common part of every server: counters and the guarded hand-off to the receiver."""

    name = "link"

    def __init__(self, receiver):
        self.receiver = receiver
        self.stats = LinkStats()

    def describe(self):
        """A short human description for the start-up banner, valid once started."""
        return self.name

    def _deliver(self, endpoint, message):
        self.stats.messages_in += 1
        try:
            self.receiver.receive(self, endpoint, message)
        except Exception:  # one bad message must not take the loop (and every other client) down
            self.stats.drops += 1
            log.exception("%s: receiver failed on a %d-byte message from %r",
                          self.name, len(message), endpoint)

    def _endpoint_closed(self, endpoint):
        hook = getattr(self.receiver, "endpoint_closed", None)
        if hook is None:
            return
        try:
            hook(self, endpoint)
        except Exception:
            log.exception("%s: receiver failed to forget endpoint %r", self.name, endpoint)

    async def start(self):
        raise NotImplementedError

    async def close(self):
        raise NotImplementedError


# --------------------------------------------------------------------------------------------- UDP

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

    def __init__(self, receiver, port, *, family=socket.AF_INET, host=None):
        super().__init__(receiver)
        self.family = family
        self.name = "udp4" if family == socket.AF_INET else "udp6"
        self.host = host if host is not None else ("0.0.0.0" if family == socket.AF_INET else "::")
        self.requested_port = port
        self.port = None
        self._loop = None
        self._sock = None

    async def start(self):
        # The socket is read directly rather than through create_datagram_endpoint: asyncio's
        # datagram transport takes one datagram per readiness event, a poll per message, which
        # was a third of the agent's time per message under load (bench/run.py).
        self._loop = asyncio.get_running_loop()
        sock = _open_udp_socket(self.family, self.host, self.requested_port)
        self.port = sock.getsockname()[1]
        self._sock = sock
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
            self._loop.remove_reader(self._sock.fileno())
            self._sock.close()
            self._sock = None


# --------------------------------------------------------------------------------------------- TCP

class TcpConnection(asyncio.Protocol):
    """One client stream; it is the endpoint the engine sees for everything that client sends."""

    _next_id = 0

    def __init__(self, server):
        TcpConnection._next_id += 1
        self.id = TcpConnection._next_id
        self.server = server
        self.peer = None
        self.transport = None
        self.decoder = LengthPrefixDecoder(MAX_MESSAGE_SIZE)
        self.closed = False

    def __repr__(self):
        return "TcpConnection(%d, %r)" % (self.id, self.peer)

    def connection_made(self, transport):
        self.transport = transport
        self.peer = transport.get_extra_info("peername")
        self.server._connection_made(self)

    def data_received(self, data):
        server = self.server
        server.stats.bytes_in += len(data)
        for message in self.decoder.feed(data):
            server._deliver(self, message)
        if self.decoder.broken:
            # A byte stream has no resynchronisation point: this peer is lost, the others are not.
            server.stats.drops += 1
            log.warning("tcp: %r sent an invalid length prefix; closing that connection", self)
            self.close()

    def connection_lost(self, exc):
        self.closed = True
        self.server._connection_lost(self)

    def close(self):
        if not self.closed and self.transport is not None:
            self.closed = True
            self.transport.close()


class TcpServer(Link):
    """TCP v4/v6: a 2-byte little-endian length before every message, both ways.

    At most ``max_connections`` streams at a time; a connection beyond that is closed at once.
    """

    def __init__(self, receiver, port, *, family=socket.AF_INET, host=None,
                 max_connections=DEFAULT_TCP_MAX_CONNECTIONS):
        super().__init__(receiver)
        self.family = family
        self.name = "tcp4" if family == socket.AF_INET else "tcp6"
        self.host = host if host is not None else ("0.0.0.0" if family == socket.AF_INET else "::")
        self.requested_port = port
        self.port = None
        self.max_connections = max_connections
        self.connections = set()
        self.rejected_connections = 0
        self._server = None

    async def start(self):
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(
            lambda: TcpConnection(self), self.host, self.requested_port, family=self.family,
            reuse_address=True, backlog=self.max_connections)
        self.port = self._server.sockets[0].getsockname()[1]

    def describe(self):
        return "%s agent on port %d" % (self.name, self.port)

    def _connection_made(self, connection):
        if len(self.connections) >= self.max_connections:
            self.rejected_connections += 1
            log.warning("tcp: %d connections open, refusing %r", len(self.connections), connection)
            connection.closed = True
            connection.transport.close()
            return
        self.connections.add(connection)
        log.debug("tcp: %r connected", connection)

    def _connection_lost(self, connection):
        if connection in self.connections:
            self.connections.discard(connection)
            log.debug("tcp: %r disconnected", connection)
            self._endpoint_closed(connection)

    def send(self, endpoint, data):
        if endpoint.closed or endpoint.transport is None:
            self.stats.drops += 1
            return False
        if endpoint.transport.get_write_buffer_size() > MAX_PENDING_OUTPUT:
            self.stats.drops += 1
            return False
        try:
            framed = encode_length_prefixed(data)
        except EncodeError as exc:
            self.stats.drops += 1
            log.warning("tcp: cannot send a %d-byte message: %s", len(data), exc)
            return False
        endpoint.transport.write(framed)
        self.stats.messages_out += 1
        self.stats.bytes_out += len(framed)
        return True

    async def close(self):
        if self._server is not None:
            self._server.close()
            for connection in list(self.connections):
                connection.close()
            await self._server.wait_closed()
            self._server = None


# ------------------------------------------------------------------------- serial and pseudoterminal

class _FramedPort:
    """One open byte-stream fd with its own frame decoder and bounded output queue."""

    def __init__(self, name, fd, crc, closer):
        self.name = name
        self.fd = fd
        self.decoder = FrameDecoder(local_addr=SERIAL_AGENT_ADDRESS, max_payload=MAX_FRAME_PAYLOAD,
                                    crc=crc)
        self.pending = bytearray()
        self.writer_armed = False
        self.closer = closer
        self.open = True
        self.remotes = set()

    def dropped_frames(self):
        d = self.decoder
        return d.crc_errors + d.oversize + d.resyncs + d.wrong_address


class SerialFramedLink(Link):
    """XRCE stream framing (§11) over one or more byte-stream fds; the agent's address is 0.

    Endpoint = ``(port_name, remote_address)``; replies are framed src=0, dst=remote_address.
    Subclasses open the fds (``SerialServer``: pyserial ports; ``PseudoterminalServer``: a pty).
    """

    name = "serial"

    def __init__(self, receiver, *, crc="arc"):
        super().__init__(receiver)
        self.crc_name = crc if isinstance(crc, str) else getattr(crc, "__name__", "custom")
        self._crc = get_crc(crc)
        self.ports = {}
        self._loop = None

    def _add_port(self, name, fd, closer):
        self._loop = asyncio.get_running_loop()
        os.set_blocking(fd, False)
        port = _FramedPort(name, fd, self._crc, closer)
        self.ports[name] = port
        self._loop.add_reader(fd, self._on_readable, port)
        return port

    def _on_readable(self, port):
        try:
            data = os.read(port.fd, _READ_CHUNK)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            # EIO: the device went away (USB unplugged, pty peer gone for good).
            log.warning("%s: reading %s failed: %s; closing it", self.name, port.name, exc)
            self._close_port(port)
            return
        if not data:
            log.warning("%s: %s reached end of file; closing it", self.name, port.name)
            self._close_port(port)
            return
        self.stats.bytes_in += len(data)
        before = port.dropped_frames()
        frames = port.decoder.feed(data)
        self.stats.drops += port.dropped_frames() - before
        for src, _dst, payload in frames:
            endpoint = (port.name, src)
            port.remotes.add(src)
            self._deliver(endpoint, payload)

    def send(self, endpoint, data):
        try:
            port_name, remote = endpoint
            port = self.ports[port_name]
        except (KeyError, TypeError, ValueError):
            self.stats.drops += 1
            return False
        if not port.open:
            self.stats.drops += 1
            return False
        try:
            frame = encode_frame(data, SERIAL_AGENT_ADDRESS, remote, crc=self._crc)
        except EncodeError as exc:
            self.stats.drops += 1
            log.warning("%s: cannot frame a %d-byte message: %s", self.name, len(data), exc)
            return False
        if len(port.pending) + len(frame) > MAX_PENDING_OUTPUT:
            self.stats.drops += 1
            return False
        self.stats.messages_out += 1
        port.pending += frame
        if not port.writer_armed:
            self._flush(port)
        return True

    def _flush(self, port):
        while port.pending:
            try:
                written = os.write(port.fd, port.pending)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as exc:
                log.warning("%s: writing %s failed: %s; closing it", self.name, port.name, exc)
                self._close_port(port)
                return
            self.stats.bytes_out += written
            del port.pending[:written]
        if port.pending and not port.writer_armed:
            self._loop.add_writer(port.fd, self._flush, port)
            port.writer_armed = True
        elif not port.pending and port.writer_armed:
            self._loop.remove_writer(port.fd)
            port.writer_armed = False

    def _close_port(self, port):
        if not port.open:
            return
        port.open = False
        loop = self._loop
        loop.remove_reader(port.fd)
        if port.writer_armed:
            loop.remove_writer(port.fd)
            port.writer_armed = False
        if port.pending:  # replies that never reached the wire
            self.stats.drops += 1
            port.pending.clear()
        try:
            port.closer()
        except OSError as exc:
            log.debug("%s: closing %s: %s", self.name, port.name, exc)
        for remote in sorted(port.remotes):
            self._endpoint_closed((port.name, remote))

    async def close(self):
        for port in list(self.ports.values()):
            if port.open and port.pending:
                # Best effort: let the last replies (e.g. DELETE statuses) reach the wire.
                self._flush(port)
            self._close_port(port)


class SerialServer(SerialFramedLink):
    """One or several serial devices opened with pyserial (raw, 8N1, no flow control).

    A device may be a glob (``/dev/serial/by-id/*OpenCR*``): the first match, in sorted order, is
    opened. Hot-plug: when a device fails (EIO or end of file after a USB unplug) its sessions are
    forgotten (``endpoint_closed``) and the same path or glob is tried again every
    ``reopen_interval`` seconds until it opens; the port keeps its name (the path or glob as given),
    so endpoints stay the same across a re-plug. Every device must open at start.
    """

    def __init__(self, receiver, devices, *, baudrate=DEFAULT_BAUDRATE, crc="arc",
                 reopen_interval=DEFAULT_REOPEN_INTERVAL):
        super().__init__(receiver, crc=crc)
        if isinstance(devices, str):
            devices = [devices]
        self.devices = list(devices)
        self.name = "serial" if len(self.devices) == 1 else "multiserial"
        self.baudrate = baudrate
        self.reopen_interval = reopen_interval
        self.reopens = 0
        self._serials = {}
        self._reopen_tasks = {}
        self._closing = False

    async def start(self):
        for device in self.devices:
            try:
                self._open(device)
            except OSError:
                await self.close()
                raise

    def _open(self, device):
        import serial  # pyserial: termios setup of baud rate and raw mode, portable and well kept

        path = _resolve_device(device)
        try:
            port = serial.Serial(path, self.baudrate, timeout=0, write_timeout=0, exclusive=True)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise OSError("cannot open %s: %s" % (device, exc)) from exc
        self._serials[device] = port
        self._add_port(device, port.fileno(), port.close)
        return path

    def _close_port(self, port):
        was_open = port.open
        super()._close_port(port)
        self._serials.pop(port.name, None)
        if was_open and not self._closing and port.name not in self._reopen_tasks:
            log.warning("%s: %s went away; trying to reopen it every %.1f s", self.name, port.name,
                        self.reopen_interval)
            self._reopen_tasks[port.name] = asyncio.ensure_future(self._reopen(port.name))

    async def _reopen(self, device):
        reported = False
        try:
            while not self._closing:
                await asyncio.sleep(self.reopen_interval)
                try:
                    path = self._open(device)
                except OSError as exc:
                    if not reported:
                        reported = True
                        log.info("%s: %s not back yet (%s)", self.name, device, exc)
                    continue
                self.reopens += 1
                log.warning("%s: %s is back (%s), serving it again", self.name, device, path)
                return
        finally:
            self._reopen_tasks.pop(device, None)

    def describe(self):
        return "%s agent on %s at %d baud" % (self.name, " ".join(self.devices), self.baudrate)

    async def close(self):
        self._closing = True
        for task in list(self._reopen_tasks.values()):
            task.cancel()
        self._reopen_tasks.clear()
        await super().close()


def _resolve_device(device):
    """``device`` itself, or the first (sorted) match when it is a glob pattern."""
    if not glob.has_magic(device):
        return device
    matches = sorted(glob.glob(device))
    if not matches:
        raise OSError("no device matches %s" % device)
    return matches[0]


class PseudoterminalServer(SerialFramedLink):
    """A fresh pty pair: the agent serves the master side, clients open ``slave_path``.

    With ``symlink`` the path is made a symbolic link to the slave (replacing an older link, never a
    regular file) and removed again on close.
    """

    name = "pseudoterminal"

    def __init__(self, receiver, *, symlink=None, crc="arc"):
        super().__init__(receiver, crc=crc)
        self.symlink = symlink
        self.slave_path = None
        self._slave_fd = None
        self._symlink_made = False

    async def start(self):
        master, slave = os.openpty()
        try:
            tty.setraw(slave, termios.TCSANOW)
            self.slave_path = os.ttyname(slave)
            if self.symlink:
                if os.path.islink(self.symlink):
                    os.unlink(self.symlink)
                os.symlink(self.slave_path, self.symlink)
                self._symlink_made = True
        except BaseException:
            os.close(master)
            os.close(slave)
            raise
        # Holding the slave open keeps the master readable (no endless EIO) while no client has it.
        self._slave_fd = slave
        self._add_port(self.slave_path, master, lambda: os.close(master))

    def describe(self):
        text = "pseudoterminal at %s" % self.slave_path
        if self._symlink_made:
            text += " (linked from %s)" % self.symlink
        return text

    async def close(self):
        await super().close()
        if self._slave_fd is not None:
            os.close(self._slave_fd)
            self._slave_fd = None
        if self._symlink_made:
            self._symlink_made = False
            try:
                if os.readlink(self.symlink) == self.slave_path:
                    os.unlink(self.symlink)
            except OSError:
                pass


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


class DiscoveryServer(Link):
    """Answers GET_INFO on the discovery port, unicast, with one MEDIUM locator per local IPv4
    address and the agent's service port (XRCE-WIRE.md §10)."""

    name = "discovery"

    def __init__(self, agent_port, port=DISCOVERY_PORT, *, host="0.0.0.0",
                 group=DISCOVERY_MULTICAST_GROUP):
        super().__init__(receiver=None)
        self.agent_port = agent_port
        self.requested_port = port
        self.port = None
        self.host = host
        self.group = group
        self.joined_group = False
        self._transport = None
        self._sock = None

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
        self._transport, _ = await loop.create_datagram_endpoint(
            lambda: _DatagramHandler(self._on_datagram), sock=sock)
        self._sock = sock

    def describe(self):
        return "discovery on port %d" % self.port

    def info_locators(self):
        return [Locator(C.LOCATOR_MEDIUM, address, self.agent_port)
                for address in local_ipv4_addresses()]

    def _on_datagram(self, data, addr):
        self.stats.bytes_in += len(data)
        self.stats.messages_in += 1
        try:
            header, payloads = decode_message(data)
        except (DecodeError, EncodeError, ValueError, IndexError) as exc:
            self.stats.drops += 1
            log.debug("discovery: malformed datagram from %r: %s", addr, exc)
            return
        requests = [p for p in payloads if isinstance(p, GetInfo)]
        if not requests:
            self.stats.drops += 1
            return
        locators = self.info_locators()
        for request in requests:
            info = Info(request.request_id, request.object_id, locators=locators)
            reply = encode_message(header.session_id, 0, 0, header.key, [info])
            self.send(addr, reply)

    def send(self, endpoint, data):
        return _send_datagram(self, self._sock, endpoint, data)

    async def close(self):
        if self._transport is not None:
            self._transport.close()
            self._transport = None
            self._sock = None


__all__ = [
    "LinkStats", "Link", "UdpServer", "TcpServer", "TcpConnection", "SerialFramedLink",
    "SerialServer", "PseudoterminalServer", "DiscoveryServer", "local_ipv4_addresses",
    "DEFAULT_BAUDRATE", "DISCOVERY_PORT", "DEFAULT_TCP_MAX_CONNECTIONS",
]
