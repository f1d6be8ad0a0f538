"""An agent at rest is not in ROS (issue 45, item 2): no DDS participant, rclpy context or
executor thread until a client's participant needs one, in any domain including the default one;
a domain whose last client participant has gone is left after the linger
(``xrce.agent.middleware.ros.membership``), and the agent is at rest again.

What a participant at rest cost: docs/PERFORMANCE.md, "At rest"; why the linger is what it is:
"Agent restart and discovery" there. The first sample still reaches ROS within the discovery bound when the
agent joins late: tests/ros/test_discovery_order.py.
"""

from __future__ import annotations

import asyncio
import os
import socket
import time

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import QoSProfile, ReliabilityPolicy

from agent_process import AgentProcess
from ros_helpers import RosPeer, async_wait_until, ros_domain, wait_until  # noqa: F401
from test_discovery_order import participant_threads, spdp_sender
from xrce.agent.middleware.ros.ros_middleware import RosMiddleware
from xrce.client import Session
from xrce.transports.udp import UdpTransport

LINGER_S = 2.0


def thread_names(pid: int) -> list:
    names = []
    for tid in os.listdir("/proc/%d/task" % pid):
        try:
            with open("/proc/%d/task/%s/comm" % (pid, tid)) as comm:
                names.append(comm.read().strip())
        except OSError:  # the thread has just ended
            pass
    return names


def main_thread_wakes_over(pid: int, seconds: float) -> int:
    def switches():
        with open("/proc/%d/task/%d/schedstat" % (pid, pid)) as schedstat:
            return int(schedstat.read().split()[2])
    before = switches()
    time.sleep(seconds)
    return switches() - before


def announcements_over(listener, seconds: float) -> int:
    """Participant announcements (SPDP) that reach ``listener`` within ``seconds``."""
    listener.settimeout(0.2)
    count = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            datagram = listener.recv(65536)
        except socket.timeout:
            continue
        if spdp_sender(datagram) is not None:
            count += 1
    return count


def test_no_dds_participant_until_a_client_needs_one_and_none_after_the_linger(
        ros_domain):  # noqa: F811
    """The agent starts (ROS_DOMAIN_ID is the test's domain, the agent's default) with no Fast
    DDS thread and announces no participant; a client's participant brings one, and its node to
    an rclpy peer; once that participant is deleted and the linger has passed, the participant
    and its threads are gone again, and a /diagnostics subscriber left behind in the domain no
    longer wakes the agent's loop. A later participant joins the domain again."""
    # Fast DDS's unicast discovery port of participant 31 in this domain, where any participant
    # announces itself under LOCALHOST discovery (test_discovery_order.py); nobody else is in
    # the domain yet.
    listener = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    listener.bind(("127.0.0.1", 7400 + 250 * ros_domain + 10 + 2 * 31))
    session = peer = None
    try:
        with AgentProcess("udp4", "-m", "dds", "--domain-linger", str(LINGER_S)) as agent:
            pid = agent.proc.pid
            # At the banner: a domain joined at start would have its participant by now.
            assert participant_threads(pid) == [] and "dds.shm.wdog" not in thread_names(pid)
            assert announcements_over(listener, 1.5) == 0

            peer = RosPeer(ros_domain)
            arrays = []
            peer.node.create_subscription(DiagnosticArray, "/diagnostics", arrays.append,
                                          QoSProfile(depth=10,
                                                     reliability=ReliabilityPolicy.RELIABLE))
            session = Session(UdpTransport("127.0.0.1", agent.port), key=0x45A00001)
            assert session.create(attempts=5, timeout_ms=1000)
            node = session.create_participant(domain_id=ros_domain, name="at_rest_board")
            assert session.run_until_all_status(5000), session.last_statuses
            assert participant_threads(pid), thread_names(pid)
            assert wait_until(lambda: ("at_rest_board", "/") in peer.node_names(), 20), \
                peer.node_names()
            assert wait_until(lambda: arrays, 15), "no /diagnostics while the domain is joined"

            session.delete_entity(node)
            assert session.run_until_all_status(5000), session.last_statuses
            assert wait_until(lambda: not participant_threads(pid), LINGER_S + 20), \
                thread_names(pid)
            assert wait_until(lambda: not peer.node_names(), 20), peer.node_names()
            session.delete(attempts=2, timeout_ms=500)  # nothing of it for the loop to time
            session.close()
            time.sleep(1)  # the deletion's own aftermath (one timer turn) settles
            # The /diagnostics subscriber is still there: the once-a-second round must not be
            # (it would wake the loop at least 4 times in 5 s).
            assert main_thread_wakes_over(pid, 5) <= 2

            session = Session(UdpTransport("127.0.0.1", agent.port), key=0x45A00005)
            assert session.create(attempts=5, timeout_ms=1000)
            node = session.create_participant(domain_id=ros_domain, name="at_rest_again")
            assert session.run_until_all_status(5000), session.last_statuses
            assert participant_threads(pid)
            assert wait_until(lambda: ("at_rest_again", "/") in peer.node_names(), 20), \
                peer.node_names()
            session.delete(attempts=2, timeout_ms=500)
    finally:
        if session is not None:
            session.close()
        if peer is not None:
            peer.close()
        listener.close()


