"""``xrce-ros``: the ``ros2`` verbs a micro-ROS user needs to see a board, for a venv that has rclpy
from the PyPI wheels but no ``ros2`` (ros2cli has no PyPI wheels).

The syntax and the output are ros2cli's (Jazzy) for the verbs it has: ``topic list/echo/hz/pub``,
``node list``, ``service list/call``, ``param list/get/set``, ``action list/send_goal``. The code is
our own, on rclpy alone: ``rosidl_runtime_py`` (ros2cli's YAML conversion) is not in the wheels
either, so ``messages`` does that part. ``cli`` holds the command line and the exit codes, ``graph``
the short-lived node every verb runs on; one module per verb group.

No daemon: like ``ros2 --no-daemon``, every command joins the graph, waits for discovery
(``--spin-time``) and leaves. ROS_DOMAIN_ID, ROS_AUTOMATIC_DISCOVERY_RANGE, ROS_LOCALHOST_ONLY and
the RMW's own variables apply as they do to any rclpy program.
"""
