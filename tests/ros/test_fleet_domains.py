"""A fleet file's domains are prepared at start like the default one (``prepare_default``): a rule's
first board finds its domain's runtime ready (no DDS participant before it), takes it, and once the
domain is left after it the domain is prepared again; the participant keeps its rule's naming."""

from __future__ import annotations

import ipaddress
import os

import pytest

from ros_helpers import DomainLease, async_wait_until, ros_domain  # noqa: F401
from test_discovery_order import participant_threads
from xrce.agent.middleware import ClientOrigin
from xrce.agent.middleware.ros.ros_middleware import RosMiddleware
from xrce.agent.middleware.ros.fleet import Fleet

pytest.importorskip("rclpy")


async def test_a_rules_domain_is_prepared_and_its_board_takes_it(tmp_path, ros_domain):  # noqa: F811
    lease = DomainLease()
    path = tmp_path / "fleet.toml"
    path.write_text('[[board]]\nname = "robot2"\naddress = "10.0.0.0/24"\nnamespace = "/robot2"\n'
                    'domain = %d\n' % lease.domain_id)
    mw = RosMiddleware(linger_s=0.2, fleet=Fleet(str(path)))
    await mw.start()
    left = []
    mw.add_domain_listener(lambda domain_id: None, left.append)
    try:
        mw.prepare_default({"ROS_DOMAIN_ID": str(ros_domain)})
        assert mw.domains.prepared_ids() == sorted([ros_domain, lease.domain_id])
        prepared = mw.domains.prepared_runtime(lease.domain_id)
        assert await async_wait_until(lambda: prepared.context is not None, 20)
        assert not prepared.joined and participant_threads(os.getpid()) == []

        board = ClientOrigin(b"\x51\x60\x00\x03", ipaddress.ip_address("10.0.0.8"))
        mw.create_participant((0x51600003, 0x01), ros_domain, "board", origin=board)
        record = mw.records.get((0x51600003, 0x01))
        assert record.domain is prepared and record.rule == "robot2"
        assert record.naming.namespace == "/robot2" and record.naming.domain == lease.domain_id
        # the default domain: no board asked for it
        assert mw.domains.prepared_runtime(ros_domain) is not None

        mw.delete((0x51600003, 0x01))
        assert await async_wait_until(lambda: left == [lease.domain_id], 20)
        again = mw.domains.prepared_runtime(lease.domain_id)
        assert again is not None and again is not prepared and not again.joined
    finally:
        await mw.close()
        lease.release()
