"""The generated message classes under real MicroPython 1.27: same bytes as CPython, same errors."""

from mp_harness import run_micropython

from xrce.msgs import geometry_msgs, nav_msgs, sensor_msgs, std_msgs, tf2_msgs, turtlebot3_msgs

# Built on CPython; the MicroPython side rebuilds each from the same dict and must produce these bytes.
SAMPLES = [
    (geometry_msgs.Twist, {"linear": {"x": 0.1, "y": -0.5}, "angular": {"z": 1.0009787}}),
    (nav_msgs.Odometry, {"header": {"stamp": {"sec": 17, "nanosec": 5}, "frame_id": "odom"},
                         "child_frame_id": "base_footprint",
                         "pose": {"pose": {"position": {"x": 1.5}, "orientation": {"z": 0.25, "w": 0.75}},
                                  "covariance": [float(i) for i in range(36)]}}),
    (turtlebot3_msgs.SensorState, {"header": {"frame_id": "x"}, "bumper": 2, "cliff": 0.5, "led": 1,
                                   "torque": True, "left_encoder": -123456, "right_encoder": 654321,
                                   "battery": 11.75}),
    (sensor_msgs.JointState, {"name": ["wheel_left", "wheel_right"], "position": [0.5, -0.25],
                              "velocity": [], "effort": [1.0]}),
    (sensor_msgs.Image, {"height": 1, "width": 3, "encoding": "mono8", "data": b"\x00\x7f\xff"}),
    (tf2_msgs.TFMessage, {"transforms": [{"child_frame_id": "a", "transform": {"rotation": {"w": 1.0}}},
                                         {"child_frame_id": "b", "transform": {"translation": {"y": 2.0}}}]}),
    (std_msgs.UInt64MultiArray, {"layout": {"dim": [{"label": "n", "size": 2, "stride": 2}]},
                                 "data": [0, 18446744073709551615]}),
    # Integers at the edges of their fields, inside runs packed by one struct call (Time is a part of
    # Header's run): the range check must let them through.
    (std_msgs.Header, {"stamp": {"sec": -2147483648, "nanosec": 4294967295}, "frame_id": "edge"}),
    (std_msgs.Int8, {"data": -128}),
    (std_msgs.UInt16, {"data": 65535}),
    (std_msgs.Int64, {"data": -9223372036854775808}),
    (sensor_msgs.BatteryState, {"voltage": 12.5, "present": True, "cell_voltage": [3.5, 3.75],
                                "location": "slot", "serial_number": "sn"}),
]

SCRIPT = """
import binascii
from xrce.wire.cdr import CdrReader
from xrce import DecodeError, EncodeError
from xrce.msgs import lookup
from xrce.msgs._into import decode_into
SAMPLES = %r
for ros_type, values in SAMPLES:
    cls = lookup(ros_type)
    msg = cls.from_dict(values)
    body = msg.to_bytes()
    assert cls.from_bytes(body) == msg, ros_type
    into = cls()  # decoded in place (integers of up to 32 bits byte by byte here) as decode does
    decode_into(into, CdrReader(body))
    assert into == msg, ros_type
    for n in range(len(body)):
        try:
            cls.from_bytes(body[:n])
            raise AssertionError("truncated %%s decoded" %% ros_type)
        except DecodeError:
            pass
    print("BODY", ros_type, binascii.hexlify(body).decode())
bad = 0
for ros_type, values in (("std_msgs/UInt8", {"data": 256}), ("std_msgs/Int32", {"data": -2147483649}),
                         ("std_msgs/String", {"data": 3}), ("sensor_msgs/Imu", {"orientation_covariance": [0.0]}),
                         ("std_msgs/UInt32", {"data": -1}), ("std_msgs/UInt64", {"data": 18446744073709551616}),
                         ("std_msgs/Header", {"stamp": {"sec": 2147483648}}),
                         ("std_msgs/Header", {"stamp": {"nanosec": -1}}),
                         ("turtlebot3_msgs/SensorState", {"right_encoder": -2147483649}),
                         ("turtlebot3_msgs/SensorState", {"led": 256}),
                         ("turtlebot3_msgs/SensorState", {"cliff": "x"})):
    try:
        lookup(ros_type).from_dict(values).to_bytes()
    except EncodeError:
        bad += 1
try:
    lookup("std_msgs/Bool").from_bytes(b"\\x07")
except DecodeError:
    bad += 1
print("REJECTED", bad)
"""


