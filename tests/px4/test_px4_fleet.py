"""Two PX4 SITL vehicles (tests/golden/px4/px4_two: client keys 00000001 and 00000002, the second
with PX4's own namespace px4_1) behind one agent with a fleet file matching PX4's keys: each
vehicle's topics and its vehicle_command service go under its rule's namespace, PX4's own
namespace kept under it; nothing is left on PX4's bare names."""

import pytest

from agent_process import AgentProcess
from microros_replay import UdpChannel
from px4_replay import Px4Capture, Px4Replayer
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from test_px4_replay import assert_agent_has_no_px4_msgs, px4_msgs  # noqa: F401


@pytest.mark.timeout(120)
def test_two_px4_named_by_their_keys(tmp_path, px4_msgs, ros_peer, ros_domain):  # noqa: F811
    fleet = tmp_path / "fleet.toml"
    fleet.write_text('[[board]]\nname = "uav1"\nkey = "0x00000001"\nnamespace = "/uav1"\n\n'
                     '[[board]]\nname = "uav2"\nkey = "0x00000002"\nnamespace = "/uav2"\n')
    capture = Px4Capture("px4_two")
    services = ("/uav1/fmu/vehicle_command", "/uav2/px4_1/fmu/vehicle_command")
    node = ros_peer.node
    clients = [node.create_client(px4_msgs.srv.VehicleCommand, name) for name in services]
    assert_agent_has_no_px4_msgs()
    with AgentProcess("udp4", "-m", "dds", "-v", "0", "--fleet", str(fleet)) as agent:
        channel = UdpChannel(agent.port)
        try:
            replay = Px4Replayer(capture, channel, domain_id=ros_domain, answer_requests=True)
            replay.run(until_step=min(capture.replier_reply_steps()))
            assert wait_until(lambda: all(c.service_is_ready() for c in clients), 30), \
                node.get_service_names_and_types()
            topics = [name for name, _ in node.get_topic_names_and_types()]
            assert any(n.startswith("/uav1/fmu/out/") for n in topics), topics
            assert any(n.startswith("/uav2/px4_1/fmu/out/") for n in topics), topics
            assert not [n for n in topics if n.startswith(("/fmu/", "/px4_1/"))], topics
            assert not [n for n, _ in node.get_service_names_and_types()
                        if n.startswith(("/fmu/", "/px4_1/"))]
        finally:
            channel.close()
        assert agent.proc.poll() is None
