"""The client's action server and client (xrce.client.actions).

Against rclc: the entities and the replies, feedback and results rclc's action server wrote for
rclpy's ActionClient in tests/golden/microros/actions_params.jsonl (a goal with four feedbacks
and its result [0, 1, 1, 2, 3, 5]; a goal of order 30 cancelled), replayed into a real client session whose
transport records what it sends; and the requests our action client writes, against the ones
rclpy's made there. End to end: under real MicroPython (tests/helpers/mp_harness.py) through a live agent.
"""

import re

import pytest

from client_capture import RclcCapture
from client_recorder import RecordingSession
from xrce.client.actions import ActionClient, ActionServer
from xrce.msgs import action_msgs
from xrce.msgs.test_msgs import Fibonacci

ACTION = "/mcu/fibonacci"
SERVICES = ("send_goal", "cancel_goal", "get_result")


@pytest.fixture(scope="module")
def rclc():
    return RclcCapture()


def _texts(body):
    return [t.decode() for t in re.findall(rb"[ -~]{4,}", body[1:])]


def _qos(body):
    # A datawriter's or datareader's representation past its topic id, without rclc's uninitialised
    # alignment byte after has-depth and without the parent's id.
    return body[10:15] + body[16:19]


def _theirs_entities(rclc):
    repliers = sorted(rclc.entities[rclc.replier(ACTION + "/_action/" + s)][1] for s in SERVICES)
    topics = {t: (rclc.entities[rclc.writer_of(t)[0]], rclc.writer_of(t)[1])
              for t in ("rt" + ACTION + "/_action/feedback", "rt" + ACTION + "/_action/status")}
    return repliers, topics


def _ours_entities(created):
    endpoints = sorted(_texts(body) for oid, body in created if body[0] in (7, 8))
    topics = [_texts(body) for oid, body in created if body[0] == 2]
    qos = [body for oid, body in created if body[0] in (5, 6)]
    return endpoints, topics, qos


def test_server_entities_are_rclcs(rclc):
    recorder = RecordingSession()
    node = recorder.session.create_participant(name="/mcu/feat_fw")
    ActionServer(recorder.session, node, ACTION, Fibonacci, lambda goal: True)
    repliers, topics = _theirs_entities(rclc)
    endpoints, our_topics, qos = _ours_entities(recorder.creations())
    assert endpoints == repliers
    assert our_topics == [texts for kind, texts, _ in rclc.entities.values()
                          if kind == 2 and texts[0] in topics]
    # Feedback reliable keep-last 10, status reliable transient-local keep-last 1.
    assert [_qos(body) for body in qos] == [_qos(topics[t][1]) for t in topics]


def test_client_entities_name_rclcs_server(rclc):
    recorder = RecordingSession()
    node = recorder.session.create_participant(name="/mcu/feat_fw")
    ActionClient(recorder.session, node, ACTION, Fibonacci)
    repliers, topics = _theirs_entities(rclc)
    endpoints, our_topics, qos = _ours_entities(recorder.creations())
    assert endpoints == repliers  # requester and replier share one representation
    assert our_topics == [["rt" + ACTION + "/_action/feedback", "test_msgs::action::dds_::Fibonacci_FeedbackMessage_"]]
    feedback_writer = topics["rt" + ACTION + "/_action/feedback"][1]
    assert qos[0][10:15] + qos[0][16:19] == _qos(feedback_writer)  # what the reader asks, the writer offers


def _decoded(cls, body):
    return cls.from_bytes(body).to_dict()


