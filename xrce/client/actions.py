# ROS 2 actions on a client node, as rclc_action gives micro-ROS firmware: an action server whose
# goal handles publish feedback and end with a result (succeeded, aborted, canceled), and an action
# client that sends goals, takes their feedback, asks for their result and cancels them.
#
#     from xrce.msgs.test_msgs import Fibonacci
#     server = ActionServer(session, node, "/fibonacci", Fibonacci, on_goal, on_cancel, max_goals=2)
#     def on_goal(goal):            # a GoalHandle; goal.goal is the request (Fibonacci.Goal)
#         return goal.goal.order < 50    # accept (True) or reject
#     ... in the firmware's loop, for each goal in server.active(): goal.publish_feedback(feedback),
#     and at the end goal.succeed(result) / goal.abort(result) / goal.canceled(result) (the last
#     once goal.cancel_requested).
#
#     client = ActionClient(session, node, "/fibonacci", Fibonacci, max_goals=2)
#     goal = client.send_goal(Fibonacci.Goal(order=5), on_feedback=f, on_result=r)
#     ... goal.accepted, goal.status, goal.result; goal.cancel()
#
# The DDS side is rmw_microxrcedds' and rclc's (tests/golden/microros/actions_params.jsonl):
# repliers (server) or requesters (client) '<action>/_action/send_goal', '.../cancel_goal',
# '.../get_result' with the action's SendGoal/GetResult types and action_msgs' CancelGoal, a
# reliable keep-last 10 'rt/<action>/_action/feedback' of the FeedbackMessage type, and a reliable
# transient-local keep-last 1 'rt/<action>/_action/status' (GoalStatusArray). rclc creates the status
# writer and, in the capture, never writes it; this server publishes every goal's status on each
# change, as rclcpp and rclpy servers do, so `ros2 action` and rclpy goal handles see the states.
#
# The client follows a goal through its replies (acceptance, cancel, result) and its feedback, not
# through the status topic: a GoalStatusArray holds every goal of the server, which a board need not
# decode to know its own.
#
# Bounded: a server holds at most ``max_goals`` goals (a finished goal keeps its slot, and its result
# for a late get_result, until a new goal needs the slot); a client has at most ``max_goals`` goals in
# flight. A board loads this module only when it makes an action server or client
# (bench/micropython/client_footprint.py states its cost).

from xrce import const, ticks_us
from xrce.msgs import action_msgs

_UNKNOWN = const(0)
_ACCEPTED = const(1)
_EXECUTING = const(2)
_CANCELING = const(3)
_SUCCEEDED = const(4)
_CANCELED = const(5)
_ABORTED = const(6)
_CANCEL_NONE = const(0)
_CANCEL_REJECTED = const(1)
_CANCEL_UNKNOWN_GOAL = const(2)
_CANCEL_TERMINATED = const(3)
_FEEDBACK_DEPTH = const(10)
_RESULT_WAITERS = const(2)  # get_result requests one goal keeps (rclpy sends one)
_ZERO_UUID = bytes(16)

STATUS_NAMES = ("unknown", "accepted", "executing", "canceling", "succeeded", "canceled", "aborted")


def _service_names(name):
    if not name.startswith("/"):
        name = "/" + name
    return name, name + "/_action/send_goal", name + "/_action/cancel_goal", name + "/_action/get_result"


def _stamp_into(time_msg, ns):
    time_msg.sec = ns // 1000000000
    time_msg.nanosec = ns % 1000000000


def _ns(time_msg):
    return time_msg.sec * 1000000000 + time_msg.nanosec


def new_goal_id():
    # 16 random bytes. MicroPython ports without os.urandom have random.getrandbits, seeded per
    # boot on most; the microsecond clock is mixed in so that two boards seeded alike still differ.
    try:
        from os import urandom

        return urandom(16)
    except ImportError:
        import random

        out = bytearray(16)
        mix = ticks_us()
        for i in range(16):
            out[i] = (random.getrandbits(8) ^ (mix >> (i % 4 * 8))) & 0xFF
        return bytes(out)


