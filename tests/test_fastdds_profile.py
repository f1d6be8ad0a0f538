"""The Fast DDS profile the agent installs when the user has none (xrce/agent/middleware/ros/fastdds_profile.py):
when it goes in, that a user's configuration keeps it out, that Fast DDS reads it without error,
and that ``xrce-agent`` installs it before its participant exists."""

import os
import subprocess
import sys

import pytest

from agent_process import AgentProcess
from ros_helpers import ros_domain  # noqa: F401
from xrce.agent.middleware.ros import fastdds_profile


def test_installed_when_the_user_has_no_fast_dds_configuration(tmp_path):
    environ = {"ROS_DOMAIN_ID": "3"}
    assert fastdds_profile.install(environ, cwd=str(tmp_path)) == fastdds_profile.PROFILE_PATH
    assert environ["FASTRTPS_DEFAULT_PROFILES_FILE"] == fastdds_profile.PROFILE_PATH
    environ = {"RMW_IMPLEMENTATION": "rmw_fastrtps_dynamic_cpp"}  # same participant code
    assert fastdds_profile.install(environ, cwd=str(tmp_path)) == fastdds_profile.PROFILE_PATH


@pytest.mark.parametrize("environ, cwd_file", [
    ({"FASTRTPS_DEFAULT_PROFILES_FILE": "/etc/robot/fastdds.xml"}, None),
    ({"FASTRTPS_DEFAULT_PROFILES_FILE": ""}, None),
    ({"FASTDDS_DEFAULT_PROFILES_FILE": "/etc/robot/fastdds.xml"}, None),
    ({"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}, None),
    ({}, "DEFAULT_FASTRTPS_PROFILES.xml"),
    ({}, "DEFAULT_FASTDDS_PROFILES.xml"),
])
def test_a_user_configuration_keeps_it_out(tmp_path, environ, cwd_file):
    if cwd_file:
        (tmp_path / cwd_file).write_text("<dds/>")
    before = dict(environ)
    assert fastdds_profile.user_profile_reason(environ, str(tmp_path))
    assert fastdds_profile.install(environ, cwd=str(tmp_path)) is None
    assert environ == before


_PARTICIPANT = """
import rclpy
from rclpy.context import Context
from rclpy.node import Node
from std_msgs.msg import String
context = Context()
rclpy.init(args=[], context=context)
node = Node("profile_check", context=context, start_parameter_services=False, enable_rosout=False)
node.create_publisher(String, "/profile_check", 10).publish(String(data="x"))
node.destroy_node()
rclpy.shutdown(context=context)
print("participant ok")
"""


def _participant_output(profile):
    """(exit code, output) of a process creating a participant with ``profile`` as Fast DDS's
    default profiles file (in the test's ROS domain)."""
    env = dict(os.environ, FASTRTPS_DEFAULT_PROFILES_FILE=str(profile))
    run = subprocess.run([sys.executable, "-c", _PARTICIPANT], env=env, capture_output=True,
                         text=True, timeout=60)
    return run.returncode, run.stdout + run.stderr


def test_fast_dds_reads_the_profile_without_error(ros_domain, tmp_path):  # noqa: F811
    pytest.importorskip("rclpy")
    code, output = _participant_output(fastdds_profile.PROFILE_PATH)
    assert code == 0 and "participant ok" in output
    assert "XMLPARSER" not in output, output
    # The check above can fail: the same profile with a value Fast DDS rejects is reported.
    broken = tmp_path / "broken.xml"
    with open(fastdds_profile.PROFILE_PATH) as profile:
        broken.write_text(profile.read().replace("<dynamic>true", "<dynamic>sometimes"))
    code, output = _participant_output(broken)
    assert "XMLPARSER" in output


def test_the_agent_installs_it_unless_the_user_has_one(ros_domain, tmp_path):  # noqa: F811
    pytest.importorskip("rclpy")
    line = "Fast DDS participant profile: %s" % fastdds_profile.PROFILE_PATH
    with AgentProcess("udp4", "-v", "5") as agent:
        pass
    assert any(line in text for text in agent.output), "".join(agent.output)
    own = tmp_path / "own.xml"
    own.write_text('<?xml version="1.0" encoding="UTF-8" ?>\n'
                   '<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"/>\n')
    with AgentProcess("udp4", "-v", "5", env={"FASTRTPS_DEFAULT_PROFILES_FILE": str(own)}) as agent:
        pass
    output = "".join(agent.output)
    assert "Fast DDS participant profile" not in output and agent.banner, output
