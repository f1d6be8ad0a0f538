"""The ``-v 4`` entity lines (issue 38), from real micro-ROS traffic: the TurtleBot3-like capture
(tests/golden/microros/main.jsonl: rclc + rmw_microxrcedds, recorded against eProsima's agent)
replayed into a real agent with rclpy (``-m dds``). Every CREATE the firmware sent that made an
object gets exactly one line naming the client key as the firmware sent it, the object id and
kind as eProsima's agent logs them, and what a user needs: the participant's name and ROS domain,
each endpoint's ROS topic, type, QoS and the ROS entity it became; ``-v 3`` has none of them."""

import re

import pytest

from agent_process import AgentProcess
from microros_replay import Capture, Replayer, UdpChannel, _submessages
from ros_helpers import ros_domain  # noqa: F401
from test_microros_replay import INTERFACES, _ros_types
from xrce.wire import constants as C

CREATED = re.compile(r"INFO +xrce\.agent: client ([0-9a-f]{8}): created (\w+) (0x[0-9A-F]{3}\((\d+)\))"
                     r"(?: in (\w+) (0x[0-9A-F]{3}\(\d\)))?(?:: (.*?))?(?: -> (.*))?$")
_NO_OBJECT = (C.OBJK_TYPE, C.OBJK_QOSPROFILE, C.OBJK_APPLICATION)


def creates_until(capture: Capture, step: int):
    """(request id, object id with its kind) of each CREATE of a DDS object in the steps."""
    found = []
    for boot, data in capture.steps[:step]:
        if data[0] <= 0x80 or boot:
            continue
        for sub_id, _flags, body in _submessages(data, 4):
            if sub_id == C.CREATE and len(body) >= 5 and body[4] not in _NO_OBJECT:
                found.append(((body[0] << 8) | body[1], ((body[2] << 8) | body[3])))
    return found


@pytest.mark.timeout(120)
@pytest.mark.parametrize("verbosity", ("4", "3"))
def test_a_micro_ros_board_at_v4_logs_one_line_per_create(verbosity, ros_domain):  # noqa: F811
    _ros_types()  # the capture's interfaces built (a cache hit after the first time)
    capture = Capture("main")
    first_sample = next(i for i, (_b, data) in enumerate(capture.steps)
                        if data[0] > 0x80 and data[4] == C.WRITE_DATA)
    with AgentProcess("udp4", "-m", "dds", "-v", verbosity,
                      "--interfaces", str(INTERFACES)) as agent:
        channel = UdpChannel(agent.port)
        try:
            replay = Replayer(capture, channel, domain_id=ros_domain)
            ours = replay.run(until_step=first_sample)
        finally:
            channel.close()
        assert agent.stop() == 0
    log = "".join(agent.output)
    lines = [CREATED.search(line) for line in log.splitlines()]
    lines = [m for m in lines if m]
    if verbosity == "3":
        assert not lines and " created " not in log
        return
    creates = creates_until(capture, first_sample)
    made = [oid for rid, oid in creates if ours.statuses.get((0, rid), (0, 0xFF))[1] == C.STATUS_OK]
    assert len(made) >= 10  # participant, topics, groups, writers, readers, replier
    assert [m.group(3) for m in lines] == ["0x%03X(%d)" % (oid >> 4, oid & 0xF) for oid in made]
    # The key the firmware sent, in every line (its CREATE_CLIENT payload).
    create_client = next(data for _b, data in capture.steps
                         if data[0] == 0x80 and data[4] == C.CREATE_CLIENT)
    key = create_client[16:20].hex()  # after the headers, cookie, version and vendor id
    assert {m.group(1) for m in lines} == {key}, (key, log)
    by_kind = {}
    for m in lines:
        by_kind.setdefault(m.group(2), []).append(m)
    participant = by_kind["participant"][0]
    assert re.fullmatch(r"name '\w+', ROS domain %d" % ros_domain, participant.group(7)), \
        participant.group(0)
    assert participant.group(8).startswith("node /"), participant.group(0)
    node = participant.group(8)[len("node "):]
    endpoints = by_kind["datawriter"] + by_kind["datareader"]
    assert len(by_kind["datawriter"]) >= 1 and len(by_kind["datareader"]) >= 1
    for m in endpoints:
        assert re.fullmatch(r"topic (/\w+) \(DDS rt/\w+\), type (\w+/msg/\w+) \(DDS \w+::msg::dds_::"
                            r"\w+_\), ROS domain %d, QoS (reliable|best_effort), "
                            r"(volatile|transient_local), keep_last \d+" % ros_domain,
                            m.group(7)), m.group(0)
        topic = re.match(r"topic (/\w+)", m.group(7)).group(1)
        entity = "publisher" if m.group(2) == "datawriter" else "subscription"
        assert m.group(8) == "%s %s of node %s" % (entity, topic, node), m.group(0)
    topics = {re.match(r"topic (/\w+)", m.group(7)).group(1) for m in endpoints}
    assert {"/sensor_state", "/cmd_vel"} <= topics, topics
    sensor = next(m for m in by_kind["datawriter"] if "/sensor_state" in m.group(7))
    assert "type turtlebot3_msgs/msg/SensorState" in sensor.group(7)
    assert all(m.group(5) == "participant" for m in by_kind["topic"] + by_kind["publisher"])
    assert by_kind["replier"][0].group(7).startswith("service /add_two_ints, type "
                                                     "example_interfaces/srv/AddTwoInts")
