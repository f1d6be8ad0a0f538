"""A scripted rclc board with one action, speaking to an agent as rmw_microxrcedds does.

The entities are the ones the firmware of tests/golden/microros/actions_params.jsonl created for
its rclc action server ``/mcu/fibonacci`` (``test_msgs/action/Fibonacci``), taken from that
capture as sent: its participant, the ``_action/send_goal``, ``_action/cancel_goal`` and
``_action/get_result`` repliers and the ``_action/feedback`` / ``_action/status`` topics with their
publishers and datawriters, every CREATE with REUSE|REPLACE. As an action *client*
(``role="client"``) the board makes the same services as requesters and reads the two topics with
the QoS rcl_action gives a client's subscriptions (feedback reliable depth 10, status reliable
transient_local depth 1), as rmw_microxrcedds creates them.

The server behaves as rclc's Fibonacci example did in the capture: a goal is accepted, its
sequence grows by one number per feedback until it holds ``order`` numbers, then get_result is
answered SUCCEEDED; a cancel of a running goal is accepted (ERROR_NONE with the goal listed) and
its result is CANCELED; a cancel of a goal the board does not know gets ERROR_UNKNOWN_GOAL_ID. The
bodies are CDR made by rclpy's serializer from the generated classes (tests only).

The session is the C client's: reliable output stream 0x80 retransmitted until acknowledged,
reliable input 0x80 taken in order and acknowledged, CREATE/DELETE waited for one at a time.
"""

from __future__ import annotations

import threading
import time

from microros_replay import Capture
from xrce.wire import constants as C
from xrce.wire.objects import DataReaderBin, EndpointQos, PubSubBin, RequesterBin
from xrce.wire.submessages import (
    AckNack, Create, CreateClient, DeliveryControl, ReadData, WriteData, decode_message,
    encode_message,
)

RELIABLE = 0x80
SESSION = 0x81
ACTION = "/mcu/fibonacci"
_SERVICES = ("send_goal", "cancel_goal", "get_result")
_TOPICS = ("feedback", "status")


def _creates_from_capture() -> dict:
    """The firmware's CREATEs for the action, as decoded from the capture: {"participant": ...,
    "send_goal": replier, ..., "feedback": [topic, publisher, datawriter], "status": [...]}."""
    capture = Capture("actions_params")
    creates = []
    for _boot, data in capture.steps:
        if data[0] > 0x80 and data[1] == RELIABLE:
            creates.extend(p for p in decode_message(data)[1] if p.ID == C.CREATE)
    found = {"participant": next(c for c in creates if c.kind == C.OBJK_PARTICIPANT)}
    for create in creates:
        if create.kind == C.OBJK_REPLIER and \
                create.representation.service_name.startswith(ACTION + "/_action/"):
            found[create.representation.service_name.rsplit("/", 1)[1]] = create
    for name in _TOPICS:
        topic = next(c for c in creates if c.kind == C.OBJK_TOPIC and
                     c.representation.topic_name == "rt%s/_action/%s" % (ACTION, name))
        writer = next(c for c in creates if c.kind == C.OBJK_DATAWRITER and
                      c.representation.topic_id == topic.object_id)
        publisher = next(c for c in creates if c.object_id == writer.tail_id)
        found[name] = [topic, publisher, writer]
    return found


