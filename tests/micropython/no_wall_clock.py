"""Run under MicroPython by tests/board/test_micropython_no_wall_clock.py: the board has no wall clock.

Before anything imports it, ``time`` is replaced in sys.modules by a stand-in that has the port's
monotonic calls only (ticks_*, sleep*), as a bare-metal port without a real-time clock has: xrce and
the TurtleBot3 firmware then run on ticks and the agent's TIMESTAMP_REPLY alone.

argv: agent_port domain_id run_seconds
Prints "key value" lines the test reads.
"""

import sys
import time as _port_time


class _BoardTime:
    pass


board_time = _BoardTime()
for _name in ("ticks_ms", "ticks_us", "ticks_diff", "ticks_add", "sleep", "sleep_ms", "sleep_us"):
    if hasattr(_port_time, _name):
        setattr(board_time, _name, getattr(_port_time, _name))
sys.modules["time"] = board_time

import xrce  # noqa: E402
from nodeudp_transport import make_callbacks  # noqa: E402
from xrce.examples.turtlebot3 import TurtleBot3  # noqa: E402
from xrce.transports.custom import CustomTransport  # noqa: E402

print("wall_clock_gone", xrce.time is board_time and not hasattr(xrce.time, "time")
      and not hasattr(xrce.time, "time_ns"))
print("board_ns", xrce.epoch_ns())  # the board's own clock: ticks_ms() when first read

port = int(sys.argv[1])
domain_id = int(sys.argv[2])
run_ms = int(float(sys.argv[3]) * 1000)
transport = CustomTransport(*make_callbacks("127.0.0.1", port), framing=False)
robot = TurtleBot3(transport, domain_id=domain_id, key=b"\x54\x42\x00\x07", time_sync_period_ms=1000)
session = robot.session
print("before_sync_ns", session.epoch_ns())
print("connect", robot.connect(timeout_ms=500, attempts=20) is not None)
print("setup", robot.setup())  # its first sync_time() is in here
print("failed_topics", ",".join(robot.failed_topics) or "-")
print("synced", session.time_synced)
print("time_offset_ns", session.time_offset_ns)
print("time_rtt_ns", session.time_rtt_ns)
print("sync_again", session.sync_time(timeout_ms=500, attempts=3))
print("epoch_ns", session.epoch_ns())
robot.run(duration_ms=run_ms)
print("time_syncs", robot.time_syncs)
print("stale_timestamps", session.stale_timestamps)
for topic in ("sensor_state", "imu", "odom"):
    print("published_" + topic, robot.published.get(topic, 0))
print("last_epoch_ns", session.epoch_ns())
robot.shutdown()
print("done", True)