async def test_a_participant_within_the_linger_keeps_the_domain(ros_domain):  # noqa: F811
    """A board that comes back within the linger finds the domain it left (the same runtime and
    DDS participant, no join); once the linger passes with nobody there, the domain is left, its
    listeners hear it, and its thread ends. An agent that never had a client never joined."""
    mw = RosMiddleware(linger_s=0.5)
    await mw.start()
    left = []
    mw.add_domain_listener(lambda _domain_id: None, left.append)
    try:
        assert mw.domain_ids() == [] and not mw.domains.runtime_ids()
        mw.create_participant((0x45A00002, 0x01), ros_domain, "first_life")
        domain = mw.domains.runtime(ros_domain)
        mw.delete((0x45A00002, 0x01))
        # The loop has not turned since: whatever the machine's load, still within the linger.
        assert mw.domain_ids() == [ros_domain] and mw.domains.runtime(ros_domain) is domain
        mw.create_participant((0x45A00003, 0x01), ros_domain, "second_life")
        assert mw.domains.runtime(ros_domain) is domain and not mw.domains.lingering_ids() and \
            not left
        await asyncio.sleep(mw.domains.linger_s * 2)
        assert mw.domains.runtime(ros_domain) is domain and not left
        mw.delete((0x45A00003, 0x01))
        assert await async_wait_until(lambda: mw.domains.runtime(ros_domain) is None, 20)
        assert left == [ros_domain] and mw.domain_ids() == []
        assert await async_wait_until(lambda: not domain.thread.is_alive(), 20)
    finally:
        await mw.close()


async def test_a_domain_joined_for_a_participant_that_fails_is_left(ros_domain,  # noqa: F811
                                                                     monkeypatch):
    """A client's first participant in a domain, whose node rclpy does not make, does not keep
    the domain joined for nothing."""
    from xrce.agent.middleware import MiddlewareError
    from xrce.agent.middleware.ros.domain import DomainRuntime

    make_node = DomainRuntime.make_node

    def refuses_the_board(runtime, name, namespace=None):
        if name == "refused_board":
            raise RuntimeError("no node this time")
        return make_node(runtime, name, namespace)

    monkeypatch.setattr(DomainRuntime, "make_node", refuses_the_board)
    mw = RosMiddleware(linger_s=0.2)
    await mw.start()
    try:
        with pytest.raises(MiddlewareError, match="no node this time"):
            mw.create_participant((0x45A00004, 0x01), ros_domain, "refused_board")
        assert await async_wait_until(lambda: mw.domains.runtime(ros_domain) is None, 20)
    finally:
        await mw.close()