def test_server_answers_as_rclc(rclc):
    # rclc's firmware: a feedback per step (the sequence so far, from [0, 1, 1]) and the result
    # after the fourth; a cancelled goal ends canceled with an empty sequence.
    recorder = RecordingSession()
    node = recorder.session.create_participant(name="/mcu/feat_fw")
    server = ActionServer(recorder.session, node, ACTION, Fibonacci, lambda goal: True)
    recorder.take()
    send_goal = rclc.exchanges(ACTION + "/_action/send_goal")
    get_result = rclc.exchanges(ACTION + "/_action/get_result")
    cancel = rclc.exchanges(ACTION + "/_action/cancel_goal")
    feedback_writer = rclc.writer_of("rt" + ACTION + "/_action/feedback")[0]
    their_feedback = rclc.writes[feedback_writer]
    our_feedback = []

    def serve(replier, identity, request):
        # The reply (if any) the request got, and the feedback written meanwhile.
        callback, msg_class = recorder.session._readers[replier]
        callback(identity, msg_class.from_bytes(request))
        writes = recorder.writes()
        our_feedback.extend(body for oid, body in writes if oid == server.feedback_writer)
        return [body[24:] for oid, body in writes if oid == replier]

    def step(goal):
        sequence = list(goal.sequence_so_far)
        goal.sequence_so_far = sequence + [sequence[-1] + sequence[-2]] if len(sequence) > 1 else [0, 1]
        feedback = Fibonacci.Feedback(sequence=goal.sequence_so_far)
        goal.publish_feedback(feedback)

    for n, (goal_exchange, result_exchange) in enumerate(zip(send_goal, get_result)):
        reply = serve(server.send_goal_replier, bytes([n]) * 24, goal_exchange[0])
        ours_reply = _decoded(Fibonacci.SendGoal.Response, reply[0])
        theirs_reply = _decoded(Fibonacci.SendGoal.Response, goal_exchange[1])
        assert ours_reply["accepted"] == theirs_reply["accepted"] is True
        goal = server.active()[0]
        assert goal.goal.order == Fibonacci.SendGoal.Request.from_bytes(goal_exchange[0]).goal.order
        assert serve(server.result_replier, bytes([n + 10]) * 24, result_exchange[0]) == []  # waits
        goal.sequence_so_far = [0, 1]
        for _ in range(4):
            step(goal)
        if n == 0:
            goal.succeed(Fibonacci.Result(sequence=goal.sequence_so_far))
        else:
            cancel_reply = serve(server.cancel_replier, b"\x20" * 24, cancel[0][0])
            ours_cancel = _decoded(action_msgs.CancelGoal.Response, cancel_reply[0])
            theirs_cancel = _decoded(action_msgs.CancelGoal.Response, cancel[0][1])
            for answer in (ours_cancel, theirs_cancel):  # rclc stamps goals 0, this server with the clock
                for info in answer["goals_canceling"]:
                    info.pop("stamp")
            assert ours_cancel == theirs_cancel and goal.cancel_requested
            goal.canceled(Fibonacci.Result())
        writes = recorder.writes()
        our_feedback.extend(body for oid, body in writes if oid == server.feedback_writer)
        results = [body[24:] for oid, body in writes if oid == server.result_replier]
        assert [_decoded(Fibonacci.GetResult.Response, r) for r in results] == \
            [_decoded(Fibonacci.GetResult.Response, result_exchange[1])]
    assert our_feedback == their_feedback


