"""Type drift caught (issue 52): a board whose classes come from another definition of a type than
the agent's package. Real agent process (``-m dds``), real rclpy, our client on CPython with
classes made as gen-msgs makes them (``xrce.msgs._define``: the same tables, another definition).

- board → ROS: the agent checks a writer's first sample (then at most one a minute) against its
  package and names a drifted one once per endpoint, with the board's key, the topic, the type and
  the fix, counted in the stats: board float64 where the agent has float32, a field added at the
  end, a field removed. A matching type never warns.
- ROS → board: the board's session tells a sample its class reads past the end of, or leaves
  bytes unread of, once per reader (``session.type_drift``).
- The check's schedule, without processes: the first sample checked, the next ones published by
  the middleware's own function (nothing added per sample), one re-check a minute, none after a
  drift was named.
"""

from __future__ import annotations

import contextlib
import re
import time
from types import SimpleNamespace

import pytest

from agent_process import AgentProcess
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from xrce.agent.engine import type_drift
from xrce.agent.middleware import TopicSpec
from xrce.agent.observe.stats_view import fetch_stats
from xrce.client.session import Session
from xrce.msgs import _define
from xrce.transports.udp import UdpTransport

# The board's classes, generated from definitions that differ from the agent's packages.
BOARD_FLOAT64 = _define("std_msgs/msg/Float32", ("data",), "d")  # agent: float32 data
BOARD_FIELD_ADDED = _define("geometry_msgs/msg/Vector3", ("x", "y", "z", "w"), "dddd")
BOARD_FIELD_REMOVED = _define("geometry_msgs/msg/Vector3", ("x", "y"), "dd")


def stats_port(agent):
    return int(re.search(r"stats on 127\.0\.0\.1:(\d+)", agent.banner).group(1))


def drift_warnings(agent):
    if agent.proc.poll() is None:
        agent.drain()
    return [line for line in "".join(agent.output).splitlines() if "WARNING" in line and "type drift" in line]


@contextlib.contextmanager
def board(agent, domain_id, name):
    session = Session(UdpTransport("127.0.0.1", agent.port), history=8)
    try:
        assert session.create(attempts=5, timeout_ms=1000)
        yield session, session.create_participant(domain_id=domain_id, name=name)
    finally:
        session.delete(attempts=2, timeout_ms=500)
        session.close()


def _write(session, writer, samples, reliable):
    for sample in samples:
        session.write(writer, sample, stream_id=None if reliable else session.best_effort)
        session.run_until_timeout(20)
    session.run_until_timeout(300)


@pytest.mark.parametrize("board_class, sample, topic, ros_type, why", [
    (BOARD_FLOAT64, lambda i: BOARD_FLOAT64(data=12.5 + i), "/battery_voltage", "std_msgs/msg/Float32",
     "4 of its 8 bytes are left unread after the type's last field"),
    (BOARD_FIELD_ADDED, lambda i: BOARD_FIELD_ADDED(x=1.0, y=2.0, z=3.0, w=float(i)), "/wheel_speed",
     "geometry_msgs/msg/Vector3", "8 of its 32 bytes are left unread"),
    (BOARD_FIELD_REMOVED, lambda i: BOARD_FIELD_REMOVED(x=1.0, y=float(i)), "/wheel_speed",
     "geometry_msgs/msg/Vector3", "its 16 bytes do not decode as this type (it reads past their end)"),
], ids=["float64-for-float32", "field-added-at-end", "field-removed"])
@pytest.mark.parametrize("reliable", [False, True], ids=["best-effort", "reliable"])
def test_a_drifted_board_type_is_named_once_with_the_fix(ros_domain, board_class, sample, topic, ros_type,
                                                        why, reliable):  # noqa: F811
    with AgentProcess("udp4", "-m", "dds", "--stats-port", "0") as agent:
        port = stats_port(agent)
        with board(agent, ros_domain, "drift_board") as (session, node):
            writer = session.create_writer(node, topic, board_class, reliable=reliable)
            assert session.run_until_all_status(10000), session.last_statuses
            _write(session, writer, [sample(i) for i in range(30)], reliable)
            assert wait_until(lambda: drift_warnings(agent), 10), "".join(agent.output)
            session.run_until_timeout(500)
            lines = drift_warnings(agent)
            snapshot = fetch_stats(port)
            key = session.key.hex()
    assert len(lines) == 1, lines  # once per endpoint, however many samples
    line = lines[0]
    assert "client %s at udp4 127.0.0.1:" % key in line and "datawriter" in line, line
    assert "type drift on %s: a sample the board wrote cannot be %s as this agent has it: %s" % (
        topic, ros_type, why) in line, line
    package = ros_type.split("/")[0]
    assert ("fix: regenerate the board's classes (xrce-client gen-msgs DIR/%s) or rebuild the agent's package "
            "(xrce-agent build-interfaces DIR --package %s) from the same .msg" % (package, package)) in line, line
    assert snapshot["agent"]["mismatches"] == 1, snapshot["agent"]
    [row] = snapshot["clients"]
    [endpoint] = [e for e in row["endpoints"] if e["kind"] == "datawriter"]
    assert endpoint["samples"] == 30 and len(endpoint["mismatches"]) == 1, endpoint
    assert endpoint["mismatches"][0].startswith("type drift on %s" % topic), endpoint


