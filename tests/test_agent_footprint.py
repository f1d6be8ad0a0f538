"""What the agent process leaves out to stay small (bench/agent_cost.py measures the memory)."""

import subprocess
import sys

import pytest

from agent_process import REPO, AgentProcess
from ros_helpers import ros_domain  # noqa: F401


def test_no_rcl_log_file(ros_domain, tmp_path):  # noqa: F811
    """rcl's own log file stays closed (xrce/agent/ros_domain.py ROS_ARGS); every rclpy process
    that opens it leaves one file per start in ROS_LOG_DIR."""
    pytest.importorskip("rclpy")
    with AgentProcess("udp4", env={"ROS_LOG_DIR": str(tmp_path)}) as agent:
        assert agent.banner
    assert agent.proc.returncode == 0
    assert list(tmp_path.iterdir()) == []


_MODULES_OF_A_SERVING_AGENT = r"""
import io, os, sys, threading
banner = threading.Event()


class Watch(io.TextIOWrapper):
    def write(self, text):
        if "agent on port" in text:
            banner.set()
        return super().write(text)


sys.stdout = Watch(sys.stdout.detach(), line_buffering=True)


def report():
    banner.wait(60)
    sys.stderr.write("MODULES " + " ".join(sorted(sys.modules)) + "\n")
    sys.stderr.flush()
    os._exit(0)


threading.Thread(target=report, daemon=True).start()
from xrce.agent.launcher import main
main(sys.argv[1:])
"""

# Each was imported by every agent once; each is only needed by some subcommand or option.
_NOT_IMPORTED_BY_A_UDP_AGENT = ("xrce.agent.demo", "xrce.agent.tcp_links",
                                "xrce.agent.serial_links", "shutil", "ssl",
                                "xml.etree.ElementTree")


def test_a_udp_agent_leaves_out_what_other_subcommands_use():
    run = subprocess.run([sys.executable, "-c", _MODULES_OF_A_SERVING_AGENT,
                          "udp4", "-p", "0", "-m", "ced"], cwd=REPO, capture_output=True,
                         text=True, timeout=60)
    line = [text for text in run.stderr.splitlines() if text.startswith("MODULES ")]
    assert line, run.stdout + run.stderr
    modules = set(line[0].split()[1:])
    assert "xrce.agent.udp_links" in modules and "xrce.agent.engine" in modules
    assert not modules.intersection(_NOT_IMPORTED_BY_A_UDP_AGENT)