def test_client_asks_as_rclpy_did(rclc):
    recorder = RecordingSession()
    node = recorder.session.create_participant(name="/mcu/feat_fw")
    client = ActionClient(recorder.session, node, ACTION, Fibonacci, max_goals=2)
    recorder.take()
    results, feedbacks = [], []
    theirs_request = Fibonacci.SendGoal.Request.from_bytes(rclc.exchanges(ACTION + "/_action/send_goal")[0][0])
    goal = client.send_goal(Fibonacci.Goal(order=theirs_request.goal.order), on_feedback=lambda g, f: feedbacks.append(list(f.sequence)),
                            on_result=results.append)
    sent = recorder.writes()
    assert [oid for oid, _ in sent] == [client.send_goal_requester]
    ours_request = Fibonacci.SendGoal.Request.from_bytes(sent[0][1])
    assert ours_request.goal.order == theirs_request.goal.order and bytes(ours_request.goal_id.uuid) == goal.goal_id
    assert len(set(goal.goal_id)) > 1  # a random UUID, not zeros

    def reply(requester, body):
        callback, msg_class = recorder.session._readers[requester]
        request_id = [rid for rid, g in client._pending.items() if g is goal][0]
        callback(request_id, msg_class.from_bytes(body))

    # rclc's acceptance: the client asks for the result at once (on_result given).
    reply(client.send_goal_requester, rclc.exchanges(ACTION + "/_action/send_goal")[0][1])
    assert goal.accepted is True
    sent = recorder.writes()
    assert [oid for oid, _ in sent] == [client.result_requester]
    assert bytes(Fibonacci.GetResult.Request.from_bytes(sent[0][1]).goal_id.uuid) == goal.goal_id
    # Feedback reaches the goal it names (rclc's feedback samples, renamed to this goal).
    for body in rclc.writes[rclc.writer_of("rt" + ACTION + "/_action/feedback")[0]][:4]:
        client._on_feedback(Fibonacci.FeedbackMessage.from_bytes(goal.goal_id + body[16:]))
    client._on_feedback(Fibonacci.FeedbackMessage.from_bytes(bytes(16) + body[16:]))  # someone else's
    assert feedbacks == [[0, 1, 1], [0, 1, 1, 2], [0, 1, 1, 2, 3], [0, 1, 1, 2, 3, 5]]
    reply(client.result_requester, rclc.exchanges(ACTION + "/_action/get_result")[0][1])
    assert results == [goal] and goal.status == 4 and list(goal.result.sequence) == [0, 1, 1, 2, 3, 5]

    # Cancelling: the request names the goal with a zero stamp, as rclpy's did.
    second = client.send_goal(Fibonacci.Goal(order=30))
    recorder.take()
    second.cancel()
    sent = recorder.writes()
    cancel_request = action_msgs.CancelGoal.Request.from_bytes(sent[0][1])
    theirs_cancel = action_msgs.CancelGoal.Request.from_bytes(rclc.exchanges(ACTION + "/_action/cancel_goal")[0][0])
    assert bytes(cancel_request.goal_info.goal_id.uuid) == second.goal_id
    assert cancel_request.goal_info.stamp.to_dict() == theirs_cancel.goal_info.stamp.to_dict()


def test_server_bounds_and_cancel_rules():
    recorder = RecordingSession()
    node = recorder.session.create_participant(name="fw")
    refused = []
    server = ActionServer(recorder.session, node, "/fib", Fibonacci, lambda goal: goal.goal.order >= 0,
                          on_cancel=lambda goal: goal.goal.order != 13 or refused.append(goal), max_goals=2)
    recorder.take()

    def send(order, uuid):
        request = Fibonacci.SendGoal.Request()
        request.goal_id.uuid, request.goal.order = uuid, order
        return Fibonacci.SendGoal.Response.from_bytes(
            recorder.serve(server.send_goal_replier, uuid + bytes(8), request.to_bytes())).accepted

    def cancel(uuid, sec=0):
        request = action_msgs.CancelGoal.Request()
        request.goal_info.goal_id.uuid, request.goal_info.stamp.sec = uuid, sec
        return action_msgs.CancelGoal.Response.from_bytes(
            recorder.serve(server.cancel_replier, uuid + bytes(8), request.to_bytes()))

    a, b, c = bytes([1] * 16), bytes([2] * 16), bytes([3] * 16)
    assert send(-1, a) is False  # on_goal refused
    assert send(5, a) and send(13, b)
    assert send(7, c) is False  # both slots hold active goals
    statuses = [action_msgs.GoalStatusArray.from_bytes(body) for oid, body in recorder.last_writes
                if oid == server.status_writer]
    assert statuses == []  # a refused goal changes no status
    assert cancel(bytes([9] * 16)).return_code == 2  # unknown goal
    response = cancel(bytes(16))  # every goal: 13 refuses
    assert response.return_code == 0 and [bytes(i.goal_id.uuid) for i in response.goals_canceling] == [a]
    assert refused and server.active()[1].status == 2
    status = [action_msgs.GoalStatusArray.from_bytes(body) for oid, body in recorder.last_writes
              if oid == server.status_writer][-1]
    assert [(bytes(s.goal_info.goal_id.uuid), s.status) for s in status.status_list] == [(a, 3), (b, 2)]
    server.active()[0].canceled(Fibonacci.Result())
    assert cancel(a).return_code == 3  # terminated
    assert cancel(b).return_code == 1  # on_cancel refused
    with pytest.raises(ValueError):
        server.goals[0].succeed(Fibonacci.Result())
    # A finished goal's slot goes to a new goal; its result is then gone (status unknown).
    assert send(7, c)
    result = Fibonacci.GetResult.Request()
    result.goal_id.uuid = a
    answer = Fibonacci.GetResult.Response.from_bytes(recorder.serve(server.result_replier, a + bytes(8), result.to_bytes()))
    assert answer.status == 0 and list(answer.result.sequence) == []


