"""rclc actions through ``xrce-agent -m dds`` with rclpy's real ``ActionClient``/``ActionServer``.

The board is ``rclc_action_peer.RclcActionPeer``: the entities rmw_microxrcedds created for the
rclc action server of tests/golden/microros/actions_params.jsonl (taken from that capture), over
UDP and over a serial line (a real pty pair). Three things an rclc user does:

- the board serves the action: a goal with its feedbacks and result SUCCEEDED, a second goal
  cancelled while it runs (CANCELED);
- the board is the action client of an rclpy ActionServer: the same, seen from the board;
- the board resets (same client key, a new CREATE_CLIENT; over UDP from a new source port) while
  a goal runs: the ROS side gets no made-up result for the lost goal, its cancel is answered by the
  rebooted board (unknown goal), and the next goal succeeds; the agent keeps serving.

Before, the agent refused the send_goal replier (``'test_msgs::action::dds_::
Fibonacci_SendGoal_Request_' is not a service type``) and ``rclc_action_server_init`` failed.
"""

from __future__ import annotations

import asyncio
import os
import threading
import time
from contextlib import contextmanager

import pytest

from agent_process import AgentProcess
from microros_replay import SerialChannel, UdpChannel
from rclc_action_peer import RclcActionPeer
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from xrce.wire import constants as C

LINKS = ("udp", "serial")
FEEDBACKS = [[0, 1, 1], [0, 1, 1, 2], [0, 1, 1, 2, 3], [0, 1, 1, 2, 3, 5]]  # order 6, as recorded


@contextmanager
def board_link(link: str, pty_pair):
    """(agent, channel): an ``xrce-agent -m dds`` and the board's side of its link."""
    if link == "udp":
        with AgentProcess("udp4", "-m", "dds", "-v", "0") as agent:
            channel = UdpChannel(agent.port)
            try:
                yield agent, channel
            finally:
                channel.close()
    else:
        board_fd, board_tty = pty_pair()
        with AgentProcess("multiserial", "--devs", board_tty, "-m", "dds", "-v", "0") as agent:
            yield agent, SerialChannel(board_fd)


def _done(future, timeout: float = 30.0):
    assert wait_until(future.done, timeout), "no answer within %.0f s" % timeout
    return future.result()


def _booted(board: RclcActionPeer, expected=(C.STATUS_OK,)) -> None:
    statuses = board.boot_up()
    assert all(status in expected for status in statuses), statuses


@pytest.mark.timeout(120)
@pytest.mark.parametrize("link", LINKS)
def test_board_serves_an_action_to_rclpy(link, ros_peer, ros_domain, pty_pair):  # noqa: F811
    from action_msgs.msg import GoalStatus
    from action_msgs.srv import CancelGoal
    from rclpy.action import ActionClient
    from test_msgs.action import Fibonacci

    with board_link(link, pty_pair) as (agent, channel):
        board = RclcActionPeer(channel, ros_domain)
        client = ActionClient(ros_peer.node, Fibonacci, "/mcu/fibonacci")
        try:
            _booted(board)
            assert wait_until(client.server_is_ready, 20)
            feedback = []
            handle = _done(client.send_goal_async(Fibonacci.Goal(order=6), lambda message: (
                feedback.append(list(message.feedback.sequence)))))
            assert handle.accepted
            result = _done(handle.get_result_async())
            assert (result.status, list(result.result.sequence)) == \
                (GoalStatus.STATUS_SUCCEEDED, [0, 1, 1, 2, 3, 5])
            assert wait_until(lambda: len(feedback) >= 4, 5) and feedback == FEEDBACKS

            board.feedback_period = 0.3  # long enough to cancel it on the way
            running = []
            handle = _done(client.send_goal_async(Fibonacci.Goal(order=40), lambda message: (
                running.append(list(message.feedback.sequence)))))
            assert handle.accepted
            result_future = handle.get_result_async()
            assert wait_until(lambda: running, 10)
            cancel = _done(handle.cancel_goal_async())
            assert cancel.return_code == CancelGoal.Response.ERROR_NONE
            assert [bytes(g.goal_id.uuid) for g in cancel.goals_canceling] == \
                [bytes(handle.goal_id.uuid)]
            result = _done(result_future)
            assert result.status == GoalStatus.STATUS_CANCELED
            assert 3 <= len(result.result.sequence) < 40
        finally:
            client.destroy()
            board.reset()
        assert agent.proc.poll() is None


