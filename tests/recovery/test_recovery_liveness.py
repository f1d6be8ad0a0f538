"""When the agent deletes a client ("Recovery and liveliness" in docs/ARCHITECTURE.md), against
real agent processes, real sockets and pty pairs, and the ROS graph as rclpy sees it:

- replaced at once: a new key from the same UDP address and port (a firmware with a fixed local
  port), or through a serial device closed and opened again (a USB board re-enumerating): the old
  client's publisher leaves the ROS graph long before any dead time (set to 2 minutes here);
- retired: a new key from the same host and another port (rmw_microxrcedds after a reboot) that
  creates the same node retires the silent old client once it has been dead, while a neighbour
  that speaks, and a silent one that is another node, stay; 100 reconnections under new keys
  leave one publisher in the graph;
- expiry: ``--client-expire-time 3000`` deletes a silent client 3 s after its last message (it
  took 30 s, the dead time, before);
- sleepers: a client silent for many dead times keeps its session and publishes when it wakes; one
  whose session was taken from it gets it back by pinging (``auto_recover``);
- recorded micro-ROS firmware (golden restart.jsonl) booting again under a new key: its first
  life is retired (rmw_microxrcedds creates the same participant).

Each board is a ``Session`` of this project's client on its own socket; boards of "different
hosts" send from different loopback addresses (127.0.0.x). The only durations asserted are
"not before" bounds that load cannot break, and the expiry's upper bound, which is the feature
(with a margin for a loaded machine).
"""

import re
import socket
import time
from pathlib import Path

from agent_process import AgentProcess
from microros_replay import Capture, Replayer, UdpChannel
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from test_recovery_agent import PtyDevice
from xrce.wire import constants as C
from xrce.client.session import Session
from xrce.msgs.std_msgs import String
from xrce.transports.udp import UdpTransport

INTERFACES = Path(__file__).resolve().parents[1] / "interfaces"  # turtlebot3_msgs for the captures
LONG_DEAD_TIME_MS = "120000"  # no dead time passes during a test: only replacement can act


class BoundUdpTransport(UdpTransport):
    """A board's UDP socket sent from a chosen address and port: a firmware that binds a fixed
    local port, or a board with an address of its own (127.0.0.x are all this machine)."""

    __slots__ = ("source",)

    def __init__(self, agent_port, source):
        self.source = source
        super().__init__("127.0.0.1", agent_port)

    def open(self):
        if self._sock is not None:
            return
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(self.source)
        sock.connect((self.host, self.port))
        self._sock, self._poller = sock, None


def free_udp_port(address="127.0.0.1"):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind((address, 0))
        return sock.getsockname()[1]


def board(transport, key, domain_id, node, topic, **options):
    """A board that creates its node and one publisher, as a micro-ROS firmware does at start."""
    options.setdefault("auto_recover", False)
    session = Session(transport, key=key, history=8, **options)
    assert session.create(attempts=10, timeout_ms=1000)
    participant = session.create_participant(domain_id=domain_id, name=node)
    writer = session.create_writer(participant, topic, String)
    assert session.run_until_all_status(20000), session.last_statuses  # a loaded machine
    return session, writer


def publishers(ros_peer, topic):  # noqa: F811
    return ros_peer.node.count_publishers(topic)


def wait_for_log_lines(agent, pattern, count, timeout):
    """Read the running agent's log until ``count`` distinct lines of all it logged match
    ``pattern`` (or the timeout); returns how many did. What is read stays in ``agent.output``."""
    matching = re.compile(r"^.*(?:%s).*$" % pattern, re.M)
    deadline = time.monotonic() + timeout
    while True:
        agent.drain()
        seen = len(set(matching.findall("".join(agent.output))))
        if seen >= count or time.monotonic() > deadline or agent.proc.poll() is not None:
            return seen
        time.sleep(0.2)


def agent_log(agent):
    assert agent.stop() == 0
    return "".join(agent.output)


