"""Run under MicroPython by tests/board/test_micropython_client.py: the unmodified client over a custom
transport bridged to Node's UDP socket, against a real xrce-agent.

argv: agent_port  (the CPython side of the test publishes Twist on /mp_cmd and reads /mp_chatter)
"""

import sys

from nodeudp_transport import make_callbacks
from xrce.client.session import Session, ping_agent
from xrce.msgs.geometry_msgs import Twist
from xrce.msgs.std_msgs import String
from xrce.transports.custom import CustomTransport

port = int(sys.argv[1])
transport = CustomTransport(*make_callbacks("127.0.0.1", port), framing=False)

rtt = ping_agent(transport, 500, 10)
print("ping_agent", rtt is not None)
session = Session(transport, key=b"\x4d\x50\x00\x01", history=8)
print("create", session.create(attempts=10, timeout_ms=500))
print("ping_session", session.ping(500, 3))
print("sync_time", session.sync_time(500, 3))
node = session.create_participant(name="micropython_node")
writer = session.create_writer(node, "/mp_chatter", String)
received = []
reader = session.create_reader(node, "/mp_cmd", Twist, received.append)
print("entities", session.run_until_all_status(2000))
for i in range(10):
    session.write(writer, String(data="from micropython %d" % i))
print("delivered", session.run_until_confirm_delivery(3000))
deadline = 200
while len(received) < 3 and deadline > 0:
    session.spin_once(20)
    deadline -= 1
print("received", len(received), received[0].linear.x if received else None)
print("epoch_ms", session.epoch_ms())
# The methods the session loads on first use (xrce.client.on_demand) work on a board too.
session.cancel_data(reader)
session.delete_entity(writer)
print("delete_entity", session.run_until_all_status(2000))
print("delete", session.delete(attempts=3, timeout_ms=500))
