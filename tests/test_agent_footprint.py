"""What the agent process leaves out to stay small (bench/agent_cost.py measures the memory)."""

import pytest

from agent_process import AgentProcess
from ros_helpers import ros_domain  # noqa: F401


def test_no_rcl_log_file(ros_domain, tmp_path):  # noqa: F811
    """rcl's own log file stays closed (xrce/agent/ros_domain.py ROS_ARGS); every rclpy process
    that opens it leaves one file per start in ROS_LOG_DIR."""
    pytest.importorskip("rclpy")
    with AgentProcess("udp4", env={"ROS_LOG_DIR": str(tmp_path)}) as agent:
        assert agent.banner
    assert agent.proc.returncode == 0
    assert list(tmp_path.iterdir()) == []