def test_a_new_key_from_the_same_udp_address_and_port_replaces_the_old_client(
        ros_peer, ros_domain):  # noqa: F811
    with AgentProcess("udp4", "-m", "dds", "--client-dead-time", LONG_DEAD_TIME_MS) as agent:
        source = ("127.0.0.1", free_udp_port())
        first, _ = board(BoundUdpTransport(agent.port, source), 0x0F1E0001, ros_domain,
                         "fixed_port_fw", "/fixed_port_first")
        assert wait_until(lambda: publishers(ros_peer, "/fixed_port_first") == 1, 20)
        first.close()  # power lost: no DELETE; the board boots under a new rand() key
        second, _ = board(BoundUdpTransport(agent.port, source), 0x0F1E0002, ros_domain,
                          "fixed_port_fw", "/fixed_port_second")
        try:
            assert wait_until(lambda: publishers(ros_peer, "/fixed_port_second") == 1, 20)
            # Gone from the graph with no dead time passed (2 minutes): replaced, not retired.
            assert wait_until(lambda: publishers(ros_peer, "/fixed_port_first") == 0, 20)
        finally:
            second.close()
        log = agent_log(agent)
    assert "client 0f1e0001 replaced by client 0f1e0002" in log, log
    assert "retired" not in log and "expired" not in log


def test_a_new_key_through_a_reopened_serial_device_replaces_the_old_client(
        tmp_path, ros_peer, ros_domain):  # noqa: F811
    link = str(tmp_path / "ttyACM_board")
    device = PtyDevice(link)
    try:
        with AgentProcess("serial", "-D", str(tmp_path / "ttyACM_*"), "-m", "dds",
                          "--client-dead-time", LONG_DEAD_TIME_MS) as agent:
            first, _ = board(device.transport(), 0x5E1A0001, ros_domain, "usb_fw", "/usb_first")
            assert wait_until(lambda: publishers(ros_peer, "/usb_first") == 1, 20)
            device.unplug()  # the board resets: its USB device goes and comes back
            time.sleep(0.3)
            device = PtyDevice(link)
            # The agent reopens the device within 0.2 s; the board's CREATE_CLIENT is repeated
            # until it answers (board() tries 10 times, 1 s apart).
            board(device.transport(), 0x5E1A0002, ros_domain, "usb_fw", "/usb_second")
            assert wait_until(lambda: publishers(ros_peer, "/usb_second") == 1, 20)
            assert wait_until(lambda: publishers(ros_peer, "/usb_first") == 0, 20)
            log = agent_log(agent)
    finally:
        device.unplug()
    assert "client 5e1a0001 replaced by client 5e1a0002" in log, log


def test_a_new_key_from_the_same_host_retires_the_dead_old_client_not_its_neighbours(
        ros_peer, ros_domain):  # noqa: F811
    with AgentProcess("udp4", "-m", "dds", "--client-dead-time", "1500") as agent:
        host = "127.0.0.3"
        talking, _ = board(BoundUdpTransport(agent.port, (host, 0)), 0x7A1C0001, ros_domain,
                           "talking_neighbour", "/neighbour_talking")
        quiet, _ = board(BoundUdpTransport(agent.port, (host, 0)), 0x7A1C0002, ros_domain,
                         "quiet_neighbour", "/neighbour_quiet")
        old, _ = board(BoundUdpTransport(agent.port, (host, 0)), 0x7A1C0003, ros_domain,
                       "rebooting_fw", "/reboot_old")
        assert wait_until(lambda: publishers(ros_peer, "/reboot_old") == 1, 20)
        spoke = time.monotonic()
        assert old.ping(1000, 3)  # the agent heard it after ``spoke``
        old.close()  # no DELETE; back from a new port with a new key, the same node
        new, _ = board(BoundUdpTransport(agent.port, (host, 0)), 0x7A1C0004, ros_domain,
                       "rebooting_fw", "/reboot_new")
        try:
            topics = ("/neighbour_talking", "/neighbour_quiet", "/reboot_new")
            assert wait_until(lambda: all(publishers(ros_peer, t) == 1 for t in topics), 20)

            def gone():
                talking.ping(300, 1)  # the talking neighbour speaks all along
                return publishers(ros_peer, "/reboot_old") == 0

            assert wait_until(gone, 40, 0.3)
            assert time.monotonic() - spoke >= 1.5  # retired once dead, not before
            talking.ping(300, 1)
            time.sleep(2.0)  # both neighbours past another dead time
            assert all(publishers(ros_peer, t) == 1 for t in topics)
        finally:
            for session in (talking, quiet, new):
                session.close()
        log = agent_log(agent)
    assert re.search(r"client 7a1c0003 silent for \d+ ms and client 7a1c0004, created since from "
                     r"the same host 127\.0\.0\.3, has its participant: retired", log), log
    assert log.count("retired") == 1, log


