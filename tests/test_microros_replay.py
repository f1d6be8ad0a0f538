"""Real micro-ROS traffic (tests/golden/microros/: rclc + rmw_microxrcedds + Micro XRCE-DDS Client
2.4.3 talking to eProsima's MicroXRCEAgent 2.4.3) replayed against a live ``xrce-agent``: the
firmware's side is sent as the firmware sent it (tests/microros_replay.py rewrites only what a live
client derives from the agent's answers), and our agent must answer as eProsima's did: the same
STATUS (object and status code) for every request, STATUS_AGENT, INFO and TIMESTAMP_REPLY for
each request of theirs, a DATA for every READ_DATA eProsima answered with one, and a teardown in
which every request is answered OK.

Without ROS (``-m ced``) a second XRCE client plays the rclpy peers of the recording (``/cmd_vel``
at 30 Hz, ``/add_two_ints`` calls). The same firmware sequence also goes over a serial line (a real
pty pair, ``multiserial``), as boards without networking run it.
"""

import os
import termios
import tty

import pytest

from agent_process import AgentProcess
from microros_replay import Capture, Replayer, RosSideFeeder, SerialChannel, UdpChannel
from xrce import constants as C

CAPTURES = ("main", "big", "teardown", "restart")


def check_answers(capture: Capture, ours) -> None:
    theirs = capture.eprosima
    requests = {(boot, rid) for boot, rid, _ in capture.requests()}
    assert requests and requests <= set(theirs.statuses)  # every request of the firmware's
    mismatched = {"request 0x%04X (boot %d)" % (rid, boot):
                  (theirs.statuses[(boot, rid)], ours.statuses.get((boot, rid)))
                  for boot, rid in sorted(requests)
                  if ours.statuses.get((boot, rid)) != theirs.statuses[(boot, rid)]}
    assert not mismatched, "(object, status) eProsima vs ours: %r" % mismatched
    assert ours.status_agent == theirs.status_agent
    assert dict(ours.infos) == dict(theirs.infos)
    assert dict(ours.timestamp_replies) == dict(theirs.timestamp_replies)
    unanswered = sorted(key for key in theirs.data if not ours.data.get(key))
    assert not unanswered, "READ_DATA eProsima answered with DATA, we did not: %r" % unanswered


def check_teardown(capture: Capture, ours) -> None:
    deletes = [(boot, rid) for boot, rid, sub_id in capture.requests() if sub_id == C.DELETE]
    assert len(deletes) >= 10  # topics first, then writer + publisher, readers, replier, ...
    assert all(ours.statuses[key][1] == C.STATUS_OK for key in deletes), \
        [(key, ours.statuses.get(key)) for key in deletes]
    assert all(status in (C.STATUS_OK, C.STATUS_OK_MATCHED) for _, status in ours.statuses.values())


@pytest.mark.timeout(120)
@pytest.mark.parametrize("name", CAPTURES)
def test_capture_replayed_over_udp_gets_eprosimas_answers(name):
    capture = Capture(name)
    with AgentProcess("udp4", "-m", "ced", "-v", "0") as agent:
        feeder = RosSideFeeder(UdpChannel(agent.port), service=True)
        channel = UdpChannel(agent.port)
        try:
            replay = Replayer(capture, channel)
            ours = replay.run(speed=1.0)
        finally:
            channel.close()
            feeder.close()
            feeder.channel.close()
    check_answers(capture, ours)
    check_teardown(capture, ours)
    # rmw_microxrcedds waits on each cancel READ_DATA before deleting a reader (1 s at most):
    # answered within that, as eProsima did (it answered the /cmd_vel reader's in 48 ms).
    for boot, rid, _reader in capture.cancel_reads():
        if capture.eprosima.data.get((boot, rid)):
            assert replay.answered_at[(boot, rid)] - replay.sent_at[(boot, rid)] < 1.0


@pytest.fixture
def pty_pairs():
    opened = []

    def make():
        master, slave = os.openpty()
        tty.setraw(master, termios.TCSANOW)
        opened.extend((master, slave))
        return master, os.ttyname(slave)

    yield make
    for fd in opened:
        os.close(fd)


@pytest.mark.timeout(120)
@pytest.mark.parametrize("name", ("teardown", "restart"))
def test_rmw_call_sequence_over_serial(name, pty_pairs):
    """The firmware's calls as rmw_microxrcedds makes them (CREATE with REUSE|REPLACE; a board
    reset with the same key, every entity REUSEd and answered OK_MATCHED; the TOPIC-first teardown
    with cancel READ_DATA), over a serial line of a real pty pair."""
    capture = Capture(name)
    (firmware_fd, firmware_tty), (ros_side_fd, ros_side_tty) = pty_pairs(), pty_pairs()
    with AgentProcess("multiserial", "--devs", "%s %s" % (firmware_tty, ros_side_tty),
                      "-m", "ced", "-v", "0"):
        feeder = RosSideFeeder(SerialChannel(ros_side_fd), service=True)
        try:
            replay = Replayer(capture, SerialChannel(firmware_fd))
            ours = replay.run(speed=1.0)
        finally:
            feeder.close()
    check_answers(capture, ours)
    check_teardown(capture, ours)
    if name == "restart":
        second_boot = [key for key in capture.eprosima.statuses if key[0] == 1]
        assert second_boot and all(ours.statuses[key][1] in (C.STATUS_OK_MATCHED, C.STATUS_OK)
                                   for key in second_boot)
        creates = [(boot, rid) for boot, rid, sub_id in capture.requests() if sub_id == C.CREATE
                   and boot == 1]
        assert all(ours.statuses[key][1] == C.STATUS_OK_MATCHED for key in creates)
