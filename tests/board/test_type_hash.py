"""A board's declared RIHS01 type hashes (issue 52): gen-msgs writes rosidl's hash of each message
(the same as a colcon build of the package writes into share/<pkg>/msg/<Type>.json), a board on
MicroPython declares it at creation through ``xrce.client.type_hash`` (rmw's ``typehash=...;`` in
the EndpointQos's user data), and the agent compares it with its package's before any sample:
the matching type is said at INFO, the one whose .msg differs is a mismatch WARNING with the fix.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from agent_process import AgentProcess
from mp_harness import run_micropython
from ros_helpers import ros_domain, wait_until  # noqa: F401

PACKAGE = "hash_board_msgs"
PACKAGE_XML = """<?xml version="1.0"?>
<package format="3">
  <name>hash_board_msgs</name>
  <version>0.0.1</version>
  <description>test</description>
  <maintainer email="test@example.com">test</maintainer>
  <license>Apache-2.0</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  <depend>std_msgs</depend>
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
"""
CMAKE_LISTS = """cmake_minimum_required(VERSION 3.8)
project(hash_board_msgs)
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
find_package(std_msgs REQUIRED)
rosidl_generate_interfaces(${PROJECT_NAME} "msg/WheelTicks.msg" "msg/Battery.msg" DEPENDENCIES std_msgs)
ament_export_dependencies(rosidl_default_runtime)
ament_package()
"""
WHEEL_TICKS = "std_msgs/Header header\nint32[] ticks\nfloat32 voltage\n"

BOARD = r"""
import sys
from nodeudp_transport import make_callbacks
from xrce.client import Session
from xrce.client.type_hash import create_reader, create_writer, type_hash
from xrce.msgs.hash_board_msgs import Battery, WheelTicks
from xrce.transports.custom import CustomTransport

session = Session(CustomTransport(*make_callbacks("127.0.0.1", int(sys.argv[1])), framing=False),
                  key=b"\x48\x41\x53\x48")