def test_a_board_reconnecting_100_times_under_new_keys_leaves_one_publisher(
        ros_peer, ros_domain):  # noqa: F811
    """rmw_microxrcedds' reconnection pattern 100 times: a new socket (new port), a new key, the
    same node and publisher, one sample, gone without DELETE. A short dead time (1 s) keeps the
    test short; the bound scales with it (30 s by default: test_agent_engine_retirement)."""
    with AgentProcess("udp4", "-m", "dds", "--client-dead-time", "1000") as agent:
        for life in range(100):
            session, writer = board(UdpTransport("127.0.0.1", agent.port), 0x0D0D0000 + life,
                                    ros_domain, "reconnecting_fw", "/reconnecting")
            session.write(writer, String(data="life %d" % life))
            session.flush()
            session.close()
            agent.drain()  # ~10 log lines a life: a full pipe would stall the agent
        # Every earlier life goes: retired once dead; or replaced at once where the kernel gave a
        # new socket the port of an earlier life (ephemeral ports are drawn at random: a repeat
        # among 100 is likely).
        gone = wait_for_log_lines(agent, r": retired, deleting its|replaced by client", 99, 90)
        assert gone == 99, gone
        # The last life is kept (asleep as far as anyone can tell).
        assert wait_until(lambda: publishers(ros_peer, "/reconnecting") == 1, 30, 0.1), \
            publishers(ros_peer, "/reconnecting")
        time.sleep(1.0)  # a late ghost would show up in discovery now
        assert publishers(ros_peer, "/reconnecting") == 1
        assert ros_peer.node_names().count(("reconnecting_fw", "/")) == 1
        log = agent_log(agent)
    assert log.count(": retired, deleting its") + log.count("replaced by client") == 99


def test_expire_time_deletes_a_silent_client_that_long_after_its_last_message(
        ros_peer, ros_domain):  # noqa: F811
    with AgentProcess("udp4", "-m", "dds", "--client-expire-time", "3000") as agent:
        session, _ = board(UdpTransport("127.0.0.1", agent.port), 0x3E3E0001, ros_domain,
                           "expiring_fw", "/expiring")
        try:
            assert wait_until(lambda: publishers(ros_peer, "/expiring") == 1, 20)
            spoke = time.monotonic()
            assert session.ping(1000, 3)  # heard by the agent after ``spoke``, then silence
            assert wait_until(lambda: publishers(ros_peer, "/expiring") == 0, 25, 0.05)
            gone_after = time.monotonic() - spoke
        finally:
            session.close()
        log = agent_log(agent)
    print("publisher gone from the ROS graph %.2f s after the last message" % gone_after)
    assert gone_after >= 3.0  # not before the expiry
    assert gone_after < 20.0  # and long before the 30 s dead time that used to gate it
    silent_ms, = [int(ms) for ms in
                  re.findall(r"client 3e3e0001 silent for (\d+) ms: expired", log)]
    # Deleted by the timer set for that moment; the margin is the loop's lateness on a loaded
    # machine (the rule's own slack is one tick, 0.2 s).
    assert 3000 <= silent_ms < 5000, silent_ms


def test_a_sleeper_keeps_its_session_and_publishes_when_it_wakes(
        ros_peer, ros_domain):  # noqa: F811
    """Silent for more than four dead times, with neighbours rebooting on its host meanwhile (as
    other nodes): nothing deletes it. Ten minutes are the same state, dead and kept, with no timer
    that could act (test_agent_engine_retirement moves the clock through ten minutes)."""
    received = []
    ros_peer.node.create_subscription(_ros_string(), "/sleeper", received.append, 10)
    with AgentProcess("udp4", "-m", "dds", "--client-dead-time", "500") as agent:
        sleeper, writer = board(BoundUdpTransport(agent.port, ("127.0.0.4", 0)), 0x51EE0001,
                                ros_domain, "sleeper_fw", "/sleeper")
        try:
            assert wait_until(lambda: publishers(ros_peer, "/sleeper") == 1, 20)
            for life in range(3):  # a neighbour behind the same address reboots, under new keys
                neighbour, _ = board(BoundUdpTransport(agent.port, ("127.0.0.4", 0)),
                                     0x51EE0010 + life, ros_domain, "other_fw", "/other")
                neighbour.close()
                time.sleep(0.7)
            assert publishers(ros_peer, "/sleeper") == 1
            sleeper.write(writer, String(data="good morning"))
            sleeper.flush()

            def arrived():
                sleeper.spin_once(20)  # acknowledges what the agent resends, as a board does
                return any(msg.data == "good morning" for msg in received)

            assert wait_until(arrived, 20)
        finally:
            sleeper.close()
        log = agent_log(agent)
    assert "client 51ee0001 silent for" in log and "client 51ee0001 is alive again" in log, log
    assert "client 51ee0001 deleted" not in log.split("client 51ee0001 is alive again")[0]


