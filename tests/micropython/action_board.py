"""Run under MicroPython by tests/client/test_client_actions.py: a node with an action server or an action
client (xrce.client.actions) for test_msgs/action/Fibonacci, over a custom transport bridged to
Node's UDP socket, against a real xrce-agent.

argv: agent_port domain_id role(server|client) seconds

server: '/fibonacci', two goals at most. A goal of order < 0 is rejected; each accepted goal gains
one element per 100 ms, published as feedback, and succeeds at order + 1 elements; a goal of order
>= 40 aborts at 4 elements; a cancelled goal ends canceled with what it had. A goal of order 1000
ends the run (rejected).
client: '/fibonacci' on the other side: goal order 5 (feedback, result), then goal order 30
cancelled after its second feedback, then two goals at once (orders 3 and 4).
Prints "key value" lines the test reads.
"""

import sys

from nodeudp_transport import make_callbacks
from xrce import ticks_diff, ticks_ms
from xrce.client.session import Session
from xrce.transports.custom import CustomTransport

port = int(sys.argv[1])
domain_id = int(sys.argv[2])
role = sys.argv[3]
seconds = float(sys.argv[4])

session = Session(CustomTransport(*make_callbacks("127.0.0.1", port), framing=False),
                  key=b"\x41\x43\x54" + (b"\x53" if role == "server" else b"\x43"))
print("connect", session.create(attempts=20, timeout_ms=500))
node = session.create_participant(domain_id=domain_id, name="fib_" + role)
from xrce.client.actions import STATUS_NAMES, ActionClient, ActionServer  # noqa: E402
from xrce.msgs.test_msgs import Fibonacci  # noqa: E402

start = ticks_ms()


def running():
    return ticks_diff(ticks_ms(), start) < seconds * 1000


def serve():
    state = {"stop": False}
    sequences = {}
    log = []

    def on_goal(goal):
        if goal.goal.order == 1000:
            state["stop"] = True
        return goal.goal.order >= 0 and goal.goal.order != 1000

    server = ActionServer(session, node, "/fibonacci", Fibonacci, on_goal, max_goals=2)
    print("setup", session.run_until_all_status(10000))
    last_step = ticks_ms()
    while running() and not state["stop"]:
        session.spin_once(10)
        if ticks_diff(ticks_ms(), last_step) < 100:
            continue
        last_step = ticks_ms()
        for goal in server.active():
            sequence = sequences.setdefault(goal.goal_id, [0, 1])
            if goal.cancel_requested:
                goal.canceled(Fibonacci.Result(sequence=sequence))
            elif goal.goal.order >= 40 and len(sequence) >= 4:
                goal.abort(Fibonacci.Result(sequence=sequence))
            else:
                sequence.append(sequence[-1] + sequence[-2])
                goal.publish_feedback(Fibonacci.Feedback(sequence=sequence))
                if len(sequence) >= goal.goal.order + 1:
                    goal.succeed(Fibonacci.Result(sequence=sequence))
            if not goal.active:
                log.append("%d:%s" % (goal.goal.order, STATUS_NAMES[goal.status]))
    session.run_until_timeout(300)
    print("goals", ",".join(log))


def run_client():
    client = ActionClient(session, node, "/fibonacci", Fibonacci, max_goals=2)
    print("setup", session.run_until_all_status(10000))
    feedback = {}
    finished = []

    def on_feedback(goal, fb):
        feedback.setdefault(goal.goal_id, []).append(len(fb.sequence))

    def on_result(goal):
        finished.append(goal)

    def wait(predicate):
        while running() and not predicate():
            session.spin_once(20)
        return predicate()

    # A request sent before the agent's side has found the server is lost (DDS, volatile): the first
    # goal is sent again until it is answered, as a firmware waiting for its server would.
    while running():
        first = client.send_goal(Fibonacci.Goal(order=5), on_feedback=on_feedback, on_result=on_result)
        answered = ticks_ms()
        while first.accepted is None and ticks_diff(ticks_ms(), answered) < 2000:
            session.spin_once(20)
        if first.accepted is not None:
            break
        client.goals.remove(first)
    wait(lambda: first.done)
    print("first", first.accepted, STATUS_NAMES[first.status], list(first.result.sequence) if first.result else None,
          len(feedback.get(first.goal_id, ())))
    second = client.send_goal(Fibonacci.Goal(order=30), on_feedback=on_feedback, on_result=on_result)
    wait(lambda: len(feedback.get(second.goal_id, ())) >= 2)
    second.cancel()
    wait(lambda: second.done)
    print("second", second.accepted, STATUS_NAMES[second.status], second.cancel_return_code)
    both = [client.send_goal(Fibonacci.Goal(order=n), on_feedback=on_feedback, on_result=on_result)
            for n in (3, 4)]
    print("third", client.send_goal(Fibonacci.Goal(order=2)) is None)  # max_goals=2 in flight
    wait(lambda: both[0].done and both[1].done)
    print("both", ";".join("%s,%s" % (STATUS_NAMES[g.status], list(g.result.sequence) if g.result else None)
                           for g in both))


if role == "server":
    serve()
else:
    run_client()
session.delete(attempts=2, timeout_ms=500)
print("done", True)
