"""Real micro-ROS traffic (tests/golden/microros/: rclc + rmw_microxrcedds + Micro XRCE-DDS Client
2.4.3 talking to eProsima's MicroXRCEAgent 2.4.3) replayed against a live ``xrce-agent``: the
firmware's side is sent as the firmware sent it (tests/helpers/microros_replay.py rewrites only what a live
client derives from the agent's answers), and our agent must answer as eProsima's did: the same
STATUS (object and status code) for every request, STATUS_AGENT, INFO and TIMESTAMP_REPLY for
each request of theirs, a DATA for every READ_DATA eProsima answered with one, and a teardown in
which every request is answered OK.

Without ROS (``-m ced``) a second XRCE client plays the rclpy peers of the recording (``/cmd_vel``
at 30 Hz, ``/add_two_ints`` calls); with ROS (``-m dds``) rclpy peers do, as they did. The same
firmware sequence also goes over a serial line (a real pty pair, ``multiserial``), as boards
without networking run it.
"""

import threading
import time
from pathlib import Path

import pytest

from agent_process import AgentProcess
from microros_replay import Capture, Replayer, RosSideFeeder, SerialChannel, UdpChannel
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from xrce.wire import constants as C

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
    counted = lambda counts: {boot: n for boot, n in counts.items() if n}  # noqa: E731
    assert counted(ours.infos) == counted(theirs.infos)
    assert counted(ours.timestamp_replies) == counted(theirs.timestamp_replies)
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


@pytest.mark.timeout(120)
@pytest.mark.parametrize("name", ("teardown", "restart"))
def test_rmw_call_sequence_over_serial(name, pty_pair):
    """The firmware's calls as rmw_microxrcedds makes them (CREATE with REUSE|REPLACE; a board
    reset with the same key, every entity REUSEd and answered OK_MATCHED; the TOPIC-first teardown
    with cancel READ_DATA), over a serial line of a real pty pair."""
    capture = Capture(name)
    (firmware_fd, firmware_tty), (ros_side_fd, ros_side_tty) = pty_pair(), pty_pair()
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


# ------------------------------------------------------------------------- with ROS (-m dds)

INTERFACES = Path(__file__).resolve().parents[1] / "interfaces"


def _ros_types():
    """(SensorState, Twist, AddTwoInts) rclpy classes, built first (a cache hit after the first
    time): turtlebot3_msgs ships with xrce, example_interfaces with the tests."""
    from xrce.agent import interfaces

    interfaces.build(names=["turtlebot3_msgs"])
    interfaces.build([str(INTERFACES)], names=["example_interfaces"])
    from example_interfaces.srv import AddTwoInts
    from geometry_msgs.msg import Twist
    from turtlebot3_msgs.msg import SensorState

    return SensorState, Twist, AddTwoInts


class RosSide:
    """The rclpy peers of the recording: a best-effort /sensor_state subscriber, a reliable
    /cmd_vel publisher at 30 Hz and an /add_two_ints client calling four times a second."""

    def __init__(self, ros_peer):
        from rclpy.qos import qos_profile_sensor_data

        sensor_state, twist, add_two_ints = _ros_types()
        node = self.node = ros_peer.node
        self.sensor_states = []
        node.create_subscription(sensor_state, "/sensor_state", self.sensor_states.append,
                                 qos_profile_sensor_data)
        self.cmd_vel = node.create_publisher(twist, "/cmd_vel", 10)
        self.twist = twist
        self.client = node.create_client(add_two_ints, "/add_two_ints")
        self.request = add_two_ints.Request(a=2, b=3)
        self.calls = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ros-side", daemon=True)
        self._thread.start()

    def _run(self):
        count = 0
        while not self._stop.wait(1 / 30):
            count += 1
            self.cmd_vel.publish(self.twist())
            if count % 8 == 0 and self.client.service_is_ready():
                self.client.call_async(self.request)
                self.calls += 1

    def close(self):
        self._stop.set()
        self._thread.join(2)


