"""The README's MicroPython example runs as written (only AGENT and DOMAIN changed) under real
MicroPython 1.27, through its UDP transport, against a real ``xrce-agent -m dds`` and rclpy."""

import re
import threading
import time
from pathlib import Path

from geometry_msgs.msg import Twist
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from agent_process import AgentProcess
from mp_harness import run_micropython
from ros_helpers import ros_domain, ros_peer  # noqa: F401

README = Path(__file__).resolve().parents[1] / "README.md"


def readme_example():
    text = README.read_text()
    section = text[text.index("## The client on MicroPython"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_readme_micropython_example_runs_as_written(ros_peer, ros_domain):  # noqa: F811
    source = readme_example()
    assert len(source.strip().splitlines()) <= 20
    with AgentProcess("udp4", "-m", "dds") as agent:
        source = re.sub(r"^AGENT = .*$", "AGENT = (%r, %d)" % ("127.0.0.1", agent.port), source, flags=re.M)
        source = re.sub(r"^DOMAIN = .*$", "DOMAIN = %d" % ros_domain, source, flags=re.M)
        chatter = []
        best_effort = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
        ros_peer.node.create_subscription(String, "/chatter", chatter.append, best_effort)
        cmd_vel = ros_peer.node.create_publisher(Twist, "/cmd_vel", 10)
        stop = threading.Event()

        def drive():
            while not stop.is_set():
                message = Twist()
                message.linear.x, message.angular.z = 0.5, -0.25
                cmd_vel.publish(message)
                time.sleep(0.1)

        driver = threading.Thread(target=drive, daemon=True)
        driver.start()
        try:
            result = run_micropython(source, timeout=120)
        finally:
            stop.set()
            driver.join(5)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "cmd_vel 0.5 -0.25" in result.stdout
    assert len(chatter) >= 50 and chatter[-1].data.startswith("hello ")