def _client_creates(server: dict) -> dict:
    """The same entities for an rclc action client: requesters, subscribers and datareaders."""
    found = {"participant": server["participant"]}
    for name in _SERVICES:
        rep = server[name].representation
        found[name] = Create(0, (server[name].object_id & 0xFFF0) | C.OBJK_REQUESTER,
                             C.OBJK_REQUESTER, C.REPRESENTATION_IN_BINARY,
                             RequesterBin(rep.service_name, rep.request_type, rep.reply_type,
                                          rep.request_topic, rep.reply_topic),
                             server[name].tail_id, server[name].flags)
    qos = {"feedback": EndpointQos(C.QOS_RELIABLE | C.QOS_KEEP_LAST, 10),
           "status": EndpointQos(C.QOS_RELIABLE | C.QOS_KEEP_LAST | C.QOS_TRANSIENT_LOCAL, 1)}
    for name in _TOPICS:
        topic, publisher, writer = server[name]
        subscriber = Create(0, (publisher.object_id & 0xFFF0) | C.OBJK_SUBSCRIBER,
                            C.OBJK_SUBSCRIBER, C.REPRESENTATION_IN_BINARY, PubSubBin(),
                            publisher.tail_id, publisher.flags)
        reader = Create(0, (writer.object_id & 0xFFF0) | C.OBJK_DATAREADER, C.OBJK_DATAREADER,
                        C.REPRESENTATION_IN_BINARY, DataReaderBin(topic.object_id, qos[name]),
                        subscriber.object_id, writer.flags)
        found[name] = [topic, subscriber, reader]
    return found


def _cdr(message) -> bytes:
    from rclpy.serialization import serialize_message

    return serialize_message(message)[4:]  # without the encapsulation header


def _decoded(body: bytes, message_type):
    from rclpy.serialization import deserialize_message

    return deserialize_message(b"\x00\x01\x00\x00" + bytes(body), message_type)


