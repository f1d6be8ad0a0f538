"""Samples from ROS to a board sent by the compiled path's receive thread
(xrce/agent/engine/compiled/_reader_out.c, ``FastPath.reader_ready``).

End to end through real agent processes, real sockets and real rclpy, once with the compiled path
and once with ``XRCE_FASTPATH=0``: a board that only reads (it never writes, so nothing but its
reader registers it in C) takes a best-effort ROS topic on its best-effort stream; a READ_DATA with
a sample limit (Python's to serve) replaces the unlimited one, then an unlimited one again; and the
reader is deleted while ROS publishes as fast as it can. (Samples that arrive while no READ_DATA is
active wait in the reader's queue, up to its depth, for the next one.) Both paths must deliver the same samples,
in the same order, with the same request ids and consecutive sequence numbers, and count the same.
(The reliable stream, its window, NACKs and a STATUS waiting for room: test_fastpath_acknack.py.)
"""

import struct
import threading
import time

from agent_process import AgentProcess
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from test_fastpath import FOLD_WAIT_S, Twist_ros, needs_extension
from test_observability import stats_port
from xrce.agent.observe.stats_view import fetch_stats
from xrce.client.entities import create_reader, delete_entity, read_data
from xrce.client.session import Session
from xrce.msgs.geometry_msgs import Twist
from xrce.wire.submessages import Data, decode_message
from xrce.transports.udp import UdpTransport


def data_from_agent(transport, wait_s, until=None):
    """(stream id, seq, request id, linear.x) of every DATA the agent sends within ``wait_s``
    (sooner once ``until(list)`` holds)."""
    out = []
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline and not (until and until(out)):
        data = transport.recv(max(1, int((deadline - time.monotonic()) * 1000)))
        if data is None:
            continue
        for payload in decode_message(bytes(data))[1]:
            if isinstance(payload, Data):
                value = struct.unpack_from("<d", bytes(payload.data), 0)[0]
                out.append((data[1], data[2] | data[3] << 8, payload.request_id, value))
    return out


def run_reader_scenario(ros_peer, ros_domain, topic, env):  # noqa: F811
    """Returns (the samples each step received, as (seq step, request id order, value), the
    agent's counter deltas, whether the agent still answered after the deletion, its output)."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    publisher = ros_peer.node.create_publisher(
        Twist_ros(), topic, QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT))
    value = [0.0]

    def publish(count, pause=0.01):
        for _ in range(count):
            value[0] += 1
            message = Twist_ros()()
            message.linear.x = value[0]
            publisher.publish(message)
            time.sleep(pause)

    with AgentProcess("udp4", "-m", "dds", "-v", "5", "--stats-port", "0", env=env) as agent:
        port = stats_port(agent)
        session = Session(UdpTransport("127.0.0.1", agent.port), history=16)
        steps = []
        try:
            assert session.create(attempts=5, timeout_ms=1000)
            node = session.create_participant(domain_id=ros_domain, name="fastpath_readers")
            reader = create_reader(session, node, topic, Twist, lambda m: None, reliable=False)
            assert session.run_until_all_status(5000), session.last_statuses
            assert wait_until(lambda: publisher.get_subscription_count() > 0, 10)
            time.sleep(0.5)
            transport = session.transport
            before = fetch_stats(port)
            # 1: the unlimited READ_DATA, 20 samples.
            publish(20)
            steps.append(data_from_agent(transport, 5, lambda out: len(out) >= 20))
            # 2: a READ_DATA for 3 samples replaces it: 3 of the next 5 arrive.
            read_data(session, reader, session.best_effort, max_samples=3)
            session.flush()
            time.sleep(0.3)
            publish(5)
            steps.append(data_from_agent(transport, 1.0))
            # 3: unlimited again: the two samples the reader kept meanwhile, then 5 new ones.
            read_data(session, reader, session.best_effort)
            session.flush()
            time.sleep(0.3)
            publish(5)
            steps.append(data_from_agent(transport, 5, lambda out: len(out) >= 7))
            time.sleep(FOLD_WAIT_S)
            after = fetch_stats(port)
            # 4: the reader deleted while ROS publishes flat out; the agent goes on answering.
            flooding = threading.Event()
            flood = threading.Thread(target=lambda: [publish(1, 0.001) for _ in range(2000)
                                                     if not flooding.is_set()])
            flood.start()
            time.sleep(0.2)
            delete_entity(session, reader)
            answered = session.run_until_all_status(5000)
            flooding.set()
            flood.join()
            answered = answered and session.ping(timeout_ms=2000, attempts=3)
        finally:
            session.close()
            ros_peer.node.destroy_publisher(publisher)
    deltas = {name: after["agent"][name] - before["agent"][name]
              for name in ("samples_out", "messages_out", "dropped", "handler_errors",
                           "samples_out_compiled")}
    return steps, deltas, answered, "".join(agent.output)


def relative(steps):
    """Each step's samples with sequence numbers and request ids made relative to the first's."""
    seq0, rid0 = steps[0][0][1], steps[0][0][2]
    return [[(stream, (seq - seq0) & 0xFFFF, (rid - rid0) & 0xFFFF, value)
             for stream, seq, rid, value in step] for step in steps]


@needs_extension
def test_samples_from_ros_compiled_and_python_paths_deliver_and_count_the_same(
        ros_peer, ros_domain):  # noqa: F811
    compiled = run_reader_scenario(ros_peer, ros_domain, "/fastpath_readers_on",
                                   {"XRCE_FASTPATH": "1"})
    python = run_reader_scenario(ros_peer, ros_domain, "/fastpath_readers_off",
                                 {"XRCE_FASTPATH": "0"})
    steps = relative(python[0])
    stream = steps[0][0][0]
    assert [(s, v) for _, s, _, v in steps[0]] == [(n, n + 1.0) for n in range(20)], steps
    assert len({rid for _, _, rid, _ in steps[0]}) == 1, steps
    assert [v for *_, v in steps[1]] == [21.0, 22.0, 23.0], steps  # the limit: 3 of 5
    assert [v for *_, v in steps[2]] == [24.0, 25.0, 26.0, 27.0, 28.0, 29.0, 30.0], steps
    assert [s for _, s, _, _ in steps[1] + steps[2]] == list(range(20, 30)), steps  # no gap
    assert steps[1][0][2] != 0 and steps[2][0][2] != steps[1][0][2], steps  # each its own id
    assert all(s == stream for step in steps for s, *_ in step), steps
    assert relative(compiled[0]) == steps, (relative(compiled[0]), steps)
    for deltas in (compiled[1], python[1]):
        assert deltas["samples_out"] == 30 and deltas["messages_out"] >= 30, deltas
        assert deltas["dropped"] == 0 and deltas["handler_errors"] == 0, deltas
    assert compiled[1]["samples_out"] == python[1]["samples_out"]
    # All but the limited READ_DATA's 3 (Python's) and the first of each unlimited one (Python
    # serves it, then hands the reader to C) went out from C; none from C without it.
    assert compiled[1]["samples_out_compiled"] >= 30 - 3 - 2 - 2, compiled[1]
    assert python[1]["samples_out_compiled"] == 0, python[1]
    assert compiled[2] and python[2]  # the deletion under a flood left the agent serving
    assert "reader 0x" in compiled[3] and ": samples from ROS take the compiled path" in compiled[3]
    assert "samples from ROS take the compiled path" not in python[3]