# ------------------------------------------------------------------ server

class GoalHandle:
    # One goal on an ActionServer. ``goal`` is the request's Goal message, ``goal_id`` its 16-byte
    # UUID, ``status`` one of action_msgs/GoalStatus's numbers (STATUS_NAMES).

    def __init__(self, server, goal_id, goal, stamp_ns):
        self.server = server
        self.goal_id = goal_id
        self.goal = goal
        self.stamp_ns = stamp_ns
        self.status = _ACCEPTED
        self.result = None
        self._waiting = []  # sample identities of get_result requests not yet answered

    @property
    def active(self):
        return self.status < _SUCCEEDED

    @property
    def cancel_requested(self):
        return self.status == _CANCELING

    def publish_feedback(self, feedback):
        server = self.server
        message = server._feedback_message
        message.goal_id.uuid = self.goal_id
        message.feedback = feedback
        return server.session.write(server.feedback_writer, message, server.stream_id)

    def succeed(self, result):
        self._finish(_SUCCEEDED, result)

    def abort(self, result):
        self._finish(_ABORTED, result)

    def canceled(self, result):
        self._finish(_CANCELED, result)

    def _finish(self, status, result):
        if not self.active:
            raise ValueError("goal already %s" % STATUS_NAMES[self.status])
        self.status = status
        self.result = result
        server = self.server
        for identity in self._waiting:
            server._send_result(identity, self)
        self._waiting = []
        server.publish_status()


