"""README's "A fleet of robots": the fleet file its command line loads (docs/fleet.example.toml)
gives the boards the names the file's comments say; README's other fleet lines run in
test_readme_example.py."""

import ipaddress
from pathlib import Path

from xrce.agent.middleware import ClientOrigin
from xrce.agent.middleware.ros.fleet import Fleet
from xrce.agent.middleware.ros.naming import Naming

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "docs" / "fleet.example.toml"


def test_readme_points_at_the_example_fleet_file_it_runs():
    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("## A fleet of robots"):]
    section = section[:section.index("\n## ")]
    assert "--fleet docs/fleet.example.toml" in section and "(docs/fleet.example.toml)" in section
    assert "[[board]]" in EXAMPLE.read_text()


def test_the_example_fleet_file_names_the_boards_as_readme_says():
    fleet = Fleet(str(EXAMPLE), Naming())
    kitchen, rule = fleet.assign(ClientOrigin(bytes.fromhex("aabb0001")))
    assert rule == "tb3-kitchen" and kitchen.name("/cmd_vel") == "/robot1/cmd_vel"
    assert kitchen.name("/tf") == "/tf"
    # The device as the agent opened it (the glob matches the path itself; a real path that
    # resolves to it is tests/agent/test_fleet_rules.py's).
    naming, rule = fleet.assign(ClientOrigin(b"\x01\x02\x03\x04",
                                            device="/dev/serial/by-id/usb-ROBOTIS_OpenCR_0"))
    assert rule == "tb3-hall", rule
    assert naming.name("/cmd_vel") == "/robot2/cmd_vel_safe" and naming.domain_id(0) == 7
    drone, rule = fleet.assign(ClientOrigin(b"\x00\x00\x00\x01",
                                            address=ipaddress.ip_address("192.168.7.20")))
    assert rule == "drones" and drone.name("/fmu/out/vehicle_status") == "/uav/fmu/out/vehicle_status"
    stranger, rule = fleet.assign(ClientOrigin(b"\x00\x00\x00\x09",
                                               address=ipaddress.ip_address("10.0.0.3")))
    assert rule is None and stranger.name("/cmd_vel") == "/cmd_vel"