def test_matching_types_never_warn_and_drift_from_ros_is_told_by_the_board(ros_peer, ros_domain, capsys):  # noqa: F811
    """Shipped classes on every kind of field (strings, sequences, nested, arrays) reach ROS with
    no warning; on the way back, the board's drifted classes tell what ROS sent them."""
    from geometry_msgs.msg import Vector3 as RosVector3
    from std_msgs.msg import Float32 as RosFloat32
    from xrce.msgs.geometry_msgs import Twist, Vector3
    from xrce.msgs.sensor_msgs import BatteryState, Imu
    from xrce.msgs.std_msgs import Float32, String

    received = {}
    for topic, ros_class in (("/volts_in", RosFloat32), ("/vector_in", RosVector3)):
        received[topic] = []
        ros_peer.node.create_subscription(ros_class, topic.replace("_in", "_out"),
                                          received[topic].append, 10)
    with AgentProcess("udp4", "-m", "dds", "--stats-port", "0") as agent:
        port = stats_port(agent)
        with board(agent, ros_domain, "matching_board") as (session, node):
            writers = []
            for topic, cls in (("/chatter", String), ("/cmd", Twist), ("/v", Vector3), ("/volts", Float32),
                               ("/battery", BatteryState), ("/imu", Imu)):
                for reliable in (False, True):
                    writers.append((session.create_writer(node, topic + ("_r" if reliable else "_be"), cls,
                                                          reliable=reliable), cls, reliable))
            seen = {"float64": [], "fewer": [], "matching": []}
            session.create_reader(node, "/volts_in", BOARD_FLOAT64, seen["float64"].append)
            session.create_reader(node, "/vector_in", BOARD_FIELD_REMOVED, seen["fewer"].append)
            session.create_reader(node, "/vector_in", Vector3, seen["matching"].append)
            assert session.run_until_all_status(10000), session.last_statuses
            battery = BatteryState(voltage=11.9, cell_voltage=[3.9, 4.0, 4.0], location="rear",
                                   serial_number="SN-1")
            battery.header.frame_id = "base_link"
            for writer, cls, reliable in writers:
                samples = {String: [String(data="hello %d" % i) for i in range(5)],
                           BatteryState: [battery] * 5}.get(cls, [cls() for _ in range(5)])
                _write(session, writer, samples, reliable)
            volts = ros_peer.node.create_publisher(RosFloat32, "/volts_in", 10)
            vectors = ros_peer.node.create_publisher(RosVector3, "/vector_in", 10)
            deadline = time.monotonic() + 20
            while time.monotonic() < deadline and not (seen["matching"] and getattr(session, "type_drift", 0) >= 2):
                volts.publish(RosFloat32(data=1.5))
                vectors.publish(RosVector3(x=1.0, y=2.0, z=3.0))
                session.run_until_timeout(100)
            assert seen["matching"] and seen["matching"][-1].z == 3.0
            # The board's own two drifted readers, each named once however many samples came.
            assert len(session._drift_named) == 2
            assert not seen["float64"]  # it read past the end: no sample handed over
            assert seen["fewer"] and session.type_drift >= 2
            session.run_until_timeout(500)
            snapshot = fetch_stats(port)
    assert drift_warnings(agent) == [], drift_warnings(agent)
    assert snapshot["agent"]["mismatches"] == 0, snapshot["agent"]
    told = [line for line in capsys.readouterr().out.splitlines() if line.startswith("xrce: reader")]
    assert len(told) == 2, told
    assert any("is not std_msgs/msg/Float32 as this board's classes define it (it reads past its end)" in line
               for line in told), told
    assert any("is not geometry_msgs/msg/Vector3 as this board's classes define it (it leaves 8 bytes unread)"
               in line for line in told), told
    assert all("regenerate the board's classes (xrce-client gen-msgs)" in line for line in told), told


