"""ROS's service calls to a board's replier served by the compiled path's receive thread
(xrce/agent/engine/compiled/_replier_out.c, ``FastPath.reader_ready`` for a replier): the thread takes each
request from rcl, sends it to the board, and sends the board's reply back to ROS.

End to end through real agent processes, real sockets and real rclpy clients:

- the real micro-ROS firmware's ``/add_two_ints`` replier (its recorded set-up replayed,
  tests/helpers/firmware_replier.py), once with the compiled path and once with ``XRCE_FASTPATH=0``: the
  same answers, the same request bytes on the wire, the compiled run's counters showing the
  thread served both legs;
- a board whose READ_DATA changes from unlimited (C's) to limited (Python's, which gets the
  requests C took) and back, so both hands serve one replier in turn and the order holds;
- what a board gets wrong: a reply naming a request that does not exist, one that does not
  deserialize, one after ``--request-timeout``: none reaches ROS, the agent says so, and the next
  call is answered.
"""

import struct
import time
from pathlib import Path

import pytest
from rclpy.serialization import deserialize_message, serialize_message

from agent_process import AgentProcess
from firmware_replier import FirmwareReplier
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from test_fastpath import FOLD_WAIT_S, needs_extension
from test_observability import stats_port
from xrce.agent.observe.stats_view import fetch_stats
from xrce.client.entities import read_data
from xrce.client.session import Session
from xrce.transports.udp import UdpTransport

INTERFACES = Path(__file__).resolve().parents[1] / "interfaces"
COUNTERS = ("samples_in", "samples_out", "samples_compiled", "samples_out_compiled")


def add_two_ints():
    from xrce.agent import interfaces

    interfaces.build([str(INTERFACES)], names=["example_interfaces"])
    from example_interfaces.srv import AddTwoInts
    return AddTwoInts


def call(client, request, timeout_s):
    """The response, or None when none came within ``timeout_s`` (the request is dropped)."""
    future = client.call_async(request)
    if not wait_until(future.done, timeout_s):
        client.remove_pending_request(future)
        return None
    return future.result()


def first_answered_call(client, srv, attempts=10):
    """A service is ready once its request reader is discovered; a reply may still be lost while
    its writer is being matched (ROS 2 services have no handshake): warm up until one is
    answered."""
    for attempt in range(attempts):
        if call(client, srv.Request(a=-1 - attempt, b=0), 2.0) is not None:
            return True
    return False


def deltas(before, after):
    return {name: after["agent"][name] - before["agent"][name] for name in COUNTERS}


def run_firmware_calls(ros_peer, ros_domain, env, count=12):  # noqa: F811
    srv = add_two_ints()
    with AgentProcess("udp4", "-m", "dds", "-v", "5", "--stats-port", "0", "--interfaces",
                      str(INTERFACES), env=env) as agent:
        port = stats_port(agent)
        firmware = FirmwareReplier(agent.port, ros_domain)
        client = ros_peer.node.create_client(srv, "/add_two_ints")
        try:
            assert wait_until(client.service_is_ready, 15)
            if not first_answered_call(client, srv):
                agent.drain()
                raise AssertionError("no call answered: firmware got %d requests, answered %d; %s"
                                     % (len(firmware.requests), firmware.answered,
                                        "".join(agent.output)[-4000:]))
            warm_up = len(firmware.requests)
            before = fetch_stats(port)
            sums = [getattr(call(client, srv.Request(a=index, b=1000), 10.0), "sum", None)
                    for index in range(count)]
            time.sleep(FOLD_WAIT_S)
            counted = deltas(before, fetch_stats(port))
            requests = firmware.requests[warm_up:]
        finally:
            ros_peer.node.destroy_client(client)
            firmware.close()
        assert agent.stop() == 0, "".join(agent.output)
    return sums, requests, counted, "".join(agent.output)