@pytest.mark.timeout(180)
@pytest.mark.parametrize("name", ("main", "teardown", "restart"))
def test_capture_replayed_into_ros_gets_eprosimas_answers(name, ros_peer, ros_domain):  # noqa: F811
    """-m dds: the firmware's entities in ROS, the recording's rclpy peers talking to them. In
    the teardown, the /sensor_state publisher outlives its deleted TOPIC object until its
    DATAWRITER is deleted, as in eProsima's agent (there a DDS DataWriter keeps its topic); after
    the board reset, the firmware's writers are the same DDS writers."""
    capture = Capture(name)
    ros_side = RosSide(ros_peer)
    checked = []
    publishers = []
    teardown = len(capture.steps)
    if name == "restart":  # the second boot's
        teardown = min(i for i, (b, data) in enumerate(capture.steps)
                       if b == 1 and data[0] > 0x80 and len(data) > 4 and data[4] == C.DELETE)

    def on_step(index, boot, data):
        if index < teardown and index % 20 == 0:
            # Before and after the board reset: the same DDS writer (its GID), not a new one.
            publishers.append(tuple(bytes(info.endpoint_gid) for info in
                                    ros_side.node.get_publishers_info_by_topic("/big_string")))
        # Before the message deleting the /sensor_state writer (0x0005): its topic is gone.
        if data[0] > 0x80 and len(data) >= 12 and data[4] == C.DELETE and data[10:12] == b"\x00\x05":
            deleted_topic = any(replay.answers.statuses.get((b, rid)) == (0x0002, C.STATUS_OK)
                                for b, rid, sub in capture.requests()
                                if sub == C.DELETE and b == boot)
            checked.append((deleted_topic, ros_side.node.count_publishers("/sensor_state")))

    with AgentProcess("udp4", "-m", "dds", "-v", "0", "--interfaces", str(INTERFACES)) as agent:
        channel = UdpChannel(agent.port)
        try:
            replay = Replayer(capture, channel, domain_id=ros_domain)
            # Until ROS has discovered the firmware's entities, the data of the recording's first
            # seconds would go nowhere: wait for them before the data phase, as the peers of the
            # recording were up before the firmware.
            first_sample = next(i for i, (_b, data) in enumerate(capture.steps)
                                if data[0] > 0x80 and data[4] == C.WRITE_DATA)
            replay.run(until_step=first_sample)
            node = ros_side.node
            assert wait_until(lambda: node.count_publishers("/sensor_state") >= 1
                              and node.count_subscribers("/cmd_vel") >= 1
                              and ros_side.client.service_is_ready(), 15), \
                (node.count_publishers("/sensor_state"), node.count_subscribers("/cmd_vel"),
                 ros_side.client.service_is_ready(), replay.answers.statuses)
            ours = replay.run(start_step=first_sample, speed=1.0, on_step=on_step)
        finally:
            channel.close()
            ros_side.close()
        gone = wait_until(lambda: ros_side.node.count_publishers("/sensor_state") == 0, 10)
    check_answers(capture, ours)
    check_teardown(capture, ours)
    assert len(ros_side.sensor_states) >= 10, len(ros_side.sensor_states)
    if name == "main":
        assert ros_side.calls >= 5
    elif name == "teardown":
        assert checked == [(True, 1)], checked
        assert gone
    else:
        # REUSE matched the reliable writer whose CREATE differs in a padding byte: no second
        # DDS writer (before, a new one with a new GID replaced it).
        seen = set(publishers)
        assert len(publishers) >= 10 and len(seen) == 1 and len(seen.pop()) == 1, publishers


# ------------------------------------------- rclc beyond publish/subscribe (micro_ros_agent)

ACTIONS_BOOT = 0
SEND_GOAL, CANCEL_GOAL, GET_RESULT = 104, 120, 136  # the firmware's repliers of /mcu/fibonacci