class ActionServer:
    # ``on_goal(goal_handle)`` -> truthy to accept (the goal then executes); ``on_cancel(goal_handle)``
    # -> truthy to accept a cancel request (the goal is then canceling until ``canceled``); without
    # ``on_cancel`` every cancel request of an active goal is accepted.

    def __init__(self, session, node_id, name, action, on_goal, on_cancel=None, max_goals=2,
                 stream_id=None):
        self.session = session
        self.action = action
        self.on_goal = on_goal
        self.on_cancel = on_cancel
        self.stream_id = stream_id
        self.goals = [None] * max_goals
        self.name, send_goal, cancel_goal, get_result = _service_names(name)
        self.send_goal_replier = session.create_service_server(
            node_id, send_goal, action.SendGoal, self._on_send_goal, stream_id=stream_id)
        self.cancel_replier = session.create_service_server(
            node_id, cancel_goal, action_msgs.CancelGoal, self._on_cancel, stream_id=stream_id)
        self.result_replier = session.create_service_server(
            node_id, get_result, action.GetResult, self._on_get_result, stream_id=stream_id)
        self.feedback_writer = session.create_writer(
            node_id, self.name + "/_action/feedback", action.FeedbackMessage, reliable=True,
            depth=_FEEDBACK_DEPTH, stream_id=stream_id)
        self.status_writer = session.create_writer(
            node_id, self.name + "/_action/status", action_msgs.GoalStatusArray, reliable=True,
            depth=1, transient_local=True, stream_id=stream_id)
        self._feedback_message = action.FeedbackMessage()

    def active(self):
        # The goals accepted and not yet finished (executing or canceling).
        return [g for g in self.goals if g is not None and g.active]

    def _find(self, goal_id):
        for goal in self.goals:
            if goal is not None and goal.goal_id == goal_id:
                return goal
        return None

    def _free_slot(self):
        # An empty slot, else the one of the goal that finished first (its result expires).
        oldest = None
        for i in range(len(self.goals)):
            goal = self.goals[i]
            if goal is None:
                return i
            if not goal.active and (oldest is None or goal.stamp_ns < self.goals[oldest].stamp_ns):
                oldest = i
        return oldest

    def _on_send_goal(self, identity, request):
        response = self.action.SendGoal.Response()
        stamp = self.session.epoch_ns()
        _stamp_into(response.stamp, stamp)
        goal_id = bytes(request.goal_id.uuid)
        slot = self._free_slot()
        if slot is not None and self._find(goal_id) is None:
            goal = GoalHandle(self, goal_id, request.goal, stamp)
            if self.on_goal(goal):
                self.goals[slot] = goal
                goal.status = _EXECUTING
                response.accepted = True
        self.session.send_reply(self.send_goal_replier, identity, response, self.stream_id)
        if response.accepted:
            self.publish_status()

    def _on_cancel(self, identity, request):
        # action_msgs/CancelGoal: a zero UUID with a zero stamp cancels every goal, a zero UUID with
        # a stamp those accepted at or before it, a UUID that goal (and, with a stamp, those too).
        info = request.goal_info
        goal_id = bytes(info.goal_id.uuid)
        before = _ns(info.stamp)
        response = action_msgs.CancelGoal.Response()
        canceling = []
        wanted = None
        if goal_id != _ZERO_UUID:
            wanted = self._find(goal_id)
            if wanted is None:
                response.return_code = _CANCEL_UNKNOWN_GOAL
            elif not wanted.active:
                response.return_code = _CANCEL_TERMINATED
        if response.return_code == _CANCEL_NONE:
            for goal in self.goals:
                if goal is None or not goal.active:
                    continue
                chosen = goal is wanted or (goal_id == _ZERO_UUID and before == 0) or (
                    before and goal.stamp_ns <= before)
                if not chosen:
                    continue
                if goal.status == _CANCELING or self.on_cancel is None or self.on_cancel(goal):
                    goal.status = _CANCELING
                    answered = action_msgs.GoalInfo()
                    answered.goal_id.uuid = goal.goal_id
                    _stamp_into(answered.stamp, goal.stamp_ns)
                    canceling.append(answered)
            if not canceling:
                response.return_code = _CANCEL_REJECTED
        response.goals_canceling = canceling
        self.session.send_reply(self.cancel_replier, identity, response, self.stream_id)
        if canceling:
            self.publish_status()

    def _on_get_result(self, identity, request):
        goal = self._find(bytes(request.goal_id.uuid))
        if goal is None or not goal.active:
            self._send_result(identity, goal)
            return
        if len(goal._waiting) >= _RESULT_WAITERS:
            goal._waiting.pop(0)  # bounded: the oldest asker is the one to give up on
        goal._waiting.append(identity)

    def _send_result(self, identity, goal):
        # A finished goal's status and result; for a goal this server does not hold, status unknown
        # and an empty result (as rcl answers).
        response = self.action.GetResult.Response()
        if goal is not None:
            response.status = goal.status
            if goal.result is not None:
                response.result = goal.result
        self.session.send_reply(self.result_replier, identity, response, self.stream_id)

    def publish_status(self):
        statuses = []
        for goal in self.goals:
            if goal is None:
                continue
            status = action_msgs.GoalStatus(status=goal.status)
            status.goal_info.goal_id.uuid = goal.goal_id
            _stamp_into(status.goal_info.stamp, goal.stamp_ns)
            statuses.append(status)
        self.session.write(self.status_writer, action_msgs.GoalStatusArray(status_list=statuses),
                           self.stream_id)


# ------------------------------------------------------------------ client

