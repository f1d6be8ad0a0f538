"""The agent's TCP v4/v6 link: one stream per client, a 2-byte length before every message.

The link contract is in ``xrce.agent.links``.
"""

from __future__ import annotations

import asyncio
import socket

from xrce.agent.links import (DEFAULT_TCP_MAX_CONNECTIONS, MAX_MESSAGE_SIZE, MAX_PENDING_OUTPUT,
                              Link, log)
from xrce import EncodeError
from xrce.transports.framing import LengthPrefixDecoder, encode_length_prefixed



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



__all__ = ["TcpServer", "TcpConnection", "DEFAULT_TCP_MAX_CONNECTIONS"]