class RosActionServer:
    """An rclpy ActionServer of /mcu/fibonacci on its own node and multithreaded executor (a
    running goal must not hold up the cancel request)."""

    def __init__(self, ros_peer, period: float = 0.1):
        from rclpy.action import ActionServer, CancelResponse
        from rclpy.callback_groups import ReentrantCallbackGroup
        from rclpy.executors import MultiThreadedExecutor
        from rclpy.node import Node
        from test_msgs.action import Fibonacci

        self.Fibonacci = Fibonacci
        self.period = period
        self.node = Node("fibonacci_server", context=ros_peer.context,
                         start_parameter_services=False, enable_rosout=False)
        self.server = ActionServer(self.node, Fibonacci, "/mcu/fibonacci", self.execute,
                                   cancel_callback=lambda _request: CancelResponse.ACCEPT,
                                   callback_group=ReentrantCallbackGroup())
        self.executor = MultiThreadedExecutor(num_threads=3, context=ros_peer.context)
        self.executor.add_node(self.node)
        self._stop = False
        self._thread = threading.Thread(target=self._spin, name="fibonacci-server", daemon=True)
        self._thread.start()

    def _spin(self):
        while not self._stop:
            self.executor.spin_once(timeout_sec=0.05)

    def execute(self, handle):
        sequence = [0, 1]
        while len(sequence) < handle.request.order:
            if handle.is_cancel_requested:
                handle.canceled()
                return self.Fibonacci.Result(sequence=sequence)
            sequence.append(sequence[-1] + sequence[-2])
            handle.publish_feedback(self.Fibonacci.Feedback(sequence=sequence))
            time.sleep(self.period)
        handle.succeed()
        return self.Fibonacci.Result(sequence=sequence)

    def close(self):
        self._stop = True
        self._thread.join(5)
        self.server.destroy()
        self.executor.remove_node(self.node)
        self.node.destroy_node()
        self.executor.shutdown()


@pytest.mark.timeout(120)
@pytest.mark.parametrize("link", LINKS)
def test_board_is_the_action_client_of_rclpy(link, ros_peer, ros_domain, pty_pair):  # noqa: F811
    from action_msgs.msg import GoalInfo, GoalStatus
    from action_msgs.srv import CancelGoal
    from unique_identifier_msgs.msg import UUID

    server = RosActionServer(ros_peer)
    impl = server.Fibonacci.Impl
    node = server.node
    try:
        with board_link(link, pty_pair) as (agent, channel):
            board = RclcActionPeer(channel, ros_domain, role="client")
            try:
                _booted(board)
                # The board's feedback and status readers are in the ROS graph before the goal.
                assert wait_until(lambda: node.count_subscribers(
                    "/mcu/fibonacci/_action/feedback") >= 1 and node.count_subscribers(
                    "/mcu/fibonacci/_action/status") >= 1, 20)
                first = UUID(uuid=list(os.urandom(16)))
                accepted = board.reply(board.send("send_goal", impl.SendGoalService.Request(
                    goal_id=first, goal=server.Fibonacci.Goal(order=6))),
                    impl.SendGoalService.Response)
                assert accepted.accepted
                result = board.reply(board.send("get_result", impl.GetResultService.Request(
                    goal_id=first)), impl.GetResultService.Response)
                assert (result.status, list(result.result.sequence)) == \
                    (GoalStatus.STATUS_SUCCEEDED, [0, 1, 1, 2, 3, 5])
                mine = lambda goal: [s for g, s in board.feedback if g == bytes(goal.uuid)]  # noqa: E731
                assert wait_until(lambda: len(mine(first)) >= 4, 5) and mine(first) == FEEDBACKS
                # The status topic (transient_local, depth 1) tells the goal's end too.
                assert wait_until(lambda: any(
                    bytes(s.goal_info.goal_id.uuid) == bytes(first.uuid) and
                    s.status == GoalStatus.STATUS_SUCCEEDED
                    for array in board.status_arrays for s in array.status_list), 10)

                server.period = 0.3
                second = UUID(uuid=list(os.urandom(16)))
                assert board.reply(board.send("send_goal", impl.SendGoalService.Request(
                    goal_id=second, goal=server.Fibonacci.Goal(order=40))),
                    impl.SendGoalService.Response).accepted
                result_request = board.send("get_result", impl.GetResultService.Request(
                    goal_id=second))
                assert wait_until(lambda: mine(second), 10)
                cancel = board.reply(board.send("cancel_goal", CancelGoal.Request(
                    goal_info=GoalInfo(goal_id=second))), CancelGoal.Response)
                assert cancel.return_code == CancelGoal.Response.ERROR_NONE
                assert [bytes(g.goal_id.uuid) for g in cancel.goals_canceling] == \
                    [bytes(second.uuid)]
                result = board.reply(result_request, impl.GetResultService.Response)
                assert result.status == GoalStatus.STATUS_CANCELED
            finally:
                board.reset()
            assert agent.proc.poll() is None
    finally:
        server.close()


