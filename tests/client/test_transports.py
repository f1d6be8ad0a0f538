"""Client transports end to end over real loopback sockets, pty pairs and socketpairs."""

import os
import select
import socket
import time

import pytest

from xrce import EncodeError
from xrce.transports import TransportError
from xrce.transports.crc import crc16_x25
from xrce.transports.custom import CustomTransport
from xrce.transports.framing import FrameDecoder, encode_frame, encode_length_prefixed
from xrce.transports.serial import SerialTransport
from xrce.transports.tcp import TcpTransport
from xrce.transports.udp import UdpTransport

CREATE_CLIENT = bytes.fromhex("80000000000110005852434501000" "10FAABBCCDD8100FC01")
STATUS_AGENT = bytes.fromhex("8100000004010B000000585243450100010F00")
ACKNACK = bytes.fromhex("810000000A0105000100000080")
ESCAPED_KEY = bytes.fromhex("80000000000110005852434501000" "10F7E7D01028100FC01")


def timed_recv(transport, timeout_ms):
    start = time.monotonic()
    result = transport.recv(timeout_ms)
    return result, time.monotonic() - start


def assert_times_out(transport, timeout_ms=150):
    result, elapsed = timed_recv(transport, timeout_ms)
    assert result is None
    assert timeout_ms / 1000 - 0.02 <= elapsed < timeout_ms / 1000 + 0.5


# --- UDP ------------------------------------------------------------------------------------------


@pytest.fixture
def udp_agent():
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.settimeout(2)
    sock.bind(("127.0.0.1", 0))
    yield sock
    sock.close()


def test_udp_round_trip_and_counters(udp_agent):
    transport = UdpTransport("127.0.0.1", udp_agent.getsockname()[1])
    try:
        assert transport.mtu == 512
        assert transport.send(CREATE_CLIENT)
        data, client_address = udp_agent.recvfrom(2048)
        assert data == CREATE_CLIENT
        udp_agent.sendto(STATUS_AGENT, client_address)
        udp_agent.sendto(ACKNACK, client_address)
        assert transport.recv(1000) == STATUS_AGENT
        assert transport.recv(1000) == ACKNACK
        assert transport.sent == 1 and transport.received == 2
        assert_times_out(transport)
    finally:
        transport.close()


def test_udp_hears_only_the_agent_and_drops_oversize(udp_agent):
    transport = UdpTransport("127.0.0.1", udp_agent.getsockname()[1], mtu=64)
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        transport.send(ACKNACK)
        _, client_address = udp_agent.recvfrom(2048)
        stranger.sendto(b"not from the agent", client_address)
        udp_agent.sendto(bytes(65), client_address)
        udp_agent.sendto(bytes(64), client_address)
        assert transport.recv(1000) == bytes(64)
        assert transport.oversize == 1
        assert_times_out(transport, 100)
        with pytest.raises(EncodeError):
            transport.send(bytes(65))
    finally:
        stranger.close()
        transport.close()


def test_udp_keeps_waiting_when_no_agent_listens():
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()  # the port is now (almost certainly) closed: sends draw ICMP port unreachable
    transport = UdpTransport("127.0.0.1", port)
    try:
        transport.send(CREATE_CLIENT)
        assert_times_out(transport, 200)
        assert transport.refused >= 1
    finally:
        transport.close()


def ipv6_loopback_available():
    if not socket.has_ipv6:
        return False
    try:
        with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as sock:
            sock.bind(("::1", 0))
        return True
    except OSError:
        return False


@pytest.mark.skipif(not ipv6_loopback_available(), reason="no IPv6 loopback on this machine")
def test_udp_over_ipv6():
    agent = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
    agent.settimeout(2)
    agent.bind(("::1", 0))
    transport = UdpTransport("::1", agent.getsockname()[1], family=socket.AF_INET6)
    try:
        transport.send(ACKNACK)
        data, client_address = agent.recvfrom(2048)
        assert data == ACKNACK
        agent.sendto(STATUS_AGENT, client_address)
        assert transport.recv(1000) == STATUS_AGENT
    finally:
        transport.close()
        agent.close()


def test_udp_closed_transport_refuses_use(udp_agent):
    transport = UdpTransport("127.0.0.1", udp_agent.getsockname()[1])
    transport.close()
    transport.close()
    with pytest.raises(TransportError):
        transport.recv(10)
    with pytest.raises(TransportError):
        transport.send(ACKNACK)


# --- TCP ------------------------------------------------------------------------------------------


@pytest.fixture
def tcp_listener():
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    server.settimeout(2)
    yield server
    server.close()


def recv_exactly(sock, size):
    data = b""
    while len(data) < size:
        chunk = sock.recv(size - len(data))
        assert chunk, "peer closed early"
        data += chunk
    return data


def connect_tcp(listener, **kwargs):
    transport = TcpTransport("127.0.0.1", listener.getsockname()[1], **kwargs)
    agent_side, _ = listener.accept()
    agent_side.settimeout(2)
    return transport, agent_side


