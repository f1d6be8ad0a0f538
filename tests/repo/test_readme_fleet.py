"""README's "A fleet of robots": its TOML block is what docs/fleet.example.toml holds (the file
its command line loads), and that file gives the boards the names README says."""

import ipaddress
import re
from pathlib import Path

from xrce.agent.middleware import ClientOrigin
from xrce.agent.middleware.ros.fleet import Fleet
from xrce.agent.middleware.ros.naming import Naming

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "docs" / "fleet.example.toml"


def test_readme_shows_the_example_fleet_file_as_it_is():
    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("## A fleet of robots"):]
    block = re.search(r"```toml\n(.*?)```", section, re.S).group(1)
    assert block.strip() and block in EXAMPLE.read_text()
    assert "--fleet docs/fleet.example.toml" in section


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