@needs_extension
def test_firmware_replier_answers_the_same_on_both_paths_and_the_thread_serves_both_legs(
        ros_peer, ros_domain):  # noqa: F811
    compiled = run_firmware_calls(ros_peer, ros_domain, {"XRCE_FASTPATH": "1"})
    python = run_firmware_calls(ros_peer, ros_domain, {"XRCE_FASTPATH": "0"})
    expected = [index + 1000 for index in range(12)]
    for sums, requests, _counted, output in (compiled, python):
        assert sums == expected, output[-3000:]
        # each request once, identities distinct, the body rclpy's CDR of (a, b)
        assert len(requests) == 12 and len({r[:24] for r in requests}) == 12, requests
    # The same request bytes after the identity, whichever hand sent them.
    assert [r[24:] for r in compiled[1]] == [r[24:] for r in python[1]]
    assert [r[24:] for r in compiled[1]] == [struct.pack("<qq", index, 1000)
                                             for index in range(12)]
    # Both legs counted as the Python path counts them, and here by the thread (a request or
    # reply meeting Python's timed work, or a full hand-off, is Python's: not every one).
    counted_c, counted_py = compiled[2], python[2]
    assert counted_c["samples_out"] == counted_py["samples_out"] == 12, (counted_c, counted_py)
    assert counted_c["samples_in"] == counted_py["samples_in"] == 12, (counted_c, counted_py)
    assert counted_c["samples_out_compiled"] > 0 and counted_c["samples_compiled"] > 0, counted_c
    assert counted_py["samples_out_compiled"] == 0 and counted_py["samples_compiled"] == 0, \
        counted_py
    assert "replier 0x0008: requests from ROS and their replies take the compiled path" in \
        compiled[3]


def run_handover(ros_peer, ros_domain, env):  # noqa: F811
    """A board's replier read unlimited (3 calls), then with max_samples 2 (3 calls: the third
    waits in the replier's queue), then unlimited again (it goes out, then 2 more calls)."""
    from test_msgs.srv import BasicTypes
    from test_ros_bridge import RawBasicTypes

    with AgentProcess("udp4", "-m", "dds", "-v", "5", "--stats-port", "0", env=env) as agent:
        port = stats_port(agent)
        session = Session(UdpTransport("127.0.0.1", agent.port), history=16)
        served, answers = [], []
        try:
            assert session.create(attempts=5, timeout_ms=1000)
            node = session.create_participant(domain_id=ros_domain, name="fastpath_repliers")

            def serve(identity, request_body):
                request = deserialize_message(b"\x00\x01\x00\x00" + bytes(request_body),
                                              BasicTypes.Request)
                served.append(request.int32_value)
                response = BasicTypes.Response(int32_value=request.int32_value * 2)
                session.send_reply(replier, identity, serialize_message(response)[4:])

            replier = session.create_service_server(node, "/fastpath_double", RawBasicTypes, serve)
            assert session.run_until_all_status(5000), session.last_statuses
            client = ros_peer.node.create_client(BasicTypes, "/fastpath_double")
            assert wait_until(client.service_is_ready, 15)

            def ask(value, timeout_s=10.0):
                future = client.call_async(BasicTypes.Request(int32_value=value))
                deadline = time.monotonic() + timeout_s
                while not future.done() and time.monotonic() < deadline:
                    session.spin_once(20)
                if not future.done():
                    client.remove_pending_request(future)
                    return None
                return future.result().int32_value

            warm = 0
            while ask(-1, 2.0) is None and warm < 10:  # the reply writer being matched
                warm += 1
            served.clear()
            before = fetch_stats(port)
            answers += [ask(value) for value in (1, 2, 3)]
            # The READ_DATA takes the board's stream, ROS's requests another way: asked only
            # once the agent has acknowledged (so handled) it, or a request could still meet the
            # READ_DATA before it, on either path.
            read_data(session, replier, session.reliable, max_samples=2)
            assert session.run_until_confirm_delivery(5000)
            answers += [ask(value) for value in (4, 5)]
            waiting = client.call_async(BasicTypes.Request(int32_value=6))
            for _ in range(25):  # 0.5 s: no READ_DATA is active, the request waits
                session.spin_once(20)
            assert not waiting.done() and served == [1, 2, 3, 4, 5], served
            session.read_data(replier, session.reliable)
            assert session.run_until_confirm_delivery(5000)
            deadline = time.monotonic() + 10
            while not waiting.done() and time.monotonic() < deadline:
                session.spin_once(20)
            answers.append(waiting.result().int32_value if waiting.done() else None)
            answers += [ask(value) for value in (7, 8)]
            time.sleep(FOLD_WAIT_S)
            counted = deltas(before, fetch_stats(port))
        finally:
            session.close()
    return served, answers, counted, "".join(agent.output)


