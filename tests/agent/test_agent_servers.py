"""The agent's transport servers over real loopback sockets and pty pairs, with a fake engine."""

import asyncio
import os
import socket
import struct
import termios
import tty

import pytest

from xrce.wire import constants as C
from xrce.agent.links import serial as serial_links, tcp as tcp_links, udp as udp_links
from xrce.wire.submessages import GetInfo, Info, Locator, decode_message, encode_message
from xrce.transports.crc import crc16_x25
from xrce.transports.framing import (
    FrameDecoder,
    LengthPrefixDecoder,
    encode_frame,
    encode_length_prefixed,
)

TIMEOUT = 5.0


class EchoEngine:
    """Records every message and answers each with b"re:" + message on the same endpoint."""

    def __init__(self, fail_on=None):
        self.received = []
        self.closed_endpoints = []
        self.fail_on = fail_on
        self.arrived = asyncio.Event()

    def receive(self, link, endpoint, data):
        self.received.append((endpoint, data))
        self.arrived.set()
        if self.fail_on is not None and data == self.fail_on:
            raise RuntimeError("engine bug")
        link.send(endpoint, b"re:" + data)

    def endpoint_closed(self, link, endpoint):
        self.closed_endpoints.append(endpoint)

    async def wait_for(self, count):
        async def until():
            while len(self.received) < count:
                self.arrived.clear()
                await self.arrived.wait()
        await asyncio.wait_for(until(), TIMEOUT)


async def wait_until(predicate):
    async def poll():
        while not predicate():
            await asyncio.sleep(0.01)
    await asyncio.wait_for(poll(), TIMEOUT)


# ------------------------------------------------------------------------------------------ UDP

async def _udp_roundtrip(family, host):
    engine = EchoEngine(fail_on=b"boom")
    server = udp_links.UdpServer(engine, 0, family=family, host=host)
    await server.start()
    loop = asyncio.get_running_loop()
    client = socket.socket(family, socket.SOCK_DGRAM)
    client.setblocking(False)
    try:
        client.connect((host, server.port))
        big = bytes(range(256)) * 234  # 59904 bytes: one datagram, one message
        for message in (b"first", b"boom", big, b"last"):
            client.send(message)
        replies = []
        for _ in range(3):  # "boom" makes the engine raise: no reply, one drop
            replies.append(await asyncio.wait_for(loop.sock_recv(client, 70000), TIMEOUT))
        assert replies == [b"re:first", b"re:" + big, b"re:last"]
        assert [data for _, data in engine.received] == [b"first", b"boom", big, b"last"]
        endpoint = engine.received[0][0]
        assert endpoint[:2] == client.getsockname()[:2]
        stats = server.stats
        assert stats.messages_in == 4 and stats.messages_out == 3 and stats.drops == 1
        assert stats.bytes_in == 5 + 4 + len(big) + 4
        assert stats.bytes_out == sum(len(r) for r in replies)
    finally:
        client.close()
        await server.close()
    assert not server.send(endpoint, b"after close")


async def test_udp4_delivers_whole_datagrams_and_replies_to_the_source():
    await _udp_roundtrip(socket.AF_INET, "127.0.0.1")


async def test_udp6_delivers_whole_datagrams_and_replies_to_the_source():
    if not socket.has_ipv6:
        pytest.skip("no IPv6")
    try:
        probe = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
        probe.bind(("::1", 0))
        probe.close()
    except OSError:
        pytest.skip("no IPv6 loopback")
    await _udp_roundtrip(socket.AF_INET6, "::1")


async def test_udp_send_to_an_unreachable_address_is_a_counted_drop():
    engine = EchoEngine()
    server = udp_links.UdpServer(engine, 0, host="127.0.0.1")
    await server.start()
    try:
        assert not server.send(("not an address",), b"x")
        assert server.stats.drops == 1 and server.stats.messages_out == 0
    finally:
        await server.close()