class ActionsRosSide:
    """What the rclpy process of actions_params.jsonl did, in its order: a transient_local
    subscriber of /mcu2/latched, the parameter calls (list, get, set 42 / 2.5 / false, get), an
    ActionClient goal with feedback and result, a second goal cancelled, three 2,000-byte
    UInt8MultiArray on /big_in and a /big_out subscriber. The goals carry the recording's goal ids
    and orders (the firmware's replayed feedback names those ids)."""

    def __init__(self, ros_peer, capture: Capture):
        from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters
        from rclpy.action import ActionClient
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import String, UInt8MultiArray
        from test_msgs.action import Fibonacci

        node = self.node = ros_peer.node
        self.Fibonacci = Fibonacci
        self.goals = [(sample[24:40], int.from_bytes(sample[40:44], "little")) for sample in
                      capture.eprosima.samples[(ACTIONS_BOOT, SEND_GOAL)]]
        self.latched, self.big_out, self.feedback = [], [], []
        node.create_subscription(UInt8MultiArray, "/big_out", self.big_out.append, 10)
        self.big_in = node.create_publisher(UInt8MultiArray, "/big_in", 10)
        self.big_in_type = UInt8MultiArray
        self.latched_type, self.latched_qos = String, QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.list_parameters = node.create_client(ListParameters, "/mcu/feat_fw/list_parameters")
        self.get_parameters = node.create_client(GetParameters, "/mcu/feat_fw/get_parameters")
        self.set_parameters = node.create_client(SetParameters, "/mcu/feat_fw/set_parameters")
        self.action = ActionClient(node, Fibonacci, "/mcu/fibonacci")
        self.outcome = {}
        self.error = None
        self._thread = None

    def ready(self) -> bool:
        return self.action.server_is_ready() and self.set_parameters.service_is_ready() and \
            self.get_parameters.service_is_ready() and self.list_parameters.service_is_ready() \
            and self.node.count_subscribers("/big_in") >= 1

    def start(self):
        self._thread = threading.Thread(target=self._run_safely, name="ros-side", daemon=True)
        self._thread.start()

    def join(self, timeout):
        self._thread.join(timeout)
        assert not self._thread.is_alive(), "the ROS side is still waiting: %r" % self.outcome
        if self.error is not None:
            raise self.error

    def _run_safely(self):
        try:
            self._run()
        except BaseException as exc:  # reported by join
            self.error = exc

    @staticmethod
    def _result(future, timeout=30.0):
        assert wait_until(future.done, timeout), "no answer within %.0f s" % timeout
        return future.result()

    def _run(self):
        from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
        from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters
        from unique_identifier_msgs.msg import UUID

        node, outcome = self.node, self.outcome
        node.create_subscription(self.latched_type, "/mcu2/latched", self.latched.append,
                                 self.latched_qos)
        names = ["p_int", "p_double", "p_bool"]
        outcome["list"] = sorted(self._result(self.list_parameters.call_async(
            ListParameters.Request())).result.names)
        outcome["get"] = self._result(self.get_parameters.call_async(
            GetParameters.Request(names=names))).values
        values = [ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=42),
                  ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=2.5),
                  ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=False)]
        outcome["set"] = [r.successful for r in self._result(self.set_parameters.call_async(
            SetParameters.Request(parameters=[Parameter(name=n, value=v)
                                              for n, v in zip(names, values)]))).results]
        outcome["get again"] = self._result(self.get_parameters.call_async(
            GetParameters.Request(names=names))).values

        (first_id, first_order), (second_id, second_order) = self.goals
        feedback = lambda message: self.feedback.append(  # noqa: E731
            (bytes(message.goal_id.uuid), list(message.feedback.sequence)))
        handle = self._result(self.action.send_goal_async(
            self.Fibonacci.Goal(order=first_order), feedback, UUID(uuid=list(first_id))))
        outcome["first accepted"] = handle.accepted
        result = self._result(handle.get_result_async())
        outcome["first result"] = (result.status, list(result.result.sequence))

        handle = self._result(self.action.send_goal_async(
            self.Fibonacci.Goal(order=second_order), feedback, UUID(uuid=list(second_id))))
        outcome["second accepted"] = handle.accepted
        result_future = handle.get_result_async()
        cancel = self._result(handle.cancel_goal_async())
        outcome["cancel"] = (cancel.return_code,
                             [bytes(g.goal_id.uuid) for g in cancel.goals_canceling])
        result = self._result(result_future)
        outcome["second result"] = result.status

        for count in range(3):
            self.big_in.publish(self.big_in_type(data=bytes((i * 7 + count) & 0xFF
                                                            for i in range(2000))))
            time.sleep(0.5)
        outcome["done"] = True