# ---------------------------------------------------------------------------- end to end

import threading  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from agent_process import AgentProcess  # noqa: E402
from mp_harness import run_micropython  # noqa: E402
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: E402,F401

BOARD = Path(__file__).resolve().parents[1] / "micropython" / "action_board.py"


def _board(agent, domain, role, seconds=60):
    result = {}
    runner = threading.Thread(target=lambda: result.setdefault(
        "run", run_micropython(BOARD, agent.port, domain, role, seconds, timeout=seconds + 60)), daemon=True)
    runner.start()
    return runner, result


def _lines(run):
    assert run.returncode == 0, run.stdout + run.stderr
    lines = dict(line.split(" ", 1) for line in run.stdout.splitlines() if " " in line)
    assert lines["connect"] == lines["setup"] == lines["done"] == "True", run.stdout
    return lines


def _done(future, seconds=30.0):
    assert wait_until(future.done, seconds), "no answer in %.0f s" % seconds
    return future.result()


def _check_feedback(received, result, order):
    # The sequence so far, one step at a time, each a step further than the one before, up to the
    # result. rclpy's ActionClient drops feedback that reaches it before the goal's acceptance or
    # after its result (feedback is a topic, those are service replies: nothing orders them), so the
    # first and the last step may be missing on a loaded machine; the steps between may not.
    result = list(result)
    lengths = [len(sequence) for sequence in received]
    assert all(sequence == result[:len(sequence)] for sequence in received), received
    assert lengths == list(range(lengths[0], lengths[0] + len(lengths))), lengths
    assert lengths[0] <= 4 and lengths[-1] >= order, (lengths, order)


@pytest.mark.timeout(240)
def test_rclpy_action_client_against_the_board_under_micropython(ros_peer, ros_domain):  # noqa: F811
    from action_msgs.msg import GoalStatus
    from rclpy.action import ActionClient as RosActionClient
    from test_msgs.action import Fibonacci as RosFibonacci

    client = RosActionClient(ros_peer.node, RosFibonacci, "/fibonacci")
    with AgentProcess("udp4", "-m", "dds") as agent:
        runner, result = _board(agent, ros_domain, "server", 120)
        try:
            assert client.wait_for_server(60), "the board's action server never appeared"
            feedback = {}

            def send(order):
                future = client.send_goal_async(
                    RosFibonacci.Goal(order=order),
                    feedback_callback=lambda m, o=order: feedback.setdefault(o, []).append(list(m.feedback.sequence)))
                return _done(future)

            # A goal with feedback and result.
            handle = send(5)
            assert handle.accepted
            outcome = _done(handle.get_result_async())
            assert outcome.status == GoalStatus.STATUS_SUCCEEDED and list(outcome.result.sequence) == [0, 1, 1, 2, 3, 5]
            _check_feedback(feedback[5], outcome.result.sequence, 5)
            # A rejected goal.
            assert not send(-3).accepted
            # A cancelled goal.
            handle = send(30)
            assert wait_until(lambda: len(feedback.get(30, ())) >= 2, 30)
            cancel = _done(handle.cancel_goal_async())
            assert cancel.return_code == 0 and [bytes(g.goal_id.uuid) for g in cancel.goals_canceling] == [
                bytes(handle.goal_id.uuid)]
            outcome = _done(handle.get_result_async())
            assert outcome.status == GoalStatus.STATUS_CANCELED and len(outcome.result.sequence) >= 4
            # An aborted goal.
            handle = send(45)
            outcome = _done(handle.get_result_async())
            assert outcome.status == GoalStatus.STATUS_ABORTED and list(outcome.result.sequence) == [0, 1, 1, 2]
            # Two goals at once; a third while both run is refused (max_goals=2).
            first, second = send(8), send(9)
            assert first.accepted and second.accepted and not send(7).accepted
            outcomes = [_done(h.get_result_async()) for h in (first, second)]
            assert [(o.status, len(o.result.sequence)) for o in outcomes] == [
                (GoalStatus.STATUS_SUCCEEDED, 9), (GoalStatus.STATUS_SUCCEEDED, 10)]
            for order, outcome in zip((8, 9), outcomes):
                _check_feedback(feedback[order], outcome.result.sequence, order)
            assert handle.status == GoalStatus.STATUS_ABORTED  # followed /_action/status
            send(1000)  # ends the board's run
        finally:
            runner.join(150)
    lines = _lines(result["run"])
    assert lines["goals"] == "5:succeeded,30:canceled,45:aborted,8:succeeded,9:succeeded", lines["goals"]


