"""Client auto-recovery: the agent is killed and restarted mid-stream and the application code —
a plain publish/spin loop — never notices; its data reaches ROS (and its reader gets data) again."""

import socket
import threading
import time

from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String as RosString

from agent_process import AgentProcess
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from xrce.client.session import Session
from xrce.msgs.std_msgs import String
from xrce.transports.udp import UdpTransport


def free_udp_port():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Publisher(threading.Thread):
    """An application loop: publish every 50 ms, spin in between. No recovery code of its own."""

    def __init__(self, port, domain_id, states):
        super().__init__(daemon=True)
        self.session = Session(UdpTransport("127.0.0.1", port), history=8,
                               on_link_state=lambda s, state: states.append((time.monotonic(), state)))
        assert self.session.create(attempts=5, timeout_ms=500)
        node = self.session.create_participant(domain_id=domain_id, name="recovering_mcu")
        self.writer = self.session.create_writer(node, "/survives", String, reliable=False)
        assert self.session.run_until_all_status(5000)
        self.count = 0
        self.stop = threading.Event()

    def run(self):
        while not self.stop.is_set():
            self.count += 1
            self.session.write(self.writer, String(data="n%d" % self.count), stream_id=self.session.best_effort)
            deadline = time.monotonic() + 0.05
            while time.monotonic() < deadline:
                self.session.spin_once(10)

    def close(self):
        self.stop.set()
        self.join(5)
        self.session.close()


def test_agent_restart_mid_stream_reaches_ros_again_within_2s(ros_peer, ros_domain):  # noqa: F811
    received = []
    best_effort = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
    ros_peer.node.create_subscription(RosString, "/survives", lambda m: received.append((time.monotonic(), m.data)),
                                      best_effort)
    port = free_udp_port()
    states = []
    agent = AgentProcess("udp4", "-p", str(port), "-m", "dds").__enter__()
    publisher = None
    try:
        publisher = Publisher(port, ros_domain, states)
        publisher.start()
        assert wait_until(lambda: len(received) >= 5, 15)
        agent.proc.kill()  # a crash, not a clean shutdown
        agent.proc.wait(10)
        time.sleep(1.0)  # the robot keeps publishing into the void meanwhile
        before = len(received)
        agent = AgentProcess("udp4", "-p", str(port), "-m", "dds").__enter__()
        restarted = time.monotonic()
        assert wait_until(lambda: len(received) > before + 3, 15), states
        first_after = received[before][0]
        reconnected = [t for t, s in states if s == "connected"][-1]
        print("session back %.3f s after the restart, data in ROS after %.3f s"
              % (reconnected - restarted, first_after - restarted))
        # Ours: the session, its entities and the data flow are back within 2 s. What follows is
        # DDS discovery of the new agent's participant by the subscriber, which is Fast DDS's
        # (usually 0.1-0.5 s here, seconds on a loaded machine); it gets a generous bound.
        assert reconnected - restarted < 2.0, states
        assert first_after - restarted < 10.0
        assert [s for _, s in states][-1] == "connected" and "lost" in [s for _, s in states]
        assert publisher.session.link.recoveries == 1
    finally:
        if publisher is not None:
            publisher.close()
        agent.stop()