def test_tcp_round_trip_with_coalesced_and_split_segments(tcp_listener):
    transport, agent_side = connect_tcp(tcp_listener)
    try:
        assert transport.send(CREATE_CLIENT)
        assert recv_exactly(agent_side, 26) == b"\x18\x00" + CREATE_CLIENT
        # Two messages in one segment, then one split across two segments.
        agent_side.sendall(encode_length_prefixed(STATUS_AGENT) + encode_length_prefixed(ACKNACK))
        assert transport.recv(1000) == STATUS_AGENT
        assert transport.recv(1000) == ACKNACK
        third = encode_length_prefixed(ESCAPED_KEY)
        agent_side.sendall(third[:5])
        assert_times_out(transport, 100)
        agent_side.sendall(third[5:])
        assert transport.recv(1000) == ESCAPED_KEY
        assert transport.sent == 1 and transport.received == 3
        assert_times_out(transport)
    finally:
        transport.close()
        agent_side.close()


def test_tcp_bad_length_prefix_breaks_the_transport(tcp_listener):
    transport, agent_side = connect_tcp(tcp_listener, mtu=64)
    try:
        agent_side.sendall(b"\x41\x00" + bytes(65))  # 65 > mtu
        with pytest.raises(TransportError):
            transport.recv(1000)
        assert transport.decoder.oversize == 1
        with pytest.raises(TransportError):
            transport.recv(10)  # closed by the failure
    finally:
        transport.close()
        agent_side.close()


def test_tcp_send_refused_before_any_byte_is_counted_and_leaves_it_open(tcp_listener):
    transport, agent_side = connect_tcp(tcp_listener)
    try:
        # Linger 0: closing resets the connection, so the client's next send fails at its first byte.
        agent_side.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
        agent_side.close()
        assert select.select([transport._sock], [], [], 2)[0], "the reset never arrived"
        assert transport.send(ACKNACK) is False
        assert transport.send_errors == 1 and transport.sent == 0
        assert transport._sock is not None  # nothing of the message went out: the framing holds
    finally:
        transport.close()


def test_tcp_agent_closing_is_reported(tcp_listener):
    transport, agent_side = connect_tcp(tcp_listener)
    try:
        agent_side.sendall(encode_length_prefixed(ACKNACK))
        agent_side.close()
        assert transport.recv(1000) == ACKNACK
        with pytest.raises(TransportError):
            transport.recv(1000)
    finally:
        transport.close()


def test_tcp_connect_failure_raises():
    probe = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    with pytest.raises(TransportError):
        TcpTransport("127.0.0.1", port)


# --- Serial over a pty pair -----------------------------------------------------------------------


@pytest.fixture
def pty_pair():
    master, slave = os.openpty()
    path = os.ttyname(slave)
    transports = []

    def open_transport(**kwargs):
        transport = SerialTransport(path, **kwargs)
        transports.append(transport)
        return transport

    yield master, slave, open_transport
    for transport in transports:
        transport.close()
    os.close(slave)
    os.close(master)


def read_master(master, size, timeout_s=2.0):
    data = b""
    deadline = time.monotonic() + timeout_s
    while len(data) < size:
        remaining = deadline - time.monotonic()
        assert remaining > 0, "timed out reading the pty master: got %r" % data
        if select.select([master], [], [], remaining)[0]:
            data += os.read(master, size - len(data))
    return data


def test_serial_round_trip_over_a_pty(pty_pair):
    master, _, open_transport = pty_pair
    transport = open_transport()
    assert transport.send(CREATE_CLIENT)
    expected = encode_frame(CREATE_CLIENT, 1, 0)
    assert read_master(master, len(expected)) == expected
    assert expected[-2:] == b"\x3e\x8f"
    os.write(master, encode_frame(STATUS_AGENT, 0, 1))
    assert transport.recv(1000) == STATUS_AGENT
    # Two frames in one write, one with escapes: both come out, in order.
    os.write(master, encode_frame(ESCAPED_KEY, 0, 1) + encode_frame(ACKNACK, 0, 1))
    assert transport.recv(1000) == ESCAPED_KEY
    assert transport.recv(1000) == ACKNACK
    assert transport.sent == 1 and transport.received == 3
    assert_times_out(transport)


def test_serial_drops_frames_not_for_it_and_survives_noise(pty_pair):
    master, _, open_transport = pty_pair
    transport = open_transport()
    good = encode_frame(ACKNACK, 0, 1)
    os.write(
        master,
        b"\x00\x13garbage"
        + encode_frame(STATUS_AGENT, 0, 2)  # another client's frame
        + encode_frame(STATUS_AGENT, 5, 1)  # from someone other than the agent
        + good[:9]  # cut short: the next flag resyncs
        + good,
    )
    assert transport.recv(1000) == ACKNACK
    assert transport.decoder.wrong_address == 1
    assert transport.wrong_source == 1
    assert transport.decoder.resyncs == 1
    assert_times_out(transport, 100)


