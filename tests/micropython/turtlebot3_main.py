"""Run under MicroPython by tests/turtlebot3/test_turtlebot3.py: the unmodified xrce/examples/turtlebot3.py
over a custom transport bridged to Node's UDP socket, against a real xrce-agent -m dds.

argv: agent_port domain_id run_seconds cmd_vel_reliable(0|1)
Prints "key value" lines the test reads: the robot's counters and final state.
"""

import sys

from nodeudp_transport import make_callbacks
from xrce.examples.turtlebot3 import TurtleBot3
from xrce.transports.custom import CustomTransport

port = int(sys.argv[1])
domain_id = int(sys.argv[2])
run_ms = int(float(sys.argv[3]) * 1000)
reliable = sys.argv[4] == "1"

transport = CustomTransport(*make_callbacks("127.0.0.1", port), framing=False)
robot = TurtleBot3(transport, domain_id=domain_id, cmd_vel_reliable=reliable,
                   key=b"\x54\x42\x00\x03")
print("connect", robot.connect(timeout_ms=500, attempts=20) is not None)
print("setup", robot.setup())
print("failed_topics", ",".join(robot.failed_topics) or "-")
print("time_offset_ns", robot.session.time_offset_ns)
print("time_rtt_ns", robot.session.time_rtt_ns)
robot.run(duration_ms=run_ms)
print("commands_received", robot.commands_received)
print("last_command", "%r,%r" % robot.last_command if robot.last_command else "-")
print("failsafe_trips", robot.failsafe_trips)
for topic in ("sensor_state", "imu", "odom", "tf", "battery_state"):
    print("published_" + topic, robot.published.get(topic, 0))
print("x", robot.x)
print("y", robot.y)
robot.shutdown()
print("done", True)