# ------------------------------------------------------------------------------------------ TCP

async def _read_messages(reader, decoder, count):
    messages = []
    while len(messages) < count:
        chunk = await asyncio.wait_for(reader.read(4096), TIMEOUT)
        if not chunk:
            raise ConnectionError("closed after %d messages" % len(messages))
        messages.extend(decoder.feed(chunk))
    return messages


async def test_tcp_serves_concurrent_connections_with_partial_writes():
    engine = EchoEngine()
    server = tcp_links.TcpServer(engine, 0, host="127.0.0.1")
    await server.start()
    streams = []
    try:
        for _ in range(6):
            streams.append(await asyncio.open_connection("127.0.0.1", server.port))

        async def converse(index, reader, writer):
            messages = [b"client%d-message%d" % (index, n) * (n + 1) for n in range(5)]
            wire = b"".join(encode_length_prefixed(m) for m in messages)
            # Split the stream everywhere, including inside the 2-byte length prefix.
            step = index + 1
            for start in range(0, len(wire), step):
                writer.write(wire[start:start + step])
                await writer.drain()
                await asyncio.sleep(0)
            replies = await _read_messages(reader, LengthPrefixDecoder(), len(messages))
            assert replies == [b"re:" + m for m in messages]

        await asyncio.gather(*(converse(i, r, w) for i, (r, w) in enumerate(streams)))
        endpoints = {endpoint for endpoint, _ in engine.received}
        assert len(endpoints) == 6 and len(server.connections) == 6
        assert all(isinstance(e, tcp_links.TcpConnection) for e in endpoints)
        assert server.stats.messages_in == 30 and server.stats.messages_out == 30
    finally:
        for _, writer in streams:
            writer.close()
        await server.close()


async def test_tcp_corrupt_length_closes_only_that_connection():
    engine = EchoEngine()
    server = tcp_links.TcpServer(engine, 0, host="127.0.0.1")
    await server.start()
    good_reader, good_writer = await asyncio.open_connection("127.0.0.1", server.port)
    bad_reader, bad_writer = await asyncio.open_connection("127.0.0.1", server.port)
    try:
        good_writer.write(encode_length_prefixed(b"hello"))
        bad_writer.write(encode_length_prefixed(b"fine"))
        await engine.wait_for(2)
        bad_endpoint = next(e for e, d in engine.received if d == b"fine")
        bad_writer.write(b"\x00\x00garbage")  # a zero length: the stream has lost sync
        await bad_writer.drain()
        assert await _read_messages(bad_reader, LengthPrefixDecoder(), 1) == [b"re:fine"]
        assert await asyncio.wait_for(bad_reader.read(100), TIMEOUT) == b""  # closed by the agent
        await wait_until(lambda: engine.closed_endpoints == [bad_endpoint])
        assert server.stats.drops == 1 and len(server.connections) == 1

        good_writer.write(encode_length_prefixed(b"still here"))
        replies = await _read_messages(good_reader, LengthPrefixDecoder(), 2)
        assert replies == [b"re:hello", b"re:still here"]
        assert not server.send(bad_endpoint, b"to a closed connection")
    finally:
        good_writer.close()
        bad_writer.close()
        await server.close()


async def test_tcp_connections_beyond_the_cap_are_refused():
    engine = EchoEngine()
    server = tcp_links.TcpServer(engine, 0, host="127.0.0.1", max_connections=2)
    await server.start()
    streams = []
    try:
        for _ in range(3):
            streams.append(await asyncio.open_connection("127.0.0.1", server.port))
        extra_reader, _ = streams[2]
        assert await asyncio.wait_for(extra_reader.read(10), TIMEOUT) == b""
        assert server.rejected_connections == 1 and len(server.connections) == 2
        reader, writer = streams[0]
        writer.write(encode_length_prefixed(b"ok"))
        assert await _read_messages(reader, LengthPrefixDecoder(), 1) == [b"re:ok"]
        # Once a slot frees up, a new client gets in.
        streams[1][1].close()
        await wait_until(lambda: len(server.connections) == 1)
        streams.append(await asyncio.open_connection("127.0.0.1", server.port))
        reader, writer = streams[-1]
        writer.write(encode_length_prefixed(b"later"))
        assert await _read_messages(reader, LengthPrefixDecoder(), 1) == [b"re:later"]
    finally:
        for _, writer in streams:
            writer.close()
        await server.close()


