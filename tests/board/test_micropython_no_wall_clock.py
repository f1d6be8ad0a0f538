"""A board without a wall clock (issue 44): MicroPython with ``time.time`` and ``time.time_ns``
taken away runs ``sync_time()`` and the unmodified TurtleBot3 firmware (set-up, then a few seconds
of its loop) against a real ``xrce-agent -m dds``, and its stamps reach rclpy on the agent's clock.

Its clock is ticks alone until the agent's TIMESTAMP_REPLY sets the epoch, as eProsima's client on
an RTOS (uxr_nanos from the tick count, uxr_epoch_nanos less the offset the reply gave). The agent
runs on this machine, so the agent's clock is this test's ``time.time_ns()``.

The tick arithmetic that carries the clock over ticks_us()'s wrap is checked on CPython with
simulated ticks (below): the harness cannot wait 17 minutes for a wrap.
"""

import threading
import time
from pathlib import Path

import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu as RosImu

from agent_process import AgentProcess
from mp_harness import run_micropython
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from xrce.client import on_demand

SCRIPT = Path(__file__).resolve().parents[1] / "micropython" / "no_wall_clock.py"
BEST_EFFORT = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
# The port's ticks step in whole milliseconds (JavaScript's clock): one step at each end of an exchange.
CLOCK_STEP_NS = 1_000_000
EPOCH_2026_NS = 1_767_225_600 * 10**9


@pytest.mark.timeout(120)
def test_sync_time_and_turtlebot3_without_a_wall_clock(ros_peer, ros_domain):  # noqa: F811
    from xrce.agent import interfaces

    # Built before the run (a cache hit after the first time): built on demand, the agent's first
    # answers came after the firmware's set-up had given up on its topics.
    interfaces.build(names=["tf2_msgs", "turtlebot3_msgs"])
    imu = []
    ros_peer.node.create_subscription(RosImu, "/imu", lambda m: imu.append((time.time_ns(), m)), BEST_EFFORT)
    with AgentProcess("udp4", "-m", "dds") as agent:
        result = {}
        started_ns = time.time_ns()
        runner = threading.Thread(target=lambda: result.setdefault(
            "run", run_micropython(SCRIPT, agent.port, ros_domain, 4, timeout=90)), daemon=True)
        runner.start()
        runner.join(100)
        ended_ns = time.time_ns()
    run = result["run"]
    assert run.returncode == 0, run.stdout + run.stderr
    lines = dict(line.split(" ", 1) for line in run.stdout.splitlines() if " " in line)
    assert lines["wall_clock_gone"] == "True", run.stdout
    # Before the agent answered, the board's clock is its ticks (time since the port started), not
    # an epoch: nothing read a wall clock.
    assert 0 <= int(lines["board_ns"]) < 10**9 * 3600, lines["board_ns"]
    assert 0 <= int(lines["before_sync_ns"]) < 10**9 * 3600, lines["before_sync_ns"]
    assert lines["connect"] == lines["setup"] == lines["synced"] == lines["sync_again"] == "True", run.stdout
    assert lines["done"] == "True" and lines["failed_topics"] == "-", run.stdout
    # The offset the reply gave is the whole epoch (the board's ticks against the agent's wall clock).
    assert int(lines["time_offset_ns"]) < -EPOCH_2026_NS, lines["time_offset_ns"]
    assert 0 <= int(lines["time_rtt_ns"]) < 1_000_000_000, lines["time_rtt_ns"]  # a local exchange
    for key in ("epoch_ns", "last_epoch_ns"):
        assert started_ns <= int(lines[key]) <= ended_ns, (key, lines[key], started_ns, ended_ns)
    assert int(lines["time_syncs"]) >= 4  # set-up's, then one a second of the run
    assert int(lines["published_imu"]) >= 20 and int(lines["published_odom"]) >= 20, run.stdout
    # The firmware's stamps are the agent's clock: every one inside the run on this machine's clock
    # (a stamp from the board's ticks would be decades off), and none later than its arrival in
    # rclpy by more than a sync's error can make it.
    stamped = [(received, m.header.stamp.sec * 10**9 + m.header.stamp.nanosec) for received, m in imu]
    assert len(stamped) >= 20, len(stamped)
    assert all(started_ns <= stamp <= ended_ns for _, stamp in stamped), (started_ns, stamped[:3], ended_ns)
    delays = sorted(received - stamp for received, stamp in stamped)
    assert delays[0] > -(CLOCK_STEP_NS + 50_000_000), delays[:5]


class _Ticks:
    """A board's ticks_ms()/ticks_us(): both wrap at 2**30, as MicroPython's do."""

    PERIOD = 1 << 30

    def __init__(self, start_us):
        self.us = start_us

    def ticks_us(self):
        return self.us % self.PERIOD

    def ticks_ms(self):
        return (self.us // 1000) % self.PERIOD

    @staticmethod
    def ticks_diff(a, b):
        return ((a - b + (1 << 29)) % (1 << 30)) - (1 << 29)


def _clock_ns(demand):
    return ((demand[on_demand._BASE] << 16) + demand[on_demand._NOW_S]) * 10**9 + demand[on_demand._NOW_NS]


@pytest.mark.parametrize("start_us", [0, (1 << 30) - 5_000, 7_345_678_901, 1_000_000 * ((1 << 30) - 3_000)])
def test_the_clock_without_a_wall_clock_follows_ticks_over_their_wraps(monkeypatch, start_us):
    ticks = _Ticks(start_us)
    monkeypatch.setattr(on_demand, "ticks_us", ticks.ticks_us)
    monkeypatch.setattr(on_demand, "ticks_ms", ticks.ticks_ms)
    monkeypatch.setattr(on_demand, "ticks_diff", _Ticks.ticks_diff)
    monkeypatch.setattr(on_demand, "time", object())  # no time.time, no time.time_ns
    demand = [None] * 20
    on_demand._now(demand)
    assert _clock_ns(demand) == (ticks.ticks_ms()) * 10**6  # starts at ticks_ms()
    first = _clock_ns(demand)
    # Steps short and long: within a ticks_us() period, past it (17.9 min) several times over, and
    # up to 5 days (under half of ticks_ms()'s period); a microsecond is never lost or gained.
    for step_us in (1, 999, 123_456, 499_000_000, 501_000_000, (1 << 30) + 17, 3 * (1 << 30) - 1,
                    86_400_000_000 * 5, 7):
        ticks.us += step_us
        on_demand._now(demand)
        assert _clock_ns(demand) - first == (ticks.us - start_us) * 1000, step_us
