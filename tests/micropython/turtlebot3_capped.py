"""Run under MicroPython by tests/board/test_turtlebot3_heap.py with run.mjs --stepped, i.e. with a real
heap cap: the unmodified xrce/examples/turtlebot3.py over the real xrce.transports.udp.UdpTransport,
against a real xrce-agent. Its ``socket`` is tests/micropython/socket.py, which allocates what a
port's does: ``recv(n)`` a new n-byte buffer and a new bytes per datagram, so a board's per-datagram
receive block is in the figures.

argv: agent_port run_seconds settle_seconds client_key_hex
The harness collects garbage between the steps of main() and fails the run with a MemoryError as
soon as a step needed more heap than the cap. The loop's steps are the stages of robot.step() (one
message taken in, the fail-safe check, one publication, a time sync: TurtleBot3.step_stages()), so
the cap measures what the firmware keeps plus what one of those allocates, as a board's collector
would see it, rather than the garbage of a whole pass. Prints "key value" lines:
heap figures are live bytes (after collection) above the interpreter's own baseline.
"""

import sys

import mpheap
from xrce import ticks_diff, ticks_ms

# The example's modules, one per step: the harness can collect only between steps, while a board's
# collector also runs in the middle of an import. (xrce.client.fragments: the session loads it on the
# first /odom, which does not fit one message; xrce.client.on_demand on the first time sync.)
MODULES = ("socket", "xrce.wire.cdr", "xrce.wire.message", "xrce.wire.streams", "xrce.client.outbound",
           "xrce.client.session", "xrce.client.ping", "xrce.client.recovery", "xrce.client.fragments",
           "xrce.client.on_demand", "xrce.transports", "xrce.transports.udp", "xrce.msgs")
TYPES = (("xrce.msgs.geometry_msgs", "Twist"), ("xrce.msgs.geometry_msgs", "TransformStamped"),
         ("xrce.msgs.turtlebot3_msgs", "SensorState"), ("xrce.msgs.sensor_msgs", "Imu"),
         ("xrce.msgs.sensor_msgs", "BatteryState"), ("xrce.msgs.nav_msgs", "Odometry"),
         ("xrce.msgs.tf2_msgs", "TFMessage"))


def main():
    port = int(sys.argv[1])
    run_ms = int(float(sys.argv[2]) * 1000)
    settle_ms = int(float(sys.argv[3]) * 1000)
    key = bytes(int(sys.argv[4][i:i + 2], 16) for i in (0, 2, 4, 6))
    yield
    baseline = mpheap.live
    for name in MODULES:
        __import__(name)
        yield
    for package, type_name in TYPES:
        getattr(__import__(package, None, None, (type_name,)), type_name)
        yield
    from xrce.examples.turtlebot3 import TurtleBot3
    from xrce.transports.udp import UdpTransport
    yield
    print("baseline", baseline)  # the interpreter's and the harness's own heap, under the cap too
    print("imported", mpheap.live - baseline)
    transport = UdpTransport("127.0.0.1", port)
    # Time sync every second instead of 10 s, so the periodic path runs often during the run.
    robot = TurtleBot3(transport, cmd_vel_reliable=True, key=key, time_sync_period_ms=1000)
    print("connect", robot.connect(timeout_ms=500, attempts=20) is not None)
    yield
    # One stage of the setup per step: the harness collects the garbage of each exchange.
    ok = False
    stage = top_stage = top = 0
    for ok in robot.setup_stages():
        yield
        stage += 1
        if mpheap.high > top:  # the stage that just ended
            top, top_stage = mpheap.high, stage
    print("setup", ok)
    print("peak_setup_stage", top_stage)  # its number in setup_stages(), from 1
    print("after_setup", mpheap.live - baseline)
    print("peak_setup", mpheap.peak)  # absolute, as the --heap cap
    start = ticks_ms()
    settled = None
    low = high = 0
    peak_loop = 0  # the highest a step of the loop took the heap (absolute, as peak)
    # The live heap's low-water mark over the 10 s after settling and over the last 10 s: a leak
    # raises it, while messages that happen to be in flight (unacknowledged in a reliable window,
    # fragments being reassembled) when a step ends only move single samples.
    first_low = last_low = None
    while ticks_diff(ticks_ms(), start) < run_ms:
        for _ in robot.step_stages():
            yield
            if mpheap.high > peak_loop:  # the step just ended (set-up's last is already past)
                peak_loop = mpheap.high
        live = mpheap.live
        elapsed = ticks_diff(ticks_ms(), start)
        if settled is None:
            if elapsed >= settle_ms:
                settled = low = high = live
        elif live < low:
            low = live
        elif live > high:
            high = live
        if settled is not None and elapsed < settle_ms + 10000 and (first_low is None or live < first_low):
            first_low = live
        if elapsed >= run_ms - 10000 and (last_low is None or live < last_low):
            last_low = live
    print("settled", settled - baseline)
    print("settled_low", low - baseline)
    print("settled_high", high - baseline)
    print("low_first_10s", first_low - baseline)
    print("low_last_10s", last_low - baseline)
    print("steps", mpheap.steps)
    print("peak", mpheap.peak)
    print("peak_loop", peak_loop)
    print("commands_received", robot.commands_received)
    print("last_command", "%r,%r" % robot.last_command if robot.last_command else "-")
    print("time_syncs", robot.time_syncs)
    for topic in ("sensor_state", "imu", "odom", "tf", "battery_state"):
        print("published_" + topic, robot.published.get(topic, 0))
    print("dropped_writes", robot.session.dropped_writes)
    print("udp_received", transport.received)
    print("udp_sent", transport.sent)
    print("output_buffers", ",".join("%02x:%d" % (sid, len(robot.session._outputs[sid].buf))
                                      for sid in sorted(robot.session._outputs)))
    print("failed_topics", ",".join(robot.failed_topics) or "-")
    print("x", robot.x)
    robot.shutdown()
    print("done", True)