def test_the_check_runs_on_the_first_sample_then_once_a_minute_and_never_per_sample():
    checked, reports, timers, published = [], [], [], []

    def publish(sample):
        published.append(sample)
        return True

    verdicts = [None, None, "4 of its 8 bytes are left unread after the type's last field"]
    middleware = SimpleNamespace(sample_check=lambda key, dds_type: lambda sample: checked.append(sample) or verdicts[len(checked) - 1])
    mismatches = SimpleNamespace(report=lambda client, entry, text: reports.append(text))
    scheduler = SimpleNamespace(loop=SimpleNamespace(call_later=lambda delay, callback: timers.append((delay, callback))))
    entry = SimpleNamespace(object_id=0x15, write=publish,
                            topic_spec=TopicSpec("rt/battery", "std_msgs::msg::dds_::Float32_"))
    client = SimpleNamespace(objects={0x15: entry})
    type_drift.arm(middleware, mismatches, scheduler, client, entry, (1, 0x15))
    assert entry.write is not publish
    for i in range(5):
        assert entry.write(b"%d" % i)
    # The first was checked; from the second on the writer's publish is the middleware's own again.
    assert checked == [b"0"] and published == [b"0", b"1", b"2", b"3", b"4"] and entry.write is publish
    assert [delay for delay, _ in timers] == [type_drift.RECHECK_S]
    timers.pop()[1]()  # a minute later: the next sample is checked
    entry.write(b"5")
    entry.write(b"6")
    assert checked == [b"0", b"5"] and entry.write is publish and len(timers) == 1
    timers.pop()[1]()
    entry.write(b"7")  # drifted: named, and not checked again
    entry.write(b"8")
    assert checked == [b"0", b"5", b"7"] and timers == [] and entry.write is publish
    assert reports == ["type drift on /battery: a sample the board wrote cannot be std_msgs/msg/Float32 as this "
                       "agent has it: 4 of its 8 bytes are left unread after the type's last field; "
                       + type_drift.FIX % ("std_msgs", "std_msgs")]
    assert published[-2:] == [b"7", b"8"]  # its samples still go to ROS
    # A writer deleted before its timer: the timer re-arms nothing.
    middleware2 = SimpleNamespace(sample_check=lambda key, dds_type: lambda sample: None)
    type_drift.arm(middleware2, mismatches, scheduler, client, entry, (1, 0x15))
    entry.write(b"9")
    del client.objects[0x15]
    timers.pop()[1]()
    assert entry.write is publish
    # A type the agent has no package for (carried by name): nothing is armed.
    type_drift.arm(SimpleNamespace(sample_check=lambda key, dds_type: None), mismatches, scheduler, client, entry, (1, 0x15))
    assert entry.write is publish


def test_a_declared_type_hash_is_compared_with_the_agents_package_at_creation(ros_domain):  # noqa: F811
    """rmw's ``typehash=RIHS01_...;`` in a binary datawriter's or datareader's QoS user data (what
    xrce.client.type_hash sends): the same hash as the installed package is said at INFO, another
    one is a mismatch named before any sample, a type carried by name has nothing to compare."""
    import json
    import sys
    from pathlib import Path

    from xrce.msgs.std_msgs import Float32
    from xrce.wire.objects import EndpointQos

    def installed(name):
        with open(Path(sys.prefix) / "share" / "std_msgs" / "msg" / (name + ".json")) as description:
            return json.load(description)["type_hashes"][0]["hash_string"]
    right, wrong = installed("Float32"), installed("String")

    def qos(hash_string):
        return EndpointQos(0x0002, 10, user_data=b"typehash=" + hash_string.encode() + b";")

    with AgentProcess("udp4", "-m", "dds", "-v", "4", "--stats-port", "0") as agent:
        port = stats_port(agent)
        with board(agent, ros_domain, "hash_board") as (session, node):
            ok = session.create_topic(node, "rt/volts_ok", Float32.TYPE_NAME)
            session.create_datawriter(session.create_publisher(node), ok, qos(right))
            bad = session.create_topic(node, "rt/volts_bad", Float32.TYPE_NAME)
            session.create_datareader(session.create_subscriber(node), bad, qos(wrong))
            named = session.create_topic(node, "rt/ticks", "nowhere_msgs::msg::dds_::Ticks_")
            session.create_datawriter(session.create_publisher(node), named, qos(right))
            assert session.run_until_all_status(10000), session.last_statuses
            assert wait_until(lambda: agent.drain() or "carried by name" in "".join(agent.output), 10)
            snapshot = fetch_stats(port)
    log = "".join(agent.output).splitlines()
    [warning] = [line for line in log if "WARNING" in line and "type hash" in line]
    assert "client %s at udp4 127.0.0.1:" % session.key.hex() in warning and "datareader" in warning, warning
    assert ("type hash mismatch on /volts_bad: the board's classes of std_msgs/msg/Float32 were generated from a "
            "definition with %s, this agent's package has %s; " % (wrong, right)
            + type_drift.FIX % ("std_msgs", "std_msgs")) in warning, warning
    assert [line for line in log if "/volts_ok std_msgs/msg/Float32: type hash %s, as this agent's package" % right
            in line], log
    assert [line for line in log if "/ticks nowhere_msgs/msg/Ticks: the board declares type hash %s; this agent "
            "has no package of the type to compare it with (carried by name)" % right in line], log
    assert snapshot["agent"]["mismatches"] == 1, snapshot["agent"]
    assert type_drift._declared(b"typehash=" + right.encode() + b";") == right
    assert type_drift._declared(b"other=1;typehash=" + right.encode() + b";") == right
    for user_data in (None, b"", b"\xff\xfe", b"typehash=RIHS01_short;", b"typehash=RIHS02_" + b"0" * 64 + b";"):
        assert type_drift._declared(user_data) is None, user_data