# ---------------------------------------------------------------------------- serial and pty

class PtyPeer:
    """The client end of a serial line in a test: an fd read and written through the loop."""

    def __init__(self, fd, crc=None):
        self.fd = fd
        self.decoder = FrameDecoder(crc=crc) if crc else FrameDecoder()
        os.set_blocking(fd, False)

    def write(self, data):
        """Small writes that fit the pty buffer."""
        assert os.write(self.fd, data) == len(data)

    async def write_all(self, data):
        """Writes of any size, waiting for the agent to drain the pty."""
        loop = asyncio.get_running_loop()
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(self.fd, view):]
            except BlockingIOError:
                writable = loop.create_future()
                loop.add_writer(self.fd, writable.set_result, None)
                try:
                    await asyncio.wait_for(writable, TIMEOUT)
                finally:
                    loop.remove_writer(self.fd)

    async def frames(self, count):
        loop = asyncio.get_running_loop()
        got = []
        readable = asyncio.Event()
        loop.add_reader(self.fd, readable.set)
        try:
            async def collect():
                while len(got) < count:
                    await readable.wait()
                    readable.clear()
                    try:
                        got.extend(self.decoder.feed(os.read(self.fd, 4096)))
                    except BlockingIOError:
                        pass
            await asyncio.wait_for(collect(), TIMEOUT)
        finally:
            loop.remove_reader(self.fd)
        return got


async def test_serial_delivers_frames_and_drops_bad_crc(pty_pair):
    master, slave_path = pty_pair()
    engine = EchoEngine()
    server = serial_links.SerialServer(engine, slave_path, baudrate=115200)
    await server.start()
    peer = PtyPeer(master)
    try:
        good = encode_frame(b"\x80\x00\x00\x00hello", 1, 0)
        bad = bytearray(encode_frame(b"\x80\x00\x00\x00corrupt", 1, 0))
        bad[-1] ^= 0xFF
        other_address = encode_frame(b"from three", 3, 0)
        not_for_agent = encode_frame(b"for someone else", 1, 5)
        # Byte-by-byte chunks for the first frame, then everything else in one write.
        for byte in good:
            peer.write(bytes((byte,)))
        peer.write(bytes(bad) + not_for_agent + other_address)
        frames = await peer.frames(2)
        assert frames == [(0, 1, b"re:\x80\x00\x00\x00hello"), (0, 3, b"re:from three")]
        assert [e for e, _ in engine.received] == [(slave_path, 1), (slave_path, 3)]
        assert server.stats.drops == 2  # bad CRC + wrong destination
        port = server.ports[slave_path]
        assert port.decoder.crc_errors == 1 and port.decoder.wrong_address == 1
        assert server.stats.messages_in == 2 and server.stats.messages_out == 2
        assert server.stats.bytes_in == len(good) + len(bad) + len(not_for_agent) + len(other_address)
    finally:
        await server.close()
    assert not server.send((slave_path, 1), b"after close")


async def test_serial_ccitt_crc_and_a_large_message(pty_pair):
    master, slave_path = pty_pair()
    engine = EchoEngine()
    server = serial_links.SerialServer(engine, [slave_path], crc="ccitt")
    await server.start()
    peer = PtyPeer(master, crc=crc16_x25)
    try:
        # 0x7E/0x7D everywhere: escaping doubles the frame; far beyond the pty's buffer.
        big = bytes([0x7E, 0x7D, 0x01]) * 6000
        _, frames = await asyncio.gather(peer.write_all(encode_frame(big, 0, 0, crc=crc16_x25)),
                                         peer.frames(1))
        assert frames == [(0, 0, b"re:" + big)]
        assert server.ports[slave_path].decoder.crc_errors == 0
    finally:
        await server.close()