@pytest.mark.timeout(150)
@pytest.mark.parametrize("link", LINKS)
def test_board_reset_with_a_goal_in_flight(link, ros_peer, ros_domain, pty_pair):  # noqa: F811
    from action_msgs.msg import GoalStatus
    from action_msgs.srv import CancelGoal
    from rclpy.action import ActionClient
    from test_msgs.action import Fibonacci

    with board_link(link, pty_pair) as (agent, channel):
        board = RclcActionPeer(channel, ros_domain, feedback_period=0.2)
        client = ActionClient(ros_peer.node, Fibonacci, "/mcu/fibonacci")
        try:
            _booted(board)
            assert wait_until(client.server_is_ready, 20)
            lost = []
            handle = _done(client.send_goal_async(Fibonacci.Goal(order=40), lambda message: (
                lost.append(list(message.feedback.sequence)))))
            assert handle.accepted
            lost_result = handle.get_result_async()
            assert wait_until(lambda: len(lost) >= 2, 10)

            board.reset()  # power cut mid-goal: nothing more from this boot
            board = RclcActionPeer(channel, ros_domain, boot=1)
            # rmw_microxrcedds creates everything again with REUSE|REPLACE: the agent kept it.
            _booted(board, (C.STATUS_OK_MATCHED,))
            assert client.server_is_ready()

            # The rebooted board does not know the goal: its cancel says so, and nothing
            # answers the lost goal's result with an outcome the board never produced.
            cancel = _done(handle.cancel_goal_async())
            assert cancel.return_code == CancelGoal.Response.ERROR_UNKNOWN_GOAL_ID
            feedbacks_then = len(lost)
            time.sleep(0.5)
            assert len(lost) == feedbacks_then and not lost_result.done()

            fresh = []
            handle = _done(client.send_goal_async(Fibonacci.Goal(order=6), lambda message: (
                fresh.append(list(message.feedback.sequence)))))
            assert handle.accepted
            result = _done(handle.get_result_async())
            assert (result.status, list(result.result.sequence)) == \
                (GoalStatus.STATUS_SUCCEEDED, [0, 1, 1, 2, 3, 5])
            assert wait_until(lambda: len(fresh) >= 4, 5) and fresh == FEEDBACKS
        finally:
            client.destroy()
            board.reset()
        assert agent.proc.poll() is None


# ---------------------------------------------------------- the mapping and the middleware alone

FIBONACCI = "test_msgs::action::dds_::Fibonacci_"


def test_action_parts_map_onto_rclpys_action_classes():
    from action_msgs.srv import CancelGoal
    from test_msgs.action import Fibonacci

    from xrce.agent.middleware import UnknownTypeError
    from xrce.agent.middleware.ros.raw_types import raw_message_type
    from xrce.agent.middleware.ros.types import message_class, service_class

    impl = Fibonacci.Impl
    assert service_class(FIBONACCI + "SendGoal_Request_") is impl.SendGoalService
    assert service_class(FIBONACCI + "SendGoal_Response_") is impl.SendGoalService
    assert service_class(FIBONACCI + "GetResult_Request_") is impl.GetResultService
    assert service_class("action_msgs::srv::dds_::CancelGoal_Request_") is CancelGoal
    assert message_class(FIBONACCI + "FeedbackMessage_") is impl.FeedbackMessage
    assert message_class(FIBONACCI + "Goal_") is Fibonacci.Goal
    # What the agent publishes feedback with: the C type support alone (the tests above see
    # rclpy's ActionClient take those samples).
    raw = raw_message_type(FIBONACCI + "FeedbackMessage_")
    assert (raw.__module__, raw.__name__) == ("test_msgs.action", "Fibonacci_FeedbackMessage")
    for wrong, call in ((FIBONACCI + "FeedbackMessage_", service_class),
                        (FIBONACCI + "SendGoal_Request_", raw_message_type),
                        (FIBONACCI + "Cancel_Request_", service_class),
                        ("test_msgs::action::dds_::NoSuchAction_SendGoal_Request_", service_class)):
        with pytest.raises(UnknownTypeError):
            call(wrong)


