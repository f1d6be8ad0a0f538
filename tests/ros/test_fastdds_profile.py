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


@pytest.mark.parametrize("major, variable, name", [
    (2, "FASTRTPS_DEFAULT_PROFILES_FILE", "fastdds_profile.xml"),  # Jazzy
    (3, "FASTDDS_DEFAULT_PROFILES_FILE", "fastdds3_profile.xml"),  # Kilted: FASTRTPS_ is deprecated
])
def test_installed_when_the_user_has_no_fast_dds_configuration(tmp_path, major, variable, name):
    environ = {"ROS_DOMAIN_ID": "3"}
    path = fastdds_profile.install(environ, cwd=str(tmp_path), fastdds_major=major)
    assert os.path.basename(path) == name and os.path.exists(path)
    assert environ == {"ROS_DOMAIN_ID": "3", variable: path}
    environ = {"RMW_IMPLEMENTATION": "rmw_fastrtps_dynamic_cpp"}  # same participant code
    assert fastdds_profile.install(environ, cwd=str(tmp_path), fastdds_major=major) == path
    # The discovery server variable makes the participant a client; the profile leaves that be.
    environ = {"ROS_DISCOVERY_SERVER": "127.0.0.1:11811"}
    assert fastdds_profile.install(environ, cwd=str(tmp_path), fastdds_major=major) == path
    assert environ["ROS_DISCOVERY_SERVER"] == "127.0.0.1:11811"


def test_each_profile_changes_the_same_settings():
    import xml.etree.ElementTree as ElementTree

    def settings(major):
        root = ElementTree.parse(fastdds_profile.profile_for(major)[0]).getroot()
        return {element.tag.split("}")[1]: (element.text or "").strip() for element in root.iter()
                if len(element) == 0}

    two, three = settings(2), settings(3)
    for name in ("preallocated_number", "dynamic", "sec", "nanosec"):
        assert two[name] == three[name], name
    assert two["bytesPerPeriod"] == three["max_bytes_per_period"] == "0"  # no limit: asynchronous only
    assert three["flow_controller_name"] == three["name"]  # the builtin writers use the listed one


@pytest.mark.parametrize("major", [2, 3])
@pytest.mark.parametrize("environ, cwd_file", [
    ({"FASTRTPS_DEFAULT_PROFILES_FILE": "/etc/robot/fastdds.xml"}, None),
    ({"FASTRTPS_DEFAULT_PROFILES_FILE": ""}, None),
    ({"FASTDDS_DEFAULT_PROFILES_FILE": "/etc/robot/fastdds.xml"}, None),
    ({"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}, None),
    ({}, "DEFAULT_FASTRTPS_PROFILES.xml"),
    ({}, "DEFAULT_FASTDDS_PROFILES.xml"),
])
def test_a_user_configuration_keeps_it_out(tmp_path, environ, cwd_file, major):
    if cwd_file:
        (tmp_path / cwd_file).write_text("<dds/>")
    before = dict(environ)
    assert fastdds_profile.user_profile_reason(environ, str(tmp_path))
    assert fastdds_profile.install(environ, cwd=str(tmp_path), fastdds_major=major) is None
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


def _participant_output(profile, variable):
    """(exit code, output) of a process creating a participant with ``profile`` as Fast DDS's
    default profiles file (in the test's ROS domain)."""
    env = {k: v for k, v in os.environ.items() if not k.endswith("_DEFAULT_PROFILES_FILE")}
    env[variable] = str(profile)
    run = subprocess.run([sys.executable, "-c", _PARTICIPANT], env=env, capture_output=True,
                         text=True, timeout=60)
    return run.returncode, run.stdout + run.stderr


def test_fast_dds_reads_the_profile_without_error(ros_domain, tmp_path):  # noqa: F811
    pytest.importorskip("rclpy")
    from xrce.agent.interfaces import ros_install as rosenv

    installed = rosenv.installed_fastdds()
    assert installed, "no Fast DDS library found beside rclpy in %s" % rosenv.ament_prefixes()
    path, variable = fastdds_profile.profile_for(installed[0])
    print("Fast DDS %s: %s through %s" % (installed[1], os.path.basename(path), variable))
    code, output = _participant_output(path, variable)
    assert code == 0 and "participant ok" in output
    assert "XMLPARSER" not in output and "deprecated" not in output, output
    # The check above can fail: the same profile with a value Fast DDS rejects is reported, and
    # so is the other major version's file (the element each lacks).
    broken = tmp_path / "broken.xml"
    with open(path) as profile:
        broken.write_text(profile.read().replace("<dynamic>true", "<dynamic>sometimes"))
    code, output = _participant_output(broken, variable)
    assert "XMLPARSER" in output
    other = fastdds_profile.profile_for(2 if installed[0] >= 3 else 3)[0]
    code, output = _participant_output(other, variable)
    assert "XMLPARSER" in output and ("throughputController" in output or "flow_controller" in output), \
        output


def test_the_agent_installs_it_unless_the_user_has_one(ros_domain, tmp_path):  # noqa: F811
    pytest.importorskip("rclpy")
    from xrce.agent.interfaces import ros_install as rosenv

    path, _ = fastdds_profile.profile_for(rosenv.installed_fastdds()[0])
    line = "Fast DDS participant profile: %s" % path
    with AgentProcess("udp4", "-v", "5") as agent:
        pass
    assert any(line in text for text in agent.output), "".join(agent.output)
    assert "XMLPARSER" not in "".join(agent.output), "".join(agent.output)
    own = tmp_path / "own.xml"
    own.write_text('<?xml version="1.0" encoding="UTF-8" ?>\n'
                   '<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"/>\n')
    with AgentProcess("udp4", "-v", "5", env={"FASTDDS_DEFAULT_PROFILES_FILE": str(own)}) as agent:
        pass
    output = "".join(agent.output)
    assert "Fast DDS participant profile" not in output and agent.banner, output