@pytest.mark.timeout(240)
def test_rclc_actions_and_parameters_replayed_into_ros(ros_peer, ros_domain):  # noqa: F811
    """actions_params.jsonl (rclc 6.1 against micro_ros_agent) through ``-m dds`` with the
    recording's rclpy side: every STATUS as micro_ros_agent answered it (the action's three
    repliers and two topics included: before, the send_goal replier was refused as "not a
    service type"), a DATA for every READ_DATA that got one there (parameter and action
    requests, /big_in), and on the ROS side the outcomes the recording's rclpy process saw."""
    from action_msgs.msg import GoalStatus
    from action_msgs.srv import CancelGoal

    capture = Capture("actions_params")
    ros_side = ActionsRosSide(ros_peer, capture)
    # Up to the firmware's first reply: every entity is made and read by then.
    first_reply = next(i for i, (_b, data) in enumerate(capture.steps)
                       if data[0] > 0x80 and data[4] == C.WRITE_DATA and
                       (data[10] << 8 | data[11]) in (72, 8, 40))
    with AgentProcess("udp4", "-m", "dds", "-v", "0") as agent:
        channel = UdpChannel(agent.port)
        try:
            replay = Replayer(capture, channel, domain_id=ros_domain, answer_requests=True)
            replay.run(until_step=first_reply)
            assert wait_until(ros_side.ready, 20), (ros_side.action.server_is_ready(),
                                                    replay.answers.statuses)
            ros_side.start()
            try:
                ours = replay.run(start_step=first_reply, speed=1.0)
            except AssertionError as exc:  # say where the ROS side was
                raise AssertionError("%s; the ROS side: %r %r" % (exc, ros_side.outcome,
                                                                 ros_side.error)) from None
            ros_side.join(30)
        finally:
            channel.close()
        assert agent.proc.poll() is None  # still serving after the teardown
    check_answers(capture, ours)
    check_teardown(capture, ours)
    outcome = ros_side.outcome
    (first_id, _), (second_id, _) = ros_side.goals
    assert outcome["list"] == ["p_bool", "p_double", "p_int"]
    assert [(v.integer_value, v.double_value, v.bool_value) for v in outcome["get"]] == \
        [(7, 0.0, False), (0, 0.5, False), (0, 0.0, True)]
    assert outcome["set"] == [True, True, True]
    assert [(v.integer_value, v.double_value, v.bool_value) for v in outcome["get again"]] == \
        [(42, 0.0, False), (0, 2.5, False), (0, 0.0, False)]
    assert outcome["first accepted"] and outcome["second accepted"]
    assert outcome["first result"] == (GoalStatus.STATUS_SUCCEEDED, [0, 1, 1, 2, 3, 5])
    assert [f for goal, f in ros_side.feedback if goal == first_id] == \
        [[0, 1, 1], [0, 1, 1, 2], [0, 1, 1, 2, 3], [0, 1, 1, 2, 3, 5]]
    assert outcome["cancel"] == (CancelGoal.Response.ERROR_NONE, [second_id])
    assert outcome["second result"] == GoalStatus.STATUS_CANCELED
    assert [m.data for m in ros_side.latched] == ["latched-hello"]
    assert len(ros_side.big_out) == 3 and all(len(m.data) == 2000 for m in ros_side.big_out)