def test_serial_frame_trickling_in_byte_by_byte(pty_pair):
    master, _, open_transport = pty_pair
    transport = open_transport()
    frame = encode_frame(STATUS_AGENT, 0, 1)
    for byte in frame[:-1]:
        os.write(master, bytes((byte,)))
    assert transport.recv(50) is None
    os.write(master, frame[-1:])
    assert transport.recv(1000) == STATUS_AGENT


def test_serial_custom_addresses_and_ccitt_crc(pty_pair):
    master, _, open_transport = pty_pair
    transport = open_transport(local_addr=7, remote_addr=3, crc="ccitt", mtu=128)
    transport.send(ACKNACK)
    expected = encode_frame(ACKNACK, 7, 3, crc=crc16_x25)
    assert read_master(master, len(expected)) == expected
    os.write(master, encode_frame(STATUS_AGENT, 3, 7) + encode_frame(STATUS_AGENT, 3, 7, crc=crc16_x25))
    assert transport.recv(1000) == STATUS_AGENT
    assert transport.decoder.crc_errors == 1
    with pytest.raises(EncodeError):
        transport.send(bytes(129))


def test_serial_open_failure_raises():
    with pytest.raises(TransportError):
        SerialTransport("/dev/this-port-does-not-exist")


# --- Custom transport -----------------------------------------------------------------------------


class SocketCallbacks:
    """Custom-transport callbacks over one end of a socketpair, recording what they were asked."""

    def __init__(self, sock, max_write=None):
        self.sock = sock
        self.max_write = max_write
        self.opened = 0
        self.closed = 0
        self.write_sizes = []
        self.open_result = True

    def open(self, user):
        assert user is self
        self.opened += 1
        return self.open_result

    def close(self, user):
        self.closed += 1
        return True

    def write(self, user, data):
        if self.max_write is not None:
            data = data[: self.max_write]
        self.write_sizes.append(len(data))
        return user.sock.send(data)

    def read(self, user, buf, size, timeout_ms):
        user.sock.settimeout(max(timeout_ms, 0) / 1000)
        try:
            return user.sock.recv_into(buf, size)
        except (TimeoutError, BlockingIOError):
            return 0

    def transport(self, **kwargs):
        return CustomTransport(self.open, self.close, self.write, self.read, user=self, **kwargs)


@pytest.fixture
def stream_pair():
    client_end, agent_end = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    agent_end.settimeout(2)
    yield client_end, agent_end
    client_end.close()
    agent_end.close()


def test_custom_framed_round_trip_with_partial_writes(stream_pair):
    client_end, agent_end = stream_pair
    callbacks = SocketCallbacks(client_end, max_write=7)
    transport = callbacks.transport()
    try:
        assert callbacks.opened == 1
        assert transport.send(ESCAPED_KEY)
        expected = encode_frame(ESCAPED_KEY, 0, 0)
        assert sum(callbacks.write_sizes) == len(expected) and max(callbacks.write_sizes) == 7
        decoder = FrameDecoder(local_addr=0)
        assert decoder.feed(recv_exactly(agent_end, len(expected))) == [(0, 0, ESCAPED_KEY)]
        agent_end.sendall(encode_frame(STATUS_AGENT, 0, 0) + b"noise" + encode_frame(ACKNACK, 0, 0))
        assert transport.recv(1000) == STATUS_AGENT
        assert transport.recv(1000) == ACKNACK
        assert transport.decoder.dropped_bytes == 5
        assert_times_out(transport)
    finally:
        transport.close()
        transport.close()
    assert callbacks.closed == 1


def test_custom_framed_write_failure_is_reported(stream_pair):
    client_end, _ = stream_pair
    callbacks = SocketCallbacks(client_end, max_write=0)
    transport = callbacks.transport()
    try:
        assert transport.send(ACKNACK) is False
        assert transport.send_errors == 1 and transport.sent == 0
    finally:
        transport.close()


def test_custom_open_failure_raises(stream_pair):
    client_end, _ = stream_pair
    callbacks = SocketCallbacks(client_end)
    callbacks.open_result = False
    with pytest.raises(TransportError):
        callbacks.transport()
    assert callbacks.closed == 0


def test_custom_without_framing_over_a_datagram_pair():
    client_end, agent_end = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    agent_end.settimeout(2)
    callbacks = SocketCallbacks(client_end)
    transport = callbacks.transport(framing=False, mtu=64)
    try:
        assert transport.send(CREATE_CLIENT)
        assert callbacks.write_sizes == [len(CREATE_CLIENT)]
        assert agent_end.recv(2048) == CREATE_CLIENT  # the bare message, no frame
        agent_end.send(STATUS_AGENT)
        agent_end.send(bytes(65))
        agent_end.send(ACKNACK)
        assert transport.recv(1000) == STATUS_AGENT
        assert transport.recv(1000) == ACKNACK  # the oversize packet in between is dropped
        assert transport.oversize == 1
        assert_times_out(transport)
        with pytest.raises(EncodeError):
            transport.send(bytes(65))
    finally:
        transport.close()
        client_end.close()
        agent_end.close()