class RclcActionPeer:
    """One boot of the board (see the module docstring). ``channel`` is a microros_replay
    UdpChannel or SerialChannel; ``boot`` picks its socket (a reset board comes back from a new
    UDP source port). ``feedback_period`` paces the server's goal execution."""

    def __init__(self, channel, domain_id: int, role: str = "server", boot: int = 0,
                 key: bytes = b"\xc0\xff\xee\x01", feedback_period: float = 0.1,
                 timeout: float = 30.0):
        from test_msgs.action import Fibonacci

        self.Fibonacci = Fibonacci
        self.channel, self.boot, self.role = channel, boot, role
        self.domain_id = domain_id
        self.feedback_period = feedback_period
        self.timeout = timeout
        self.key = key
        server = _creates_from_capture()
        self.entities = server if role == "server" else _client_creates(server)
        self.ids = {name: (self.entities[name].object_id if name in _SERVICES
                           else self.entities[name][2].object_id) for name in _SERVICES + _TOPICS}
        self.lock = threading.RLock()
        self.out_seq = 0
        self.unacked = {}  # seq -> message
        self.in_expected = 0  # next sequence number of the agent's reliable stream
        self.request_id = 0x100
        self.statuses = {}  # request id -> status
        self.goals = {}  # goal id -> {"order", "sequence", "status", "waiting": [identities]}
        self.replies = {}  # request id of a request we sent -> reply body
        self.feedback = []  # (goal id, sequence) the client got
        self.status_arrays = []
        self.stopped = False
        self._thread = None

    # -- session --------------------------------------------------------------------------------

    def _next_request_id(self) -> int:
        with self.lock:
            self.request_id = (self.request_id + 1) & 0xFFFF or 0x100
            return self.request_id

    def _send_reliable(self, payloads) -> None:
        with self.lock:
            seq, self.out_seq = self.out_seq, (self.out_seq + 1) & 0xFFFF
            message = encode_message(SESSION, RELIABLE, seq, None, payloads)
            self.unacked[seq] = message
            self._transmit(message)

    def _send_none(self, payloads) -> None:
        self._transmit(encode_message(SESSION, 0, 0, None, payloads))

    def _transmit(self, message: bytes) -> None:
        with self.lock:  # one frame at a time on a serial line (the test's and the peer's thread)
            self.channel.send(self.boot, message)

    def _pump(self, timeout: float) -> None:
        for boot, message in self.channel.receive(timeout):
            if boot != self.boot or not message or self.stopped:
                continue
            header, payloads = decode_message(message)
            if header.stream_id == RELIABLE:
                with self.lock:
                    if header.seq != self.in_expected:  # a gap or a repeat: the agent resends
                        self._send_none([AckNack(self.in_expected, 0, RELIABLE)])
                        continue
                    self.in_expected = (self.in_expected + 1) & 0xFFFF
                self._send_none([AckNack(self.in_expected, 0, RELIABLE)])
            for payload in payloads:
                self._handle(payload)

    def _handle(self, payload) -> None:
        if payload.ID == C.STATUS:
            self.statuses[payload.request_id] = payload.status
        elif payload.ID == C.ACKNACK and payload.stream_id == RELIABLE:
            with self.lock:
                for seq in [s for s in self.unacked if s < payload.first_unacked]:
                    del self.unacked[seq]
        elif payload.ID == C.HEARTBEAT and payload.stream_id == RELIABLE:
            self._send_none([AckNack(self.in_expected, 0, RELIABLE)])
        elif payload.ID == C.DATA:
            self._on_data(payload.object_id, bytes(payload.data))

    def _resend(self) -> None:
        with self.lock:
            pending = sorted(self.unacked.items())
        for _seq, message in pending:
            self._transmit(message)

    def wait(self, predicate, timeout: float | None = None) -> bool:
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        resend_at = time.monotonic() + 0.2
        while not predicate():
            now = time.monotonic()
            if now >= deadline:
                return False
            if now >= resend_at:
                self._resend()
                resend_at = now + 0.2
            if self._thread is not None and threading.current_thread() is not self._thread:
                time.sleep(0.01)  # the peer's thread receives
            else:
                self._pump(0.02)
        return True

    def _request(self, payload) -> int:
        payload.request_id = self._next_request_id()
        self._send_reliable([payload])
        if not self.wait(lambda: payload.request_id in self.statuses):
            raise AssertionError("no STATUS for request 0x%04X" % payload.request_id)
        return self.statuses[payload.request_id]

    def boot_up(self) -> list:
        """CREATE_CLIENT, then every entity one at a time, then READ_DATA on what it reads;
        returns the STATUS of each CREATE."""
        self._transmit(encode_message(0x80, 0, 0, None, [CreateClient(self.key, SESSION, 512)]))
        got = []
        # What the agent sent the previous boot before it learnt of the reset may still be on the
        # line ahead of the answer: read until the answer, or for 2 s.
        deadline = time.monotonic() + 2.0
        while not got and time.monotonic() < deadline:
            for boot, message in self.channel.receive(max(0.0, deadline - time.monotonic())):
                if boot == self.boot and message and message[4] == C.STATUS_AGENT:
                    got.append(decode_message(message)[1][0].status)
        if not got:
            raise AssertionError("no STATUS_AGENT")
        assert got == [C.STATUS_OK]
        participant = self.entities["participant"]
        participant.tail_id = self.domain_id
        order = [participant] + [self.entities[name] for name in _SERVICES] + \
            [c for name in _TOPICS for c in self.entities[name]]
        statuses = [self._request(create) for create in order]
        reads = list(_SERVICES) if self.role == "server" else list(_SERVICES) + list(_TOPICS)
        for name in reads:
            self._send_reliable([ReadData(self._next_request_id(), self.ids[name], RELIABLE,
                                          DeliveryControl(C.MAX_SAMPLES_UNLIMITED, 0, 0, 0))])
        self._thread = threading.Thread(target=self._run, name="rclc-action-peer", daemon=True)
        self._thread.start()
        return statuses

    def _run(self) -> None:
        resend_at = time.monotonic() + 0.2
        while not self.stopped:
            self._pump(0.02)
            if self.role == "server":
                self._step_goals()
            if time.monotonic() >= resend_at:
                self._resend()
                resend_at = time.monotonic() + 0.2

    def reset(self) -> None:
        """The board loses power: nothing more is sent or taken, nothing is deleted."""
        self.stopped = True
        if self._thread is not None:
            self._thread.join(5)

    # -- the action -----------------------------------------------------------------------------

    def _reply(self, name: str, identity: bytes, response) -> None:
        self._send_reliable([WriteData(self._next_request_id(), self.ids[name],
                                       identity + _cdr(response))])

    def _on_data(self, object_id: int, sample: bytes) -> None:
        impl = self.Fibonacci.Impl
        if self.role == "client":
            if object_id == self.ids["feedback"]:
                message = _decoded(sample, impl.FeedbackMessage)
                self.feedback.append((bytes(message.goal_id.uuid), list(message.feedback.sequence)))
            elif object_id == self.ids["status"]:
                from action_msgs.msg import GoalStatusArray

                self.status_arrays.append(_decoded(sample, GoalStatusArray))
            else:  # a reply: behind the request id and object id of the WRITE_DATA that asked
                self.replies[(sample[0] << 8) | sample[1]] = sample[4:]
            return
        identity, body = sample[:24], sample[24:]
        if object_id == self.ids["send_goal"]:
            request = _decoded(body, impl.SendGoalService.Request)
            goal_id = bytes(request.goal_id.uuid)
            self.goals[goal_id] = {"order": request.goal.order, "sequence": [0, 1],
                                   "status": 2, "next": time.monotonic() + self.feedback_period,
                                   "waiting": []}
            self._reply("send_goal", identity, impl.SendGoalService.Response(accepted=True))
        elif object_id == self.ids["get_result"]:
            goal_id = bytes(_decoded(body, impl.GetResultService.Request).goal_id.uuid)
            goal = self.goals.get(goal_id)
            if goal is None:  # unknown: rcl_action answers STATUS_UNKNOWN at once
                self._reply("get_result", identity, impl.GetResultService.Response(status=0))
            else:
                goal["waiting"].append(identity)
                self._answer_results(goal)
        elif object_id == self.ids["cancel_goal"]:
            from action_msgs.msg import GoalInfo
            from action_msgs.srv import CancelGoal

            request = _decoded(body, CancelGoal.Request)
            goal_id = bytes(request.goal_info.goal_id.uuid)
            goal = self.goals.get(goal_id)
            response = CancelGoal.Response()
            if goal is None or goal["status"] not in (1, 2):
                response.return_code = CancelGoal.Response.ERROR_UNKNOWN_GOAL_ID if goal is None \
                    else CancelGoal.Response.ERROR_GOAL_TERMINATED
            else:
                goal["status"] = 5  # CANCELED once the running step sees it
                response.goals_canceling = [GoalInfo(goal_id=request.goal_info.goal_id)]
            self._reply("cancel_goal", identity, response)
            if goal is not None:
                self._answer_results(goal)

    def _step_goals(self) -> None:
        impl = self.Fibonacci.Impl
        now = time.monotonic()
        for goal_id, goal in self.goals.items():
            if goal["status"] != 2 or now < goal["next"]:
                continue
            goal["next"] = now + self.feedback_period
            sequence = goal["sequence"]
            if len(sequence) >= goal["order"]:
                goal["status"] = 4  # SUCCEEDED
                self._answer_results(goal)
                continue
            sequence.append(sequence[-1] + sequence[-2])
            message = impl.FeedbackMessage()
            message.goal_id.uuid = list(goal_id)
            message.feedback.sequence = sequence
            self._send_reliable([WriteData(self._next_request_id(), self.ids["feedback"],
                                           _cdr(message))])

    def _answer_results(self, goal: dict) -> None:
        if goal["status"] not in (4, 5):
            return
        impl = self.Fibonacci.Impl
        for identity in goal["waiting"]:
            response = impl.GetResultService.Response(status=goal["status"])
            response.result.sequence = goal["sequence"]
            self._reply("get_result", identity, response)
        goal["waiting"] = []

    # -- as an action client --------------------------------------------------------------------

    def send(self, name: str, request) -> int:
        """Write a request on requester ``name``; its request id (the reply's key in replies)."""
        request_id = self._next_request_id()
        self._send_reliable([WriteData(request_id, self.ids[name], _cdr(request))])
        return request_id

    def reply(self, request_id: int, response_type, timeout: float | None = None):
        if not self.wait(lambda: request_id in self.replies, timeout):
            raise AssertionError("no reply to request 0x%04X" % request_id)
        return _decoded(self.replies[request_id], response_type)