async def test_multiserial_keeps_ports_apart(pty_pair):
    (master_a, path_a), (master_b, path_b) = pty_pair(), pty_pair()
    engine = EchoEngine()
    server = serial_links.SerialServer(engine, [path_a, path_b])
    await server.start()
    assert server.name == "multiserial"
    peer_a, peer_b = PtyPeer(master_a), PtyPeer(master_b)
    try:
        peer_a.write(encode_frame(b"to a", 1, 0))
        peer_b.write(encode_frame(b"to b", 1, 0))
        assert await peer_a.frames(1) == [(0, 1, b"re:to a")]
        assert await peer_b.frames(1) == [(0, 1, b"re:to b")]
        assert sorted(e for e, _ in engine.received) == sorted([(path_a, 1), (path_b, 1)])
    finally:
        await server.close()


async def test_serial_open_failure_is_an_oserror(tmp_path):
    not_a_tty = tmp_path / "not-a-tty"
    not_a_tty.write_bytes(b"")
    server = serial_links.SerialServer(EchoEngine(), str(not_a_tty))
    with pytest.raises(OSError, match="not-a-tty"):
        await server.start()


async def test_a_serial_device_not_there_yet_is_waited_for(tmp_path):
    """As eProsima's agent: no device at start is not an error; it is tried until it appears."""
    server = serial_links.SerialServer(EchoEngine(), str(tmp_path / "no-such-tty"), reopen_interval=0.05)
    await server.start()
    try:
        await asyncio.sleep(0.2)
        assert server.ports == {} and list(server._reopen_tasks) == [str(tmp_path / "no-such-tty")]
    finally:
        await server.close()
    assert server._reopen_tasks == {}