async def test_result_requests_wait_for_the_goal_beyond_the_request_timeout(
        ros_domain, ros_peer):  # noqa: F811
    """A get_result request is answered when the goal ends, which may be long after the agent's
    request timeout: neither the replier (board = action server) nor the requester (board =
    action client) gives up on it, as rcl_action does not; a plain service's request still does."""
    from rclpy.serialization import deserialize_message, serialize_message
    from test_msgs.action import Fibonacci

    from xrce.agent.middleware import EndpointQosSpec, ServiceSpec
    from xrce.agent.middleware.ros.ros_middleware import RosMiddleware
    from ros_helpers import async_wait_until

    impl = Fibonacci.Impl
    qos = EndpointQosSpec(reliable=True, keep_last=True, depth=10, durability="volatile")
    request_t, reply_t = FIBONACCI + "GetResult_Request_", FIBONACCI + "GetResult_Response_"
    mw = RosMiddleware(request_timeout_s=0.3)
    await mw.start()
    try:
        mw.create_participant((1, 0x01), ros_domain, "board")
        pending = []
        mw.create_replier((1, 0x18), (1, 0x01), ServiceSpec(
            "/board/fib/_action/get_result", request_t, reply_t), qos,
            lambda identity, body: pending.append(identity))
        client = ros_peer.node.create_client(impl.GetResultService, "/board/fib/_action/get_result")
        assert await async_wait_until(client.service_is_ready)
        future = client.call_async(impl.GetResultService.Request())
        assert await async_wait_until(lambda: pending)
        await asyncio.sleep(0.8)
        answer = impl.GetResultService.Response(status=4)
        answer.result.sequence = [0, 1, 1]
        assert mw.write_reply((1, 0x18), pending[0], serialize_message(answer)[4:])
        assert await async_wait_until(future.done)
        assert list(future.result().result.sequence) == [0, 1, 1] and mw.requests_timed_out == 0

        def late_result(_request, response):  # the goal ends 0.8 s after the request
            time.sleep(0.8)
            response.status = 4
            response.result.sequence = [0, 1]
            return response

        ros_peer.node.create_service(impl.GetResultService, "/server/fib/_action/get_result",
                                     late_result)
        replies = []
        mw.create_requester((1, 0x27), (1, 0x01), ServiceSpec(
            "/server/fib/_action/get_result", request_t, reply_t), qos,
            lambda correlation, body: replies.append(body))
        assert mw.write_request((1, 0x27), 7, serialize_message(
            impl.GetResultService.Request())[4:])
        assert await async_wait_until(lambda: replies, 10)
        result = deserialize_message(b"\x00\x01\x00\x00" + replies[0], impl.GetResultService.Response)
        assert list(result.result.sequence) == [0, 1] and mw.requests_timed_out == 0
    finally:
        await mw.close()


