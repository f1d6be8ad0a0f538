"""SerialTransport over any byte stream (issue 44): a port without machine.UART, or a USB CDC
stream, hands it an object with only the calls the transport documents: any(), readinto(buf, n),
write(buf, off, n). Here such an object drives the pseudoterminal of a real ``xrce-agent`` from
CPython, through the same code path a board's UART object takes (the MicroPython side of it is
tests/board/test_micropython_transport_heap.py's PortUart and the bare-metal board's UART)."""

import os
import select
import termios
import tty

import pytest

from agent_process import AgentProcess
from xrce.client import Session
from xrce.client.ping import ping_agent
from xrce.msgs.std_msgs import String
from xrce.transports.serial import SerialTransport


class StreamOnly:
    """The three calls, and nothing else: an attribute the transport reached for beyond them would
    raise AttributeError."""

    __slots__ = ("_fd", "calls")

    def __init__(self, path):
        self._fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        tty.setraw(self._fd)
        attrs = termios.tcgetattr(self._fd)
        attrs[4] = attrs[5] = termios.B115200
        termios.tcsetattr(self._fd, termios.TCSANOW, attrs)
        self.calls = {"any": 0, "readinto": 0, "write": 0}

    def any(self):
        self.calls["any"] += 1
        return 1 if select.select([self._fd], [], [], 0)[0] else 0

    def readinto(self, buf, n):
        self.calls["readinto"] += 1
        assert 0 < n <= len(buf)
        try:
            data = os.read(self._fd, n)
        except BlockingIOError:
            return 0
        buf[: len(data)] = data
        return len(data)

    def write(self, buf, off, n):
        self.calls["write"] += 1
        try:
            return os.write(self._fd, memoryview(buf)[off:off + n])
        except BlockingIOError:
            return None  # full: the transport offers it again

    def close_fd(self):
        os.close(self._fd)


@pytest.mark.timeout(60)
def test_serial_transport_over_a_stream_object_pings_and_publishes_through_the_agent():
    with AgentProcess("pseudoterminal", "-m", "ced") as agent:
        stream = StreamOnly(agent.device)
        try:
            transport = SerialTransport(stream)
            assert ping_agent(transport, 1000, 5) is not None
            session = Session(transport, key=b"\x53\x54\x52\x4d")
            assert session.create(attempts=5)
            node = session.create_participant(name="stream_board")
            writer = session.create_writer(node, "/chatter", String, reliable=True)
            received = []
            session.create_reader(node, "/chatter", String, lambda m: received.append(m.data))
            assert session.run_until_all_status(2000), session.last_statuses
            for i in range(5):
                assert session.write(writer, String(data="over a stream %d" % i))
            assert session.run_until_confirm_delivery(3000)
            session.run_until_timeout(500)
            assert received == ["over a stream %d" % i for i in range(5)]
            session.delete()
            transport.close()
        finally:
            stream.close_fd()
    assert stream.calls["write"] > 0 and stream.calls["readinto"] > 0 and stream.calls["any"] > 0


def test_a_stream_objects_deinit_is_left_to_its_owner():
    class Owned:
        def any(self):
            return 0

        def readinto(self, buf, n):
            return 0

        def write(self, buf, off, n):
            return n

        def deinit(self):
            raise AssertionError("the transport made no UART: closing it is its owner's business")

    transport = SerialTransport(Owned())
    assert transport.send(b"\x81\x00\x00\x00")
    assert transport.recv(0) is None
    transport.close()