def test_a_sleeper_whose_session_was_taken_gets_it_back_by_pinging(
        ros_peer, ros_domain):  # noqa: F811
    """A stranger on the sleeper's address creates its node under another key (what a spoofed
    CREATE_CLIENT could do): the sleeper, dead, is retired. Awake, its pings are answered "no
    such session" and it creates everything again (auto_recover; micro-ROS, PX4 and ArduPilot
    count that answer as a missed ping and reconnect)."""
    received = []
    ros_peer.node.create_subscription(_ros_string(), "/napper", received.append, 10)
    with AgentProcess("udp4", "-m", "dds", "--client-dead-time", "1000") as agent:
        states = []
        napper, writer = board(BoundUdpTransport(agent.port, ("127.0.0.5", 0)), 0x4A900001,
                               ros_domain, "napper_fw", "/napper", auto_recover=True,
                               on_link_state=lambda _session, state: states.append(state))
        stranger, _ = board(BoundUdpTransport(agent.port, ("127.0.0.5", 0)), 0x4A900002,
                            ros_domain, "napper_fw", "/stranger")
        try:
            # The napper is dead after 1 s, then retired (the agent says so before the board
            # wakes: a ping any sooner would revive it): its publisher leaves the graph.
            assert wait_for_log_lines(agent, r"client 4a900001 silent for \d+ ms and .*: retired",
                                      1, 30) == 1
            assert wait_until(lambda: publishers(ros_peer, "/napper") == 0, 20)

            def recovered():
                napper.spin_once(50)
                return napper.link.recoveries >= 1

            assert wait_until(recovered, 30, 0), (states, napper.link.missed, napper.connected,
                                                  napper.create_status)
            assert wait_until(lambda: publishers(ros_peer, "/napper") == 1, 20)

            def arrived():
                napper.write(writer, String(data="back"))
                napper.spin_once(100)
                return any(msg.data == "back" for msg in received)

            assert wait_until(arrived, 20, 0)
        finally:
            napper.close()
            stranger.close()
        log = agent_log(agent)
    assert "client 4a900001 silent for" in log and "retired" in log, log
    assert "lost" in states and states[-1] == "connected", states


def _ros_string():
    from std_msgs.msg import String as RosString

    return RosString


def test_micro_ros_rebooted_under_a_new_key_retires_its_first_life(
        ros_peer, ros_domain):  # noqa: F811
    """The recorded micro-ROS firmware (tests/golden/microros/restart.jsonl: rclc +
    rmw_microxrcedds, killed, booted again from a new UDP port) with the second boot's
    CREATE_CLIENT under another key, as rmw's rand() draws it after a reset: its first life is
    retired once dead, because the second created the same node; one /sensor_state publisher."""
    capture = Capture("restart")
    second_boot = [i for i, (boot, data) in enumerate(capture.steps)
                   if boot == 1 and data[0] == 0x80 and data[4] == C.CREATE_CLIENT]
    index, = second_boot
    data = capture.steps[index][1]
    assert data[16:20] == bytes.fromhex("a1b2c3d4")  # the client key in CREATE_CLIENT
    capture.steps[index] = (1, data[:16] + bytes.fromhex("a1b2c3d5") + data[20:])
    teardown = min(i for i, (boot, data) in enumerate(capture.steps)
                   if boot == 1 and data[0] > 0x80 and len(data) > 4 and data[4] == C.DELETE)
    with AgentProcess("udp4", "-m", "dds", "--client-dead-time", "1500",
                      "--interfaces", str(INTERFACES)) as agent:
        channel = UdpChannel(agent.port)
        try:
            replay = Replayer(capture, channel, domain_id=ros_domain)
            replay.run(until_step=teardown)
            assert all(status == C.STATUS_OK for (boot, _), (_, status) in
                       replay.answers.statuses.items() if boot == 1)  # created anew, not reused
            assert wait_for_log_lines(
                agent, r"client a1b2c3d4 silent for \d+ ms and client a1b2c3d5, created since "
                r"from the same host 127\.0\.0\.1, has its participant: retired", 1, 30) == 1
            assert wait_until(lambda: publishers(ros_peer, "/sensor_state") == 1, 20)
            time.sleep(1.0)  # a ghost found late by discovery would show now
            assert publishers(ros_peer, "/sensor_state") == 1
        finally:
            channel.close()
        agent_log(agent)