def _cpython_session(agent, domain, name):
    from xrce.client.session import Session
    from xrce.transports.udp import UdpTransport

    session = Session(UdpTransport("127.0.0.1", agent.port), history=8)
    assert session.create(attempts=5, timeout_ms=1000)
    return session, session.create_participant(domain_id=domain, name=name)


def _spin_until(session, predicate, seconds=30.0):
    deadline = time.monotonic() + seconds
    while not predicate() and time.monotonic() < deadline:
        session.spin_once(20)
    return predicate()


@pytest.mark.timeout(240)
def test_board_server_and_cpython_client_through_the_agent(ros_domain):  # noqa: F811
    # Both ends ours, through a live agent's own routing (-m ced): the board's server (MicroPython)
    # with this process's ActionClient, every outcome and two goals at once.
    with AgentProcess("udp4", "-m", "ced") as agent:
        runner, result = _board(agent, ros_domain, "server", 120)
        session, node = _cpython_session(agent, ros_domain, "fib_cpython_client")
        try:
            client = ActionClient(session, node, "/fibonacci", Fibonacci, max_goals=2)
            assert session.run_until_all_status(5000)
            feedback = {}

            def send(order):
                goal = None
                deadline = time.monotonic() + 60
                while time.monotonic() < deadline:  # until the board's server is up
                    goal = client.send_goal(Fibonacci.Goal(order=order),
                                            on_feedback=lambda g, f: feedback.setdefault(order, []).append(len(f.sequence)),
                                            on_result=lambda g: None)
                    if _spin_until(session, lambda: goal.accepted is not None, 2):
                        return goal
                    client.goals.remove(goal)
                raise AssertionError("no answer to goal %d" % order)

            goal = send(5)
            assert goal.accepted and _spin_until(session, lambda: goal.done)
            assert goal.status == 4 and list(goal.result.sequence) == [0, 1, 1, 2, 3, 5] and feedback[5] == [3, 4, 5, 6]
            assert send(-1).accepted is False
            goal = send(30)
            assert _spin_until(session, lambda: len(feedback.get(30, ())) >= 2)
            goal.cancel()
            assert _spin_until(session, lambda: goal.done) and goal.status == 5 and goal.cancel_return_code == 0
            goal = send(45)
            assert _spin_until(session, lambda: goal.done) and goal.status == 6
            first, second = send(8), send(9)
            assert client.send_goal(Fibonacci.Goal(order=1)) is None  # two in flight already
            assert _spin_until(session, lambda: first.done and second.done)
            assert [(g.status, len(g.result.sequence)) for g in (first, second)] == [(4, 9), (4, 10)]
            client.send_goal(Fibonacci.Goal(order=1000))
            session.run_until_timeout(500)
        finally:
            runner.join(150)
            session.delete(attempts=2, timeout_ms=500)
            session.close()
    lines = _lines(result["run"])
    assert lines["goals"] == "5:succeeded,30:canceled,45:aborted,8:succeeded,9:succeeded", lines["goals"]