@needs_extension
def test_both_hands_serve_one_replier_in_turn_and_keep_the_order(ros_peer, ros_domain):  # noqa: F811
    compiled = run_handover(ros_peer, ros_domain, {"XRCE_FASTPATH": "1"})
    python = run_handover(ros_peer, ros_domain, {"XRCE_FASTPATH": "0"})
    for served, answers, counted, output in (compiled, python):
        assert served == list(range(1, 9)), output[-3000:]
        assert answers == [2 * value for value in range(1, 9)], output[-3000:]
        assert counted["samples_out"] == 8 and counted["samples_in"] == 8, counted
    # The thread sent what the unlimited READ_DATAs asked for; Python what the limited one did
    # (and the request that waited for the next READ_DATA).
    assert 0 < compiled[2]["samples_out_compiled"] <= 5, compiled[2]  # of 1, 2, 3, 7 and 8
    assert python[2]["samples_out_compiled"] == 0, python[2]


@needs_extension
def test_replies_a_board_gets_wrong_reach_no_one_and_the_next_call_is_answered(
        ros_peer, ros_domain):  # noqa: F811
    srv = add_two_ints()
    held = {}

    def reply(identity, a, b):
        correct = identity + struct.pack("<q", a + b)
        if a == 1:  # a request that does not exist (its sequence number), then the right one
            forged = identity[:16] + struct.pack("<iI", 0, 0x7FFF0000) + struct.pack("<q", 99)
            firmware.send_sample(forged)
            return correct
        if a == 2:  # names another replier's request
            return bytes(16) + identity[16:] + struct.pack("<q", 99)
        if a == 3:  # does not deserialize: 3 bytes of the 8 of an int64
            return identity + b"\x01\x02\x03"
        if a == 4:  # answered after the request timeout (sent by the test)
            held[a] = correct[:24] + struct.pack("<q", 99)
            return None
        return correct

    with AgentProcess("udp4", "-m", "dds", "-v", "4", "--request-timeout", "0.5",
                      "--interfaces", str(INTERFACES)) as agent:
        firmware = FirmwareReplier(agent.port, ros_domain, reply)
        client = ros_peer.node.create_client(srv, "/add_two_ints")
        try:
            assert wait_until(client.service_is_ready, 15)
            assert first_answered_call(client, srv)
            assert call(client, srv.Request(a=1, b=10), 10.0).sum == 11
            assert call(client, srv.Request(a=2, b=10), 1.5) is None
            assert call(client, srv.Request(a=3, b=10), 1.5) is None
            late = client.call_async(srv.Request(a=4, b=10))
            assert wait_until(lambda: 4 in held, 10)
            time.sleep(1.0)  # past the agent's 0.5 s
            firmware.send_sample(held[4])
            time.sleep(1.0)
            assert not late.done()
            client.remove_pending_request(late)
            assert call(client, srv.Request(a=5, b=10), 10.0).sum == 15
        finally:
            ros_peer.node.destroy_client(client)
            firmware.close()
        assert agent.stop() == 0
    output = "".join(agent.output)
    assert "reply of replier 0x0008 does not deserialize" in output, output[-3000:]
    assert "service requests got no reply from their XRCE client within 0.5 s" in output, \
        output[-3000:]
    assert "Traceback" not in output, output[-3000:]