class ClientGoal:
    # One goal sent by an ActionClient: ``accepted`` is None until the server answered, ``status``
    # follows GetResult's answer (and ``cancel``'s acceptance), ``result`` is the Result message.

    def __init__(self, client, goal_id, on_feedback, on_result):
        self.client = client
        self.goal_id = goal_id
        self.on_feedback = on_feedback
        self.on_result = on_result
        self.accepted = None
        self.stamp_ns = 0
        self.status = _UNKNOWN
        self.result = None
        self.cancel_return_code = None
        self._result_asked = False

    @property
    def done(self):
        # Rejected, or its result arrived.
        return self.accepted is False or self.result is not None

    def get_result(self):
        # Ask for the result (answered when the goal ends); ``on_result(goal)`` then runs.
        if self._result_asked:
            return
        self._result_asked = True
        client = self.client
        request = client.action.GetResult.Request()
        request.goal_id.uuid = self.goal_id
        rid = client.session.send_request(client.result_requester, request, client.stream_id)
        client._pending[rid] = self

    def cancel(self):
        # Ask the server to cancel this goal; ``cancel_return_code`` holds its answer
        # (action_msgs/CancelGoal's ERROR_* numbers: 0 accepted).
        client = self.client
        request = action_msgs.CancelGoal.Request()
        request.goal_info.goal_id.uuid = self.goal_id
        rid = client.session.send_request(client.cancel_requester, request, client.stream_id)
        client._pending[rid] = self


class ActionClient:
    # At most ``max_goals`` goals are in flight (sent and not done); send_goal returns None past it.

    def __init__(self, session, node_id, name, action, max_goals=2, stream_id=None):
        self.session = session
        self.action = action
        self.stream_id = stream_id
        self.max_goals = max_goals
        self.goals = []
        self._pending = {}  # request id -> ClientGoal, for the replies of the three services
        self.name, send_goal, cancel_goal, get_result = _service_names(name)
        self.send_goal_requester = session.create_service_client(
            node_id, send_goal, action.SendGoal, self._on_goal_response, stream_id=stream_id)
        self.cancel_requester = session.create_service_client(
            node_id, cancel_goal, action_msgs.CancelGoal, self._on_cancel_response, stream_id=stream_id)
        self.result_requester = session.create_service_client(
            node_id, get_result, action.GetResult, self._on_result_response, stream_id=stream_id)
        self.feedback_reader = session.create_reader(
            node_id, self.name + "/_action/feedback", action.FeedbackMessage, self._on_feedback,
            reliable=True, depth=_FEEDBACK_DEPTH, stream_id=stream_id)

    def send_goal(self, goal, on_feedback=None, on_result=None):
        # ``on_feedback(client_goal, feedback)``; ``on_result(client_goal)`` once the result is in:
        # with it the result is asked for as soon as the goal is accepted.
        self.goals = [g for g in self.goals if not g.done]
        if len(self.goals) >= self.max_goals:
            return None
        handle = ClientGoal(self, new_goal_id(), on_feedback, on_result)
        request = self.action.SendGoal.Request()
        request.goal_id.uuid = handle.goal_id
        request.goal = goal
        rid = self.session.send_request(self.send_goal_requester, request, self.stream_id)
        if not rid:
            return None
        self._pending[rid] = handle
        self.goals.append(handle)
        return handle

    def _on_goal_response(self, request_id, response):
        handle = self._pending.pop(request_id, None)
        if handle is None:
            return
        handle.accepted = bool(response.accepted)
        handle.stamp_ns = _ns(response.stamp)
        if handle.accepted:
            handle.status = _ACCEPTED
            if handle.on_result is not None:
                handle.get_result()

    def _on_cancel_response(self, request_id, response):
        handle = self._pending.pop(request_id, None)
        if handle is None:
            return
        handle.cancel_return_code = response.return_code
        for info in response.goals_canceling:
            if bytes(info.goal_id.uuid) == handle.goal_id and handle.result is None:
                handle.status = _CANCELING

    def _on_result_response(self, request_id, response):
        handle = self._pending.pop(request_id, None)
        if handle is None:
            return
        handle.status = response.status
        handle.result = response.result
        if handle.on_result is not None:
            handle.on_result(handle)

    def _on_feedback(self, message):
        goal_id = bytes(message.goal_id.uuid)
        for handle in self.goals:
            if handle.goal_id == goal_id:
                if handle.result is None and handle.accepted:
                    handle.status = _EXECUTING
                if handle.on_feedback is not None:
                    handle.on_feedback(handle, message.feedback)
                return
