"""README's board service example runs as written (only the agent's address and the domain changed)
under MicroPython 1.27 (WebAssembly), through a real ``xrce-agent -m dds``, to an rclpy node.

The user's own ``my_robot_msgs`` (``srv/SetLed.srv`` as the example's comment gives it) goes
through the README's route: ``xrce-client gen-msgs my_robot_msgs/ -o out/`` for the board, the
package built for the node only (the agent carries the type by name). The node, named ``talker``
with a ``rate`` parameter, calls the board's ``/set_led`` twice; the board asks it for ``rate``.
"""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from agent_process import AgentProcess
from mp_harness import run_micropython
from ros_helpers import ros_domain  # noqa: F401

REPO = Path(__file__).resolve().parents[2]
README = REPO / "README.md"
PACKAGE_XML = """<?xml version="1.0"?>
<package format="3">
  <name>my_robot_msgs</name>
  <version>0.0.1</version>
  <description>README's board service example (tests/board/test_readme_service_example.py).</description>
  <maintainer email="xrce@example.invalid">xrce project</maintainer>
  <license>Apache-2.0</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
"""
CMAKE_LISTS = """cmake_minimum_required(VERSION 3.8)
project(my_robot_msgs)
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
rosidl_generate_interfaces(${PROJECT_NAME} "srv/SetLed.srv")
ament_export_dependencies(rosidl_default_runtime)
ament_package()
"""

NODE_SCRIPT = r"""
import rclpy
from rclpy.node import Node
from my_robot_msgs.srv import SetLed

rclpy.init()
node = Node("talker")
node.declare_parameter("rate", 12.5)
client = node.create_client(SetLed, "/set_led")
asks = [(2, True), (7, False)]
pending = [None]
end = node.get_clock().now().nanoseconds + 120 * 10**9
try:
    while node.get_clock().now().nanoseconds < end:
        rclpy.spin_once(node, timeout_sec=0.1)
        if pending[0] is None and asks and client.service_is_ready():
            led, on = asks.pop(0)
            pending[0] = client.call_async(SetLed.Request(led=led, on=on))
        if pending[0] is not None and pending[0].done():
            print("reply", pending[0].result().ok, flush=True)
            pending[0] = None
except Exception:  # SIGTERM from the test once the board is done (rclpy shuts the context down)
    pass
"""


def readme_service_example():
    text = README.read_text()
    section = text[text.index("## The client on MicroPython"):]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    [block] = [b for b in blocks if "create_service_server" in b]
    return block


def _srv_definition(source):
    """srv/SetLed.srv from the example's own comment ("uint8 led, bool on --- bool ok")."""
    comment = re.search(r"import SetLed\s+# srv/SetLed\.srv: (.*)$", source, re.M).group(1)
    request, response = comment.split(" --- ")
    return "\n".join(request.split(", ")) + "\n---\n" + "\n".join(response.split(", ")) + "\n"


def _node_side_env(root, source_dir):
    from xrce.agent.interfaces.builder import build

    [result] = build([str(source_dir)], cache_root=str(root / "cache"), names=["my_robot_msgs"],
                     register_results=False)
    env = dict(os.environ)
    site = os.path.join(result.prefix, "lib", "python%d.%d" % sys.version_info[:2], "site-packages")
    for name, value in (("PYTHONPATH", site), ("LD_LIBRARY_PATH", os.path.join(result.prefix, "lib"))):
        env[name] = os.pathsep.join([value] + ([env[name]] if env.get(name) else []))
    return env


@pytest.mark.timeout(300)
def test_readme_board_service_example_runs_as_written(tmp_path, ros_domain):  # noqa: F811
    source = readme_service_example()
    assert len(source.strip().splitlines()) <= 24
    package = tmp_path / "src" / "my_robot_msgs"
    (package / "srv").mkdir(parents=True)
    (package / "package.xml").write_text(PACKAGE_XML)
    (package / "CMakeLists.txt").write_text(CMAKE_LISTS)
    (package / "srv" / "SetLed.srv").write_text(_srv_definition(source))
    generated = subprocess.run([sys.executable, "-m", "xrce.client", "gen-msgs", str(package), "-o", str(tmp_path / "out")],
                               capture_output=True, text=True, timeout=120, cwd=REPO)
    assert generated.returncode == 0, generated.stderr
    assert "from xrce.msgs.my_robot_msgs import SetLed" in generated.stderr  # the line the example has
    env = _node_side_env(tmp_path, tmp_path / "src")
    with AgentProcess("udp4", "-m", "dds") as agent:
        board_source = source.replace('UdpTransport("192.168.1.10", 8888)', 'UdpTransport("127.0.0.1", %d)' % agent.port)
        board_source = board_source.replace("domain_id=0", "domain_id=%d" % ros_domain)
        assert board_source.count(str(agent.port)) == 1 and board_source.count("domain_id=%d" % ros_domain) == 1
        node = subprocess.Popen([sys.executable, "-c", NODE_SCRIPT], env=env, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        try:
            board = run_micropython(board_source, timeout=180,
                                    mounts=[(tmp_path / "out" / "xrce" / "msgs" / "my_robot_msgs",
                                             "/lib/xrce/msgs/my_robot_msgs")])
        finally:
            node.terminate()
            node_out, _ = node.communicate(timeout=60)
    assert board.returncode == 0, board.stdout + board.stderr + node_out
    lines = board.stdout.splitlines()
    assert "led 2 True" in lines and "led 7 False" in lines, board.stdout + node_out
    assert "rate [12.5]" in lines, board.stdout + node_out
    assert [line for line in node_out.splitlines() if line.startswith("reply ")] == [
        "reply True", "reply False"], node_out
