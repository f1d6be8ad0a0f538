"""Two boards with the same real micro-ROS firmware (tests/golden/microros/main.jsonl: rclc +
rmw_microxrcedds, node ``tb3_fw``) behind one agent with a fleet file: the capture replayed twice,
each copy with its own client key (the only other rewrite), the fleet's rules matching the keys to
/robot1 and /robot2. Each robot's node, /sensor_state, /cmd_vel and /add_two_ints are its own: a
Twist on /robot1/cmd_vel reaches only the first copy's reader, a request to /robot2/add_two_ints
only the second copy's replier. Over serial, the rules match boards by device, through the
symbolic links a /dev/serial/by-id glob names."""

import os

import pytest

from agent_process import AgentProcess
from microros_replay import Capture, Replayer, SerialChannel, UdpChannel
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from test_microros_replay import INTERFACES, _ros_types
from xrce.wire import constants as C

KEYS = {1: bytes.fromhex("b0000001"), 2: bytes.fromhex("b0000002")}


def _received(replay):
    """DATA samples the agent sent this copy, per object (its /cmd_vel reader, its replier)."""
    return {key[1]: len(samples) for key, samples in replay.answers.samples.items()}


@pytest.mark.timeout(120)
def test_one_firmware_twice_under_two_robots_names(tmp_path, ros_peer, ros_domain):  # noqa: F811
    _sensor_state, twist, add_two_ints = _ros_types()
    fleet = tmp_path / "fleet.toml"
    fleet.write_text("".join('[[board]]\nname = "robot%d"\nkey = "0x%s"\nnamespace = "/robot%d"\n\n'
                             % (n, key.hex(), n) for n, key in KEYS.items()))
    capture = Capture("main")
    first_sample = next(i for i, (_b, data) in enumerate(capture.steps)
                        if data[0] > 0x80 and data[4] == C.WRITE_DATA)
    node = ros_peer.node
    channels = []
    with AgentProcess("udp4", "-m", "dds", "-v", "0", "--interfaces", str(INTERFACES),
                      "--fleet", str(fleet)) as agent:
        try:
            replays = {}
            for n, key in KEYS.items():
                channels.append(UdpChannel(agent.port))
                replays[n] = Replayer(capture, channels[-1], domain_id=ros_domain, client_key=key)
                replays[n].run(until_step=first_sample)  # every entity of the firmware's
            assert wait_until(lambda: {("tb3_fw", "/robot1"), ("tb3_fw", "/robot2")}
                              <= set(ros_peer.node_names()), 15), ros_peer.node_names()
            assert ("tb3_fw", "/") not in ros_peer.node_names()
            for n in KEYS:
                assert wait_until(lambda: node.count_publishers("/robot%d/sensor_state" % n) == 1
                                  and node.count_subscribers("/robot%d/cmd_vel" % n) == 1, 15)
            assert node.count_subscribers("/cmd_vel") == 0

            to_robot1 = node.create_publisher(twist, "/robot1/cmd_vel", 10)
            assert wait_until(lambda: to_robot1.get_subscription_count() == 1, 10)
            before = {n: _received(r) for n, r in replays.items()}
            for _ in range(5):
                to_robot1.publish(twist())
            assert replays[1].wait(lambda: sum(_received(replays[1]).values())
                                   >= sum(before[1].values()) + 5, 10), replays[1].answers.samples
            replays[2].wait(lambda: False, 0.5)  # its socket read: whatever came to it
            assert _received(replays[2]) == before[2]

            client = node.create_client(add_two_ints, "/robot2/add_two_ints")
            assert client.wait_for_service(timeout_sec=10)
            before = {n: _received(r) for n, r in replays.items()}
            client.call_async(add_two_ints.Request(a=2, b=3))  # the request: the replay answers none
            assert replays[2].wait(lambda: _received(replays[2]) != before[2], 10)
            replays[1].wait(lambda: False, 0.5)
            assert _received(replays[1]) == before[1]
        finally:
            for channel in channels:
                channel.close()


@pytest.mark.timeout(120)
def test_serial_boards_matched_by_device_through_their_links(tmp_path, pty_pair, ros_peer,
                                                             ros_domain):  # noqa: F811
    """Over serial (real pty pairs, ``multiserial``): a rule's by-id glob matches the board the
    agent opened by its real path (/dev/ttyACM0 for a /dev/serial/by-id/usb-STM* link), and a
    rule naming the real path matches a board the agent opened through a link to it."""
    (stm_fd, stm_tty), (ftdi_fd, ftdi_tty) = pty_pair(), pty_pair()
    by_id = tmp_path / "by-id"
    by_id.mkdir()
    os.symlink(stm_tty, by_id / "usb-STM_Virtual_COM_Port_0001-if00")
    ftdi_link = by_id / "usb-FTDI_FT232R_0002-if00-port0"
    os.symlink(ftdi_tty, ftdi_link)
    fleet = tmp_path / "fleet.toml"
    fleet.write_text('[[board]]\nname = "stm"\ndevice = "%s/usb-STM*"\nnamespace = "/stm"\n\n'
                     '[[board]]\nname = "ftdi"\ndevice = "%s"\nnamespace = "/ftdi"\n'
                     % (by_id, ftdi_tty))
    capture = Capture("main")
    first_sample = next(i for i, (_b, data) in enumerate(capture.steps)
                        if data[0] > 0x80 and data[4] == C.WRITE_DATA)
    _ros_types()
    with AgentProcess("multiserial", "--devs", "%s %s" % (stm_tty, ftdi_link), "-m", "dds",
                      "-v", "0", "--interfaces", str(INTERFACES), "--fleet", str(fleet)):
        for fd, key in ((stm_fd, KEYS[1]), (ftdi_fd, KEYS[2])):
            Replayer(capture, SerialChannel(fd), domain_id=ros_domain,
                     client_key=key).run(until_step=first_sample)
        assert wait_until(lambda: {("tb3_fw", "/stm"), ("tb3_fw", "/ftdi")}
                          <= set(ros_peer.node_names()), 15), ros_peer.node_names()
        assert wait_until(lambda: ros_peer.node.count_subscribers("/stm/cmd_vel") == 1
                          and ros_peer.node.count_subscribers("/ftdi/cmd_vel") == 1, 15)