async def test_pseudoterminal_serves_its_slave_and_manages_the_symlink(tmp_path):
    link_path = str(tmp_path / "xrce_pty")
    os.symlink("/dev/null", link_path)  # a stale link from an earlier run is replaced
    engine = EchoEngine()
    server = serial_links.PseudoterminalServer(engine, symlink=link_path)
    await server.start()
    fd = None
    try:
        assert os.readlink(link_path) == server.slave_path
        assert server.describe().startswith("pseudoterminal at /dev/")
        fd = os.open(link_path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(fd, termios.TCSANOW)
        peer = PtyPeer(fd)
        peer.write(encode_frame(b"over the pty", 1, 0))
        assert await peer.frames(1) == [(0, 1, b"re:over the pty")]
        assert engine.received == [((server.slave_path, 1), b"over the pty")]
    finally:
        if fd is not None:
            os.close(fd)
        await server.close()
    assert not os.path.lexists(link_path)


# ------------------------------------------------------------------------------------ discovery

def _get_info(request_id=C.REQUEST_ID_DISCOVERY):
    return encode_message(0x80, 0, 0, None, [GetInfo(request_id, C.OBJECTID_AGENT, 0x03)])


async def test_discovery_answers_get_info_with_every_local_ipv4_address():
    server = udp_links.DiscoveryServer(agent_port=2022, port=0)
    await server.start()
    loop = asyncio.get_running_loop()
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client.setblocking(False)
    try:
        client.connect(("127.0.0.1", server.port))
        client.send(b"\x80\x00")  # malformed: counted, no answer
        client.send(_get_info())
        reply = await asyncio.wait_for(loop.sock_recv(client, 2048), TIMEOUT)
        header, payloads = decode_message(reply)
        assert (header.session_id, header.stream_id, header.seq) == (0x80, 0, 0)
        (info,) = payloads
        assert isinstance(info, Info) and info.request_id == C.REQUEST_ID_DISCOVERY
        assert info.availability == 1 and info.config[1] == b"\x01\x00"
        assert Locator(C.LOCATOR_MEDIUM, socket.inet_aton("127.0.0.1"), 2022) in info.locators
        assert len(info.locators) == len(udp_links.local_ipv4_addresses())
        assert server.stats.drops == 1 and server.stats.messages_out == 1
    finally:
        client.close()
        await server.close()


async def test_discovery_reply_matches_the_verified_capture():
    # XRCE-WIRE.md §10: agent on UDP port 2022 with interfaces 127.0.0.1 and 192.0.2.2.
    expected = bytes.fromhex(
        "80000000 06012C00 0009FFFD 0000010D 58524345 0100010F 00010D00 01000000"
        "02000000 017F0000 0100E607 01C00002 0200E607")

    class TwoInterfaces(udp_links.DiscoveryServer):
        def discovery_locators(self):
            return [Locator(C.LOCATOR_MEDIUM, bytes(a), self.agent_port)
                    for a in ((127, 0, 0, 1), (192, 0, 2, 2))]

    server = TwoInterfaces(agent_port=2022, port=0)
    await server.start()
    loop = asyncio.get_running_loop()
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client.setblocking(False)
    try:
        client.connect(("127.0.0.1", server.port))
        client.send(_get_info())
        assert await asyncio.wait_for(loop.sock_recv(client, 2048), TIMEOUT) == expected
    finally:
        client.close()
        await server.close()


needs_ipv6 = pytest.mark.skipif(socket.inet_pton(socket.AF_INET6, "::1")
                                not in udp_links.local_ipv6_addresses(),
                                reason="this host has no IPv6 loopback address")


@needs_ipv6
async def test_discovery_for_an_ipv6_agent_answers_ipv6_locators_on_either_family():
    """eProsima's udp6/tcp6 agent answers discovery with LARGE locators of its IPv6 addresses: an
    IPv4 locator is one a client of an IPv6 agent cannot use. Asked over IPv6 too (dual stack)."""
    server = udp_links.DiscoveryServer(agent_port=2022, port=0, family=socket.AF_INET6)
    await server.start()
    loop = asyncio.get_running_loop()
    try:
        for family, host in ((socket.AF_INET, "127.0.0.1"), (socket.AF_INET6, "::1")):
            with socket.socket(family, socket.SOCK_DGRAM) as client:
                client.setblocking(False)
                client.connect((host, server.port))
                client.send(_get_info())
                reply = await asyncio.wait_for(loop.sock_recv(client, 2048), TIMEOUT)
            _, (info,) = decode_message(reply)
            assert Locator(C.LOCATOR_LARGE, socket.inet_pton(socket.AF_INET6, "::1"), 2022) \
                in info.locators, family
            assert {loc.fmt for loc in info.locators} == {C.LOCATOR_LARGE}
            assert len(info.locators) == len(udp_links.local_ipv6_addresses())
        assert server.stats.messages_out == 2
    finally:
        await server.close()


def test_an_ipv6_large_locator_has_the_bytes_eprosima_sends():
    # TransportLocator LARGE: kind 02, 16 address bytes, then the uint32 port aligned to 4.
    from xrce.wire.cdr import CdrWriter
    w = CdrWriter()
    Locator(C.LOCATOR_LARGE, socket.inet_pton(socket.AF_INET6, "::1"), 2022).encode(w)
    assert w.getvalue() == bytes.fromhex("02" + "00" * 15 + "01" + "000000" + "E6070000")


def test_local_ipv4_addresses_include_loopback():
    addresses = udp_links.local_ipv4_addresses()
    assert socket.inet_aton("127.0.0.1") in addresses
    assert all(len(a) == 4 for a in addresses)
    assert len(set(addresses)) == len(addresses)
    assert struct.calcsize("4s") == 4
