"""``xrce-ros``: the ``ros2`` verbs a micro-ROS user needs to see a board, for a venv that has rclpy
from the PyPI wheels but no ``ros2`` (ros2cli has no PyPI wheels).

The syntax and the output are ros2cli's (Jazzy) for the verbs it has: ``topic
list/info/echo/hz/pub``, ``node list/info``, ``service list/call``, ``param list/get/set``,
``action list/send_goal``, ``interface show``. The code is
our own, on rclpy alone: ``rosidl_runtime_py`` (ros2cli's YAML conversion) is not in the wheels
either, so ``messages`` does that part. ``cli`` holds the command line and the exit codes, ``graph``
the short-lived node every verb runs on; one module per verb group.

No daemon: like ``ros2 --no-daemon``, every command joins the graph, waits for discovery
(``--spin-time``) and leaves. ROS_DOMAIN_ID, ROS_AUTOMATIC_DISCOVERY_RANGE, ROS_LOCALHOST_ONLY and
the RMW's own variables apply as they do to any rclpy program.
"""

import os
import shutil
import sys


def ros2_command(environ=None, cwd=None):
    """How a user of this venv types the ``ros2`` command in another shell, for banners to print:
    ``ros2`` when PATH has one (a ROS install), else this venv's ``xrce-ros``, by name when PATH
    finds it and by its path (relative to ``cwd`` when below it) when it does not."""
    path = (os.environ if environ is None else environ).get("PATH", os.defpath)
    if shutil.which("ros2", path=path):
        return "ros2"
    ours = os.path.join(os.path.dirname(sys.executable), "xrce-ros")
    found = shutil.which("xrce-ros", path=path)
    if found and os.path.realpath(found) == os.path.realpath(ours):
        return "xrce-ros"
    if not os.path.exists(ours):  # xrce run from a checkout without an install of its scripts
        return "%s -m xrce.tools.ros_cli" % sys.executable
    relative = os.path.relpath(ours, cwd or os.getcwd())
    return ours if relative.startswith("..") else relative