async def test_an_action_of_a_package_the_wheels_do_not_carry(ros_domain, ros_peer):  # noqa: F811
    """turtlebot3_msgs' Patrol.action (built from xrce's interface directory, not in any wheel):
    a board's send_goal replier and feedback writer of that action reach an rclpy ActionClient."""
    from rclpy.action import ActionClient
    from rclpy.serialization import deserialize_message, serialize_message

    from xrce.agent import interfaces
    from xrce.agent.middleware import EndpointQosSpec, ServiceSpec, TopicSpec
    from xrce.agent.middleware.ros.ros_middleware import RosMiddleware
    from ros_helpers import async_wait_until

    interfaces.build(names=["turtlebot3_msgs"])  # a cache hit after the first time
    from turtlebot3_msgs.action import Patrol

    patrol = "turtlebot3_msgs::action::dds_::Patrol_"
    qos = EndpointQosSpec(reliable=True, keep_last=True, depth=10, durability="volatile")
    status_qos = EndpointQosSpec(reliable=True, keep_last=True, depth=1,
                                 durability="transient_local")
    mw = RosMiddleware()
    await mw.start()
    client = ActionClient(ros_peer.node, Patrol, "/tb3/patrol")
    try:
        board = (1, 0x01)
        mw.create_participant(board, ros_domain, "tb3")
        goals = []
        repliers = {}
        for index, (part, request_t, reply_t) in enumerate((
                ("send_goal", patrol + "SendGoal_Request_", patrol + "SendGoal_Response_"),
                ("cancel_goal", "action_msgs::srv::dds_::CancelGoal_Request_",
                 "action_msgs::srv::dds_::CancelGoal_Response_"),
                ("get_result", patrol + "GetResult_Request_", patrol + "GetResult_Response_"))):
            repliers[part] = (1, 0x08 | (index + 1) << 4)
            mw.create_replier(repliers[part], board, ServiceSpec(
                "/tb3/patrol/_action/" + part, request_t, reply_t), qos,
                lambda identity, body, part=part: goals.append((part, identity, body)))
        writers = {}
        for index, (part, type_name, endpoint_qos) in enumerate((
                ("feedback", patrol + "FeedbackMessage_", qos),
                ("status", "action_msgs::msg::dds_::GoalStatusArray_", status_qos))):
            base = 0x100 * (index + 1)
            mw.create_topic((1, base | 0x02), board, TopicSpec("rt/tb3/patrol/_action/" + part,
                                                              type_name))
            mw.create_publisher((1, base | 0x03), board)
            mw.create_datawriter((1, base | 0x05), (1, base | 0x03), (1, base | 0x02),
                                 endpoint_qos)
            writers[part] = (1, base | 0x05)
        assert await async_wait_until(client.server_is_ready, 20)
        feedback = []
        sent = client.send_goal_async(Patrol.Goal(radius=0.5),
                                      lambda message: feedback.append(message.feedback.left_time))
        assert await async_wait_until(lambda: goals, 10)
        part, identity, body = goals[0]
        request = deserialize_message(b"\x00\x01\x00\x00" + body, Patrol.Impl.SendGoalService.Request)
        assert part == "send_goal" and request.goal.radius == 0.5
        assert mw.write_reply(repliers["send_goal"], identity, serialize_message(
            Patrol.Impl.SendGoalService.Response(accepted=True))[4:])
        assert await async_wait_until(sent.done, 10) and sent.result().accepted
        message = Patrol.Impl.FeedbackMessage(goal_id=request.goal_id)
        message.feedback.left_time = 3.5
        for _attempt in range(50):  # the first samples may predate matching
            assert mw.write(writers["feedback"], serialize_message(message)[4:])
            if await async_wait_until(lambda: feedback, 0.2):
                break
        assert feedback and feedback[0] == 3.5
    finally:
        client.destroy()
        await mw.close()


async def test_unanswered_result_requests_are_bounded(ros_domain, ros_peer):  # noqa: F811
    """A board that never answers get_result (it reset, or it is hostile) does not make the agent
    hold ROS-side requests without bound: the oldest beyond MAX_HELD_RESULT_REQUESTS goes."""
    from test_msgs.action import Fibonacci

    from xrce.agent.middleware import EndpointQosSpec, ServiceSpec
    from xrce.agent.middleware.ros.ros_middleware import RosMiddleware
    from xrce.agent.middleware.ros.services import MAX_HELD_RESULT_REQUESTS
    from ros_helpers import async_wait_until

    impl = Fibonacci.Impl
    mw = RosMiddleware(request_timeout_s=0.3)
    await mw.start()
    try:
        mw.create_participant((1, 0x01), ros_domain, "board")
        taken = []
        mw.create_replier((1, 0x18), (1, 0x01), ServiceSpec(
            "/board/fib/_action/get_result", FIBONACCI + "GetResult_Request_",
            FIBONACCI + "GetResult_Response_"),
            EndpointQosSpec(reliable=True, keep_last=True, depth=1000, durability="volatile"),
            lambda identity, body: taken.append(identity))
        from rclpy.qos import QoSProfile

        client = ros_peer.node.create_client(impl.GetResultService,
                                             "/board/fib/_action/get_result",
                                             qos_profile=QoSProfile(depth=1000))
        assert await async_wait_until(client.service_is_ready)
        extra = 20
        for _ in range(MAX_HELD_RESULT_REQUESTS + extra):
            client.call_async(impl.GetResultService.Request())
            await asyncio.sleep(0.002)
        assert await async_wait_until(lambda: len(taken) == MAX_HELD_RESULT_REQUESTS + extra,
                                      20), len(taken)
        record = mw.records.get((1, 0x18))
        assert len(record.pending) == MAX_HELD_RESULT_REQUESTS
        assert mw.requests_timed_out == extra
        # The oldest went; the newest can still be answered.
        assert taken[0] not in record.pending and taken[-1] in record.pending
    finally:
        await mw.close()
