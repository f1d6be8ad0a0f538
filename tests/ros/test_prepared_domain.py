"""The default domain prepared at start (``RosDomains.prepare``, issue 51 item 6): its thread,
rclpy context and executor exist before any board, its DDS participant does not (the agent at rest
is still nowhere in ROS); the first board's participant takes that runtime as its domain, the
agent's own listeners hear of the domain then, and once the domain is left after its last board
it is prepared again. Under a discovery server (``join``) the participant is made at start and the
domain is never left. What it buys (creation on a fresh agent) is a bench figure:
bench/microros/entity_creation.py; what it costs at rest: bench/agent/domain_prepare.py.
"""

from __future__ import annotations

import asyncio
import os

import pytest

from ros_helpers import async_wait_until, ros_domain  # noqa: F401
from test_discovery_order import participant_threads
from xrce.agent.middleware.ros.ros_middleware import RosMiddleware
from xrce.agent.middleware.ros.membership import default_domain_id

pytest.importorskip("rclpy")


def test_the_default_domain_is_ros_domain_id_else_0():
    assert default_domain_id({}) == 0
    assert default_domain_id({"ROS_DOMAIN_ID": " 7 "}) == 7
    assert default_domain_id({"ROS_DOMAIN_ID": ""}) == 0
    # Not a domain id: nothing prepared (a board asking for it is refused as before).
    assert default_domain_id({"ROS_DOMAIN_ID": "233"}) is None
    assert default_domain_id({"ROS_DOMAIN_ID": "-1"}) is None
    assert default_domain_id({"ROS_DOMAIN_ID": "lan"}) is None


async def test_a_prepared_domain_has_no_participant_until_a_board_and_is_prepared_again(
        ros_domain):  # noqa: F811
    mw = RosMiddleware(linger_s=0.2)
    await mw.start()
    joined, left = [], []
    mw.add_domain_listener(joined.append, left.append)
    try:
        mw.prepare_default({"ROS_DOMAIN_ID": str(ros_domain)})
        prepared = mw.domains.prepared_runtime(ros_domain)
        assert await async_wait_until(lambda: prepared.context is not None, 20)
        # Ready, yet not joined: no DDS participant, nothing of the agent's own was asked for.
        assert not prepared.joined and mw.domain_ids() == [] and joined == []
        assert participant_threads(os.getpid()) == []

        mw.create_participant((0x51600001, 0x01), ros_domain, "first_board")
        assert mw.domains.runtime(ros_domain) is prepared and \
            mw.domains.prepared_runtime(ros_domain) is None
        assert joined == [ros_domain] and mw.domain_ids() == [ros_domain]
        assert participant_threads(os.getpid())

        mw.delete((0x51600001, 0x01))
        assert await async_wait_until(lambda: left == [ros_domain], 20)
        # Left, and ready again for the next board: a new runtime, still without a participant.
        again = mw.domains.prepared_runtime(ros_domain)
        assert again is not None and again is not prepared and not again.joined
        assert await async_wait_until(lambda: not prepared.thread.is_alive(), 20)
        assert await async_wait_until(lambda: not participant_threads(os.getpid()), 20)
    finally:
        await mw.close()
    assert not mw.domains.prepared_ids() and not again.thread.is_alive()


async def test_joined_at_start_under_a_server_and_kept(ros_domain):  # noqa: F811
    """``join`` (what ``prepare_default`` asks for under ROS_DISCOVERY_SERVER, without needing
    a server here): the participant is made at start and stays after a board has come and gone,
    past the linger."""
    mw = RosMiddleware(linger_s=0.2)
    await mw.start()
    try:
        mw.prepare([ros_domain], join=True)
        domain = mw.domains.runtime(ros_domain)
        assert await async_wait_until(lambda: mw.domain_ids() == [ros_domain], 20)
        assert participant_threads(os.getpid())
        mw.create_participant((0x51600002, 0x01), ros_domain, "passing_board")
        assert mw.domains.runtime(ros_domain) is domain
        mw.delete((0x51600002, 0x01))
        assert await async_wait_until(lambda: not mw.domains.lingering_ids() and
                                      mw.domains.runtime(ros_domain) is domain, 5)
        await asyncio.sleep(mw.domains.linger_s * 3)
        assert mw.domains.runtime(ros_domain) is domain and domain.thread.is_alive()
    finally:
        await mw.close()