def test_generated_messages_match_cpython_bytes_on_micropython():
    from xrce.wire.cdr import CdrReader
    from xrce.msgs._into import decode_into

    for cls, values in SAMPLES:  # decode_into on CPython (struct throughout) gives what decode gives
        into = cls()
        decode_into(into, CdrReader(cls.from_dict(values).to_bytes()))
        assert into == cls.from_dict(values), cls.ROS_TYPE
    samples = [(cls.ROS_TYPE, values) for cls, values in SAMPLES]
    result = run_micropython(SCRIPT % (samples,), heap=4 * 1024 * 1024, timeout=90)
    assert result.returncode == 0, result.stdout + result.stderr
    bodies = {}
    for line in result.stdout.splitlines():
        if line.startswith("BODY "):
            _, ros_type, hexed = line.split(" ")
            bodies[ros_type] = hexed
    for cls, values in SAMPLES:
        assert bodies[cls.ROS_TYPE] == cls.from_dict(values).to_bytes().hex(), cls.ROS_TYPE
    assert "REJECTED 12" in result.stdout


# No shipped type has a fixed array of integers or a run mixing integer widths with padding-free
# offsets; a type defined on the spot has both, so MicroPython's range checks on them run too.
RUNS_SCRIPT = """
import binascii
from xrce import EncodeError
from xrce.msgs import _define
Ints = _define("test_msgs/msg/Ints", ("small", "wide", "octet", "arr", "tail"),
               ("h", "i", "B", ("F", 3, "i"), ("F", 2, "H")))
print("BODY", binascii.hexlify(Ints(-32768, 2147483647, 255, [-1, 0, -2147483648], [65535, 0]).to_bytes()).decode())
print("PLAN", len(Ints._P))
bad = 0
for values in ((32768, 0, 0, [0, 0, 0], [0, 0]), (0, 0, 0, [0, 2147483648, 0], [0, 0]),
               (0, 0, 0, [0, 0, 0], [-1, 0]), (0, 0, 256, [0, 0, 0], [0, 0]), (0, 0, 0, [0, 0], [0, 0])):
    try:
        Ints(*values).to_bytes()
    except EncodeError:
        bad += 1
print("REJECTED", bad)
"""


def test_integer_runs_and_arrays_are_range_checked_on_micropython():
    from xrce.msgs import _define

    ints = _define("test_msgs/msg/Ints", ("small", "wide", "octet", "arr", "tail"),
                   ("h", "i", "B", ("F", 3, "i"), ("F", 2, "H")))
    expected = ints(-32768, 2147483647, 255, [-1, 0, -2147483648], [65535, 0]).to_bytes().hex()
    result = run_micropython(RUNS_SCRIPT, heap=4 * 1024 * 1024, timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "BODY " + expected in result.stdout
    assert "PLAN 3" in result.stdout  # (h) then (i, B), then the arrays: a wider item starts a new run
    assert "REJECTED 5" in result.stdout


# On a board a type's constants stay out of the heap until asked for: the class has none after its
# import, all of them after load_constants (which hands the class back), and the constants module
# is not kept. The values are the ones CPython's class carries from its definition.
CONSTANTS_SCRIPT = """
import sys
from xrce.msgs.constants import load_constants
from xrce.msgs.sensor_msgs import BatteryState
from xrce.msgs.nav_msgs import LoadMap_Response
print("BEFORE", hasattr(BatteryState, "POWER_SUPPLY_STATUS_FULL"), hasattr(LoadMap_Response, "RESULT_SUCCESS"))
assert load_constants(BatteryState) is BatteryState
load_constants(LoadMap_Response)
print("AFTER", BatteryState.POWER_SUPPLY_STATUS_FULL, BatteryState.POWER_SUPPLY_TECHNOLOGY_VRLA,
      LoadMap_Response.RESULT_UNDEFINED_FAILURE)
print("KEPT", [name for name in sys.modules if name.endswith("_constants")])
print("ENCODES", BatteryState(power_supply_status=BatteryState.POWER_SUPPLY_STATUS_FULL).to_bytes() ==
      BatteryState(power_supply_status=4).to_bytes())
"""


def test_message_constants_load_on_request_on_micropython():
    result = run_micropython(CONSTANTS_SCRIPT, heap=1024 * 1024, timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "BEFORE False False" in result.stdout
    assert "AFTER %d %d %d" % (sensor_msgs.BatteryState.POWER_SUPPLY_STATUS_FULL,
                               sensor_msgs.BatteryState.POWER_SUPPLY_TECHNOLOGY_VRLA,
                               nav_msgs.LoadMap_Response.RESULT_UNDEFINED_FAILURE) in result.stdout
    assert "AFTER 4 8 255" in result.stdout
    assert "KEPT []" in result.stdout
    assert "ENCODES True" in result.stdout