print("create", session.create(attempts=10, timeout_ms=500))
node = session.create_participant(domain_id=int(sys.argv[2]), name="hash_board")
create_writer(session, node, "/wheel_ticks", WheelTicks, reliable=False)
create_reader(session, node, "/battery_in", Battery, print)
print("entities", session.run_until_all_status(30000), session.last_statuses)
print("dropped", "xrce.msgs.hash_board_msgs._hashes" not in sys.modules)
print("hash", type_hash(WheelTicks))
session.delete()
"""


def _package(root, battery):
    source = root / PACKAGE
    (source / "msg").mkdir(parents=True)
    (source / "package.xml").write_text(PACKAGE_XML)
    (source / "CMakeLists.txt").write_text(CMAKE_LISTS)
    (source / "msg" / "WheelTicks.msg").write_text(WHEEL_TICKS)
    (source / "msg" / "Battery.msg").write_text(battery)
    return source


@pytest.mark.timeout(300)
def test_the_hash_gen_msgs_writes_is_rosidls_and_the_agent_names_a_different_one_at_creation(tmp_path, ros_domain):  # noqa: F811
    from xrce.agent.interfaces.builder import build

    agent_side = _package(tmp_path / "agent_src", "float32 volts\n")
    board_side = _package(tmp_path / "board_src", "float64 volts\n")  # edited since the agent's build
    out = tmp_path / "out"
    generated = subprocess.run([sys.executable, "-m", "xrce.client", "gen-msgs", str(board_side), "-o", str(out)],
                               capture_output=True, text=True, timeout=120)
    assert generated.returncode == 0 and "no type hashes" not in generated.stderr, generated.stderr
    hashes_file = out / "xrce" / "msgs" / PACKAGE / "_hashes.py"
    namespace = {}
    exec(hashes_file.read_text(), namespace)
    board_hashes = namespace["HASHES"]
    assert sorted(board_hashes) == ["Battery", "WheelTicks"]
    listed = []
    exec((out / "manifest.py").read_text(), {"package": lambda name, files, base_path: listed.extend(files)})
    assert "msgs/%s/_hashes.py" % PACKAGE in listed  # frozen with the classes

    [result] = build([str(agent_side.parent)], cache_root=str(tmp_path / "cache"), names=[PACKAGE],
                     register_results=False)

    def built_hash(name):
        with open(os.path.join(result.prefix, "share", PACKAGE, "msg", name + ".json")) as description:
            return json.load(description)["type_hashes"][0]["hash_string"]
    # WheelTicks has one definition on both sides: gen-msgs computed what rosidl's colcon build did.
    assert board_hashes["WheelTicks"] == built_hash("WheelTicks")
    assert board_hashes["Battery"] != built_hash("Battery") and built_hash("Battery").startswith("RIHS01_")

    # The agent has the package as one built for it (its type support and share/), not by name.
    site = os.path.join(result.prefix, "lib", "python%d.%d" % sys.version_info[:2], "site-packages")
    env = {name: os.pathsep.join(filter(None, [value, os.environ.get(name)])) for name, value in (
        ("AMENT_PREFIX_PATH", result.prefix), ("PYTHONPATH", site),
        ("LD_LIBRARY_PATH", os.path.join(result.prefix, "lib")))}
    with AgentProcess("udp4", "-m", "dds", "-v", "4", env=env) as agent:
        board = run_micropython(BOARD, agent.port, ros_domain, timeout=120,
                                mounts=[(out / "xrce" / "msgs" / PACKAGE, "/lib/xrce/msgs/" + PACKAGE)])
        assert board.returncode == 0, board.stdout + board.stderr
        assert wait_until(lambda: agent.drain() or "type hash mismatch" in "".join(agent.output), 10)
    lines = dict(line.split(" ", 1) for line in board.stdout.splitlines() if " " in line)
    assert lines["create"] == "True" and lines["entities"].startswith("True"), board.stdout
    assert lines["dropped"] == "True" and lines["hash"] == board_hashes["WheelTicks"], board.stdout
    log = "".join(agent.output).splitlines()
    [matched] = [line for line in log if "type hash %s, as this agent's package" % board_hashes["WheelTicks"] in line]
    assert "datawriter" in matched and "/wheel_ticks %s/msg/WheelTicks" % PACKAGE in matched, matched
    [warning] = [line for line in log if "WARNING" in line and "type hash mismatch" in line]
    assert "datareader" in warning and (
        "type hash mismatch on /battery_in: the board's classes of %s/msg/Battery were generated from a "
        "definition with %s, this agent's package has %s" % (PACKAGE, board_hashes["Battery"], built_hash("Battery"))
        in warning), warning
    assert "fix: regenerate the board's classes (xrce-client gen-msgs DIR/%s)" % PACKAGE in warning, warning
    assert not [line for line in log if "type drift" in line]  # named at creation: no sample was written


def test_the_declared_hash_is_written_as_the_wire_codec_writes_a_full_endpoint_qos():
    """xrce.client.type_hash has its blob written by the set-up module's endpoint_blob with the
    core's CdrWriter (a board declaring a hash does not load xrce.wire.objects): byte for byte the
    codec's DataWriter/DataReader with an EndpointQos and user data, which the agent decodes back."""
    from xrce.client.entities import endpoint_blob
    from xrce.wire.objects import DataReaderBin, DataWriterBin, EndpointQos

    data = b"typehash=RIHS01_" + b"0123456789abcdef" * 4 + b";"
    for reader, cls in ((False, DataWriterBin), (True, DataReaderBin)):
        for flags, depth in ((0x0003, 10), (0x0002, None), (0x000B, 1)):
            blob = endpoint_blob(0x0125, flags, depth, reader, data)
            assert blob == cls(0x0125, EndpointQos(flags, depth, user_data=data)).to_blob()
            decoded = cls.from_blob(blob)
            assert bytes(decoded.qos.user_data) == data and decoded.qos.flags == flags
            assert decoded.qos.history_depth == depth and decoded.topic_id == 0x0125
