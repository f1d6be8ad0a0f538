"""Run under MicroPython by tests/client/test_client_parameters.py: a node with a parameter server
(xrce.client.parameters) over a custom transport bridged to Node's UDP socket, against a real
xrce-agent -m dds, until rclpy sets its ``done`` parameter (or ``seconds`` pass).

argv: agent_port domain_id seconds
Prints "key value" lines the test reads.
"""

import sys

from nodeudp_transport import make_callbacks
from xrce import ticks_diff, ticks_ms
from xrce.client.session import Session
from xrce.transports.custom import CustomTransport

port = int(sys.argv[1])
domain_id = int(sys.argv[2])
seconds = float(sys.argv[3])

changes = []


def on_change(name, value):
    changes.append(name)
    if name == "motor_kp" and value > 500:
        return "motor_kp above 500 saturates the driver"
    return True


session = Session(CustomTransport(*make_callbacks("127.0.0.1", port), framing=False),
                  key=b"\x50\x41\x52\x4d")
print("connect", session.create(attempts=20, timeout_ms=500))
node = session.create_participant(domain_id=domain_id, name="tb3_params")
from xrce.client.parameters import ParameterServer  # noqa: E402  (loaded only when used)

params = ParameterServer(session, node, "/tb3_params", on_change=on_change)
params.declare("motor_kp", 120, min_value=0, max_value=1000, description="wheel PID gain")
params.declare("wheel_radius", 0.033, min_value=0.01, max_value=0.1)
params.declare("use_imu", True)
params.declare("robot_name", "tb3-0042", read_only=True)
params.declare("done", False)
print("setup", session.run_until_all_status(10000))
start = ticks_ms()
while not params["done"] and ticks_diff(ticks_ms(), start) < seconds * 1000:
    session.spin_once(20)
session.run_until_timeout(300)  # the reply to the set of ``done`` goes out
print("motor_kp", params["motor_kp"])
print("wheel_radius", params["wheel_radius"])
print("use_imu", params["use_imu"])
print("changes", ",".join(changes))
session.delete(attempts=2, timeout_ms=500)
print("done", True)