class WriterAndReader:
    """Two client sessions on one agent (middleware ced): one writes /x, the other reads it."""

    def __init__(self, writer_transport, port, **writer_options):
        self.writer_session = Session(writer_transport, history=8, **writer_options)
        self.reader_session = Session(UdpTransport("127.0.0.1", port), history=8)
        self.got = []
        for session in (self.writer_session, self.reader_session):
            assert session.create(attempts=5, timeout_ms=500)
        self.writer = self.writer_session.create_writer(
            self.writer_session.create_participant(name="w"), "/x", String)
        self.reader_session.create_reader(self.reader_session.create_participant(name="r"), "/x",
                                          String, self.got.append)
        assert self.writer_session.run_until_all_status(2000) and \
            self.reader_session.run_until_all_status(2000)

    def exchange(self, tag, seconds):
        """Writes ``tag`` until the reader has it; True if it did within ``seconds``."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and not any(m.data == tag for m in self.got):
            self.writer_session.write(self.writer, String(data=tag))
            self.writer_session.spin_once(20)
            self.reader_session.spin_once(20)
        return any(m.data == tag for m in self.got)

    def close(self):
        self.writer_session.close()
        self.reader_session.close()


def test_reader_and_writer_resume_after_agent_restart_without_ros():
    port = free_udp_port()
    agent = AgentProcess("udp4", "-p", str(port), "-m", "ced").__enter__()
    try:
        pair = WriterAndReader(UdpTransport("127.0.0.1", port), port)
        assert pair.exchange("before", 5)
        agent.stop()
        agent = AgentProcess("udp4", "-p", str(port), "-m", "ced").__enter__()
        # The clients notice the restart, recover and exchange again: seconds on a loaded machine
        # (5 s was passed once in a suite beside other work); the bound is a hang's, not speed's.
        assert pair.exchange("after", 20)
        assert pair.writer_session.link.recoveries == 1 and pair.reader_session.link.recoveries == 1
        pair.close()
    finally:
        agent.stop()


class RecordingUdp(UdpTransport):
    """The client's UDP transport, keeping (time, datagram) of everything it sends."""

    def __init__(self, *args):
        super().__init__(*args)
        self.record = []

    def send_from(self, buf, length):  # send() comes here too
        self.record.append((time.monotonic(), bytes(memoryview(buf)[:length])))
        return super().send_from(buf, length)


def test_a_lost_link_sends_nothing_of_the_old_session_and_the_new_one_starts_at_zero():
    # A loaded CI machine once caught this: the writer's HEARTBEAT for samples written just before
    # the agent died reached the restarted agent right after it accepted the session again, the
    # agent's fresh reliable stream moved past the re-creations that followed, and the writer
    # never came back. Here the window is held open on purpose: samples written while the agent
    # is down, the link lost for a second before the agent returns.
    port = free_udp_port()
    states = []
    agent = AgentProcess("udp4", "-p", str(port), "-m", "ced").__enter__()
    try:
        transport = RecordingUdp("127.0.0.1", port)
        pair = WriterAndReader(transport, port, on_link_state=lambda s, state: states.append(
            (time.monotonic(), state)))
        writer_session, writer = pair.writer_session, pair.writer
        assert pair.exchange("before", 5)
        agent.stop()
        for n in range(5):  # reliable samples the stopped agent never acknowledges
            assert writer_session.write(writer, String(data="unheard %d" % n))
        deadline = time.monotonic() + 20
        while "lost" not in [state for _, state in states] and time.monotonic() < deadline:
            writer_session.spin_once(20)
        assert "lost" in [state for _, state in states], states
        lost_at = [t for t, state in states if state == "lost"][0]
        writer_session.run_until_timeout(1000)  # lost: CREATE_CLIENT every retry_ms meanwhile
        agent = AgentProcess("udp4", "-p", str(port), "-m", "ced").__enter__()
        assert pair.exchange("after", 20), states
        reconnected_at = [t for t, state in states if state == "connected"][-1]

        # While lost: CREATE_CLIENT only (session 0x80, submessage 0x00), then the re-creations,
        # which start the reliable stream (0x80) at sequence number 0, nothing in between: no
        # HEARTBEAT or message that names a sequence number of the old session's.
        window = [data for t, data in transport.record if lost_at <= t <= reconnected_at]
        creates_client = [data[0] == 0x80 and data[4] == 0x00 for data in window]
        assert False in creates_client, [data.hex() for data in window]
        restore = window[creates_client.index(False):]
        assert [(data[1], int.from_bytes(data[2:4], "little")) for data in restore] == \
            [(0x80, seq) for seq in range(len(restore))], [data.hex() for data in window]
        assert restore[0][4] == 0x01, restore[0].hex()  # CREATE
        assert writer_session.link.recoveries == 1
        pair.close()
    finally:
        agent.stop()