@pytest.mark.timeout(240)
def test_board_client_and_cpython_server_through_the_agent(ros_domain):  # noqa: F811
    # The board's ActionClient (MicroPython) against this process's ActionServer, through -m ced.
    with AgentProcess("udp4", "-m", "ced") as agent:
        session, node = _cpython_session(agent, ros_domain, "fib_cpython_server")
        server = ActionServer(session, node, "/fibonacci", Fibonacci, lambda goal: True, max_goals=2)
        assert session.run_until_all_status(5000)
        runner, result = _board(agent, ros_domain, "client", 90)
        sequences = {}
        try:
            last = time.monotonic()
            while runner.is_alive():
                session.spin_once(10)
                if time.monotonic() - last < 0.1:
                    continue
                last = time.monotonic()
                for goal in server.active():
                    sequence = sequences.setdefault(goal.goal_id, [0, 1])
                    if goal.cancel_requested:
                        goal.canceled(Fibonacci.Result(sequence=sequence))
                        continue
                    sequence.append(sequence[-1] + sequence[-2])
                    goal.publish_feedback(Fibonacci.Feedback(sequence=sequence))
                    if len(sequence) >= goal.goal.order + 1:
                        goal.succeed(Fibonacci.Result(sequence=sequence))
        finally:
            runner.join(120)
            session.delete(attempts=2, timeout_ms=500)
            session.close()
    lines = _lines(result["run"])
    assert lines["first"] == "True succeeded [0, 1, 1, 2, 3, 5] 4", lines["first"]
    assert lines["second"] == "True canceled 0", lines["second"]
    assert lines["third"] == "True"
    assert lines["both"] == "succeeded,[0, 1, 1, 2];succeeded,[0, 1, 1, 2, 3]", lines["both"]


@pytest.mark.timeout(240)
def test_board_action_client_against_rclpy_action_server(ros_peer, ros_domain):  # noqa: F811
    # The board's ActionClient (MicroPython) against rclpy's ActionServer through -m dds: feedback
    # and result, a cancelled goal, two goals at once.
    from rclpy.action import ActionServer as RosActionServer, CancelResponse
    from rclpy.callback_groups import ReentrantCallbackGroup
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.node import Node
    from test_msgs.action import Fibonacci as RosFibonacci

    def execute(goal_handle):
        sequence = [0, 1]
        while len(sequence) < goal_handle.request.order + 1:
            time.sleep(0.1)
            if goal_handle.is_cancel_requested:
                goal_handle.canceled()
                return RosFibonacci.Result(sequence=sequence)
            sequence.append(sequence[-1] + sequence[-2])
            goal_handle.publish_feedback(RosFibonacci.Feedback(sequence=sequence))
        goal_handle.succeed()
        return RosFibonacci.Result(sequence=sequence)

    node = Node("fib_ros_server", context=ros_peer.context, start_parameter_services=False,
                enable_rosout=False, use_global_arguments=False)
    RosActionServer(node, RosFibonacci, "/fibonacci", execute, callback_group=ReentrantCallbackGroup(),
                    cancel_callback=lambda request: CancelResponse.ACCEPT)
    executor = MultiThreadedExecutor(num_threads=4, context=ros_peer.context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        with AgentProcess("udp4", "-m", "dds") as agent:
            runner, result = _board(agent, ros_domain, "client", 90)
            runner.join(150)
    finally:
        executor.shutdown()
        node.destroy_node()
        spinner.join(10)
    lines = _lines(result["run"])
    # Feedback for each step but those that overtook the acceptance or the result (_check_feedback).
    assert lines["first"].startswith("True succeeded [0, 1, 1, 2, 3, 5] "), lines["first"]
    assert 2 <= int(lines["first"].rsplit(" ", 1)[1]) <= 4, lines["first"]
    assert lines["second"] == "True canceled 0", lines["second"]
    assert lines["third"] == "True"
    assert lines["both"] == "succeeded,[0, 1, 1, 2];succeeded,[0, 1, 1, 2, 3]", lines["both"]
