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


def test_reader_and_writer_resume_after_agent_restart_without_ros():
    port = free_udp_port()
    agent = AgentProcess("udp4", "-p", str(port), "-m", "ced").__enter__()
    try:
        writer_session = Session(UdpTransport("127.0.0.1", port), history=8)
        reader_session = Session(UdpTransport("127.0.0.1", port), history=8)
        got = []
        for session in (writer_session, reader_session):
            assert session.create(attempts=5, timeout_ms=500)
        writer = writer_session.create_writer(writer_session.create_participant(name="w"), "/x", String)
        reader_session.create_reader(reader_session.create_participant(name="r"), "/x", String, got.append)
        assert writer_session.run_until_all_status(2000) and reader_session.run_until_all_status(2000)

        def exchange(tag, seconds):
            deadline = time.monotonic() + seconds
            while time.monotonic() < deadline and not any(m.data == tag for m in got):
                writer_session.write(writer, String(data=tag))
                writer_session.spin_once(20)
                reader_session.spin_once(20)
            return any(m.data == tag for m in got)

        assert exchange("before", 5)
        agent.stop()
        agent = AgentProcess("udp4", "-p", str(port), "-m", "ced").__enter__()
        # The clients notice the restart, recover and exchange again: seconds on a loaded machine
        # (5 s was passed once in a suite beside other work); the bound is a hang's, not speed's.
        assert exchange("after", 20)
        assert writer_session.link.recoveries == 1 and reader_session.link.recoveries == 1
        writer_session.close()
        reader_session.close()
    finally:
        agent.stop()
