"""Generated message classes: golden capture bytes, hostile input, dict conversion, lookup, and
that the committed modules are exactly what the generator produces today."""

import filecmp
import json
import os
import random
import struct

import pytest

from xrce.tools import msggen
from xrce.wire.cdr import CdrReader, CdrWriter
from xrce import DecodeError, EncodeError
from xrce.msgs import builtin_interfaces, geometry_msgs, lookup, nav_msgs, sensor_msgs, std_msgs, tf2_msgs
from xrce.msgs import turtlebot3_msgs

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CAPTURES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "golden", "wire_captures.json")


def _golden_twist_bodies():
    with open(CAPTURES) as f:
        scenario = json.load(f)["scenarios"]["bin_twist_reliable"]
    bodies = []
    for datagram in scenario:
        raw = bytes.fromhex(datagram["hex"])
        if datagram["dir"] == "C->A" and len(raw) == 60 and raw[4] == 0x07:  # WRITE_DATA
            # 4-byte message header, 4-byte submessage header, 4-byte BaseObjectRequest
            bodies.append(raw[12:])
    return bodies


def test_golden_twist_decodes_and_reencodes_identically():
    bodies = _golden_twist_bodies()
    assert len(bodies) == 3
    first = geometry_msgs.Twist.from_bytes(bodies[0])
    assert first.linear.x == 0.1
    assert first.linear.y == -0.5
    assert first.linear.z == 0.0
    assert (first.angular.x, first.angular.y) == (0.0, 0.0)
    assert 1.0 < first.angular.z < 1.01
    for body in bodies:
        assert len(body) == 48
        assert geometry_msgs.Twist.from_bytes(body).to_bytes() == body


def test_twist_layout_is_six_le_doubles():
    t = geometry_msgs.Twist(linear=geometry_msgs.Vector3(1.0, 2.0, 3.0), angular=geometry_msgs.Vector3(z=-1.5))
    assert t.to_bytes() == struct.pack("<6d", 1.0, 2.0, 3.0, 0.0, 0.0, -1.5)


def test_alignment_counts_from_the_writer_origin():
    # A sample that starts 4 bytes into a buffer (after a BaseObjectRequest) aligns its doubles
    # from its own first byte, so the bytes equal the standalone encoding.
    t = geometry_msgs.Twist(linear=geometry_msgs.Vector3(0.5, 0.0, 0.0))
    w = CdrWriter(bytearray(8), pos=4)
    w.buf[0:4] = b"\x01\x02\x03\x04"
    t.encode(w)
    assert w.getvalue()[4:] == t.to_bytes()
    r = CdrReader(w.getvalue(), pos=4)
    assert geometry_msgs.Twist.decode(r) == t and r.remaining() == 0


def test_header_string_then_double_padding():
    p = geometry_msgs.PointStamped(header=std_msgs.Header(stamp=builtin_interfaces.Time(sec=5, nanosec=7),
                                                          frame_id="map"),
                                   point=geometry_msgs.Point(x=1.0))
    body = p.to_bytes()
    assert body[:8] == struct.pack("<iI", 5, 7)
    assert body[8:16] == struct.pack("<I", 4) + b"map\x00"
    assert body[16:24] == struct.pack("<d", 1.0)  # offset 16 is already 8-aligned
    p.header.frame_id = "abcde"  # string ends at 18: six zero pad bytes before the double
    body = p.to_bytes()
    assert body[18:24] == bytes(6) and body[24:32] == struct.pack("<d", 1.0) and len(body) == 48
    assert geometry_msgs.PointStamped.from_bytes(body) == p


def test_constants_defaults_and_type_names():
    assert turtlebot3_msgs.SensorState.TORQUE_OFF == 2
    assert turtlebot3_msgs.Sound.LOW_BATTERY == 2
    assert tf2_msgs.TF2Error.TRANSFORM_ERROR == 6
    assert sensor_msgs.BatteryState.POWER_SUPPLY_STATUS_FULL == 4
    assert geometry_msgs.Quaternion().w == 1.0
    assert sensor_msgs.NavSatStatus().status == -2
    assert geometry_msgs.Twist.TYPE_NAME == "geometry_msgs::msg::dds_::Twist_"
    assert geometry_msgs.Twist.ROS_TYPE == "geometry_msgs/msg/Twist"
    srv = turtlebot3_msgs.SERVICES["Sound"]
    assert srv.Request is turtlebot3_msgs.Sound_Request
    assert srv.TYPE_NAME_REQUEST == "turtlebot3_msgs::srv::dds_::Sound_Request_"
    assert srv.TYPE_NAME_RESPONSE == "turtlebot3_msgs::srv::dds_::Sound_Response_"
    assert srv.ROS_TYPE == "turtlebot3_msgs/srv/Sound"
    assert nav_msgs.GetMap.Response is nav_msgs.GetMap_Response
    img = sensor_msgs.Image()
    assert img.data == b"" and isinstance(img.data, bytes)
    assert sensor_msgs.Imu().orientation_covariance == [0.0] * 9


def test_sensor_state_field_order():
    s = turtlebot3_msgs.SensorState(bumper=1, cliff=0.5, sonar=1.5, illumination=2.5, led=3, button=2,
                                    torque=True, left_encoder=-7, right_encoder=9, battery=11.5)
    body = s.to_bytes()
    # stamp(8) + empty frame_id(4+1) + bumper(1) + pad(2) + 3 floats + led + button + torque + pad + ...
    assert body[13] == 1
    assert struct.unpack_from("<3f", body, 16) == (0.5, 1.5, 2.5)
    assert tuple(body[28:31]) == (3, 2, 1)
    assert struct.unpack_from("<iif", body, 32) == (-7, 9, 11.5)
    assert len(body) == 44
    assert turtlebot3_msgs.SensorState.from_bytes(body) == s


def test_dict_round_trip_and_errors():
    t = geometry_msgs.Twist.from_dict({"linear": {"x": 0.5}, "angular": {"z": 1}})
    assert t.linear.x == 0.5 and t.angular.z == 1 and t.linear.y == 0.0
    assert geometry_msgs.Twist.from_bytes(t.to_bytes()) == t
    assert t.to_dict() == {"linear": {"x": 0.5, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 1}}
    tf = tf2_msgs.TFMessage.from_dict({"transforms": [{"child_frame_id": "base", "transform": {"rotation": {"w": 1.0}}}]})
    assert tf.transforms[0].child_frame_id == "base"
    assert tf2_msgs.TFMessage.from_dict(tf.to_dict()) == tf
    with pytest.raises(EncodeError):
        geometry_msgs.Twist.from_dict({"linear": {"w": 1.0}})
    with pytest.raises(EncodeError):
        geometry_msgs.Twist.from_dict({"speed": 1.0})
    with pytest.raises(EncodeError):
        geometry_msgs.Twist.from_dict({"linear": 3})
    img = sensor_msgs.Image.from_dict({"data": [1, 2, 255]})
    assert img.data == b"\x01\x02\xff"


@pytest.mark.parametrize("bad", [
    lambda: std_msgs.UInt8(data=256),
    lambda: std_msgs.Int8(data=-129),
    lambda: std_msgs.Float64(data="x"),
    lambda: std_msgs.String(data=5),
    lambda: std_msgs.String(data="a\x00b"),
    lambda: sensor_msgs.Imu(orientation_covariance=[0.0] * 8),
    lambda: sensor_msgs.Image(data=[300]),
    lambda: geometry_msgs.Twist(linear={"x": 1.0}),
    lambda: std_msgs.Float32(data=1e300),
])
def test_bad_values_raise_encode_error(bad):
    with pytest.raises(EncodeError):
        bad().to_bytes()


FUZZ_TYPES = [geometry_msgs.Twist, std_msgs.String, sensor_msgs.Imu, sensor_msgs.LaserScan, sensor_msgs.JointState,
              sensor_msgs.BatteryState, nav_msgs.Odometry, tf2_msgs.TFMessage, turtlebot3_msgs.SensorState,
              sensor_msgs.PointCloud2, std_msgs.Float64MultiArray, sensor_msgs.CameraInfo, std_msgs.Empty]


def _sample(cls):
    if cls is tf2_msgs.TFMessage:
        return cls.from_dict({"transforms": [{"child_frame_id": "a"}, {"child_frame_id": "bb"}]})
    if cls is sensor_msgs.JointState:
        return cls(name=["j1", "j2"], position=[1.0, 2.0], velocity=[0.5], effort=[])
    if cls is sensor_msgs.LaserScan:
        return cls(ranges=[1.0, 2.0, 3.0], intensities=[0.5])
    if cls is sensor_msgs.PointCloud2:
        return cls.from_dict({"fields": [{"name": "x", "datatype": 7, "count": 1}], "data": b"\x00" * 12})
    if cls is std_msgs.String:
        return cls(data="hello")
    return cls()


@pytest.mark.parametrize("cls", FUZZ_TYPES, ids=lambda c: c.ROS_TYPE)
def test_truncated_and_random_bytes_raise_only_decode_error(cls):
    body = _sample(cls).to_bytes()
    assert cls.from_bytes(body) == _sample(cls)
    for n in range(len(body)):
        with pytest.raises(DecodeError):
            cls.from_bytes(body[:n])
    rng = random.Random(1234)
    for _ in range(400):
        data = bytearray(body)
        for _ in range(rng.randint(1, 4)):
            data[rng.randrange(len(data))] = rng.randrange(256)
        if rng.random() < 0.3:
            data = bytes(rng.randrange(256) for _ in range(rng.randint(0, 80)))
        try:
            cls.from_bytes(bytes(data))
        except DecodeError:
            pass


def test_huge_sequence_count_rejected_before_allocating():
    body = struct.pack("<I", 0xFFFFFFF0) + b"\x00" * 8
    for cls in (std_msgs.Float64MultiArray, tf2_msgs.TFMessage):
        with pytest.raises(DecodeError):
            cls.from_bytes(struct.pack("<II", 0, 0) + body if cls is std_msgs.Float64MultiArray else body)
    with pytest.raises(DecodeError):
        sensor_msgs.JointState.from_bytes(struct.pack("<iI", 0, 0) + struct.pack("<I", 1) + b"\x00"
                                          + b"\x00" * 3 + struct.pack("<I", 0x7FFFFFFF))


def test_bool_other_than_0_or_1_is_rejected():
    with pytest.raises(DecodeError):
        std_msgs.Bool.from_bytes(b"\x02")
    assert std_msgs.Bool.from_bytes(b"\x01").data is True


def test_lookup_by_every_spelling():
    assert lookup("geometry_msgs/msg/Twist") is geometry_msgs.Twist
    assert lookup("geometry_msgs/Twist") is geometry_msgs.Twist
    assert lookup("geometry_msgs::msg::dds_::Twist_") is geometry_msgs.Twist
    assert lookup("turtlebot3_msgs/srv/Sound") is turtlebot3_msgs.SERVICES["Sound"]
    assert lookup("turtlebot3_msgs/msg/Sound") is turtlebot3_msgs.Sound
    assert lookup("nav_msgs::srv::dds_::GetMap_Request_") is nav_msgs.GetMap_Request
    assert lookup("tf2_msgs/msg/TFMessage") is tf2_msgs.TFMessage
    assert lookup("nav_msgs/srv/GetMap") is nav_msgs.GetMap is nav_msgs.SERVICES["GetMap"]
    for bad in ("geometry_msgs/msg/Nope", "nope_msgs/msg/X", "geometry_msgs/srv/Twist", "os/path",
                "geometry_msgs::msg::Twist_", "../x/y", "", "a/b/c/d", "_dict/to_dict", "std_msgs/_String",
                "std_msgs/msg/__init__", "geometry_msgs/SERVICES", "cdr/CdrWriter"):
        with pytest.raises(KeyError):
            lookup(bad)


def test_repr_and_equality():
    a = geometry_msgs.Vector3(1.0, 2.0, 3.0)
    assert repr(a) == "geometry_msgs/msg/Vector3(x=1.0, y=2.0, z=3.0)"
    assert a == geometry_msgs.Vector3(1.0, 2.0, 3.0)
    assert a != geometry_msgs.Vector3(1.0, 2.0, 3.5)
    assert a != geometry_msgs.Point(1.0, 2.0, 3.0)
    with pytest.raises(AttributeError):
        a.w = 1.0  # __slots__: no stray attributes


def test_messages_pickle_and_name_their_module():
    import pickle

    odom = nav_msgs.Odometry(child_frame_id="base")
    odom.pose.pose.position.x = 1.5
    assert pickle.loads(pickle.dumps(odom)) == odom
    assert geometry_msgs.Twist.__module__ == "xrce.msgs.geometry_msgs._Twist"
    assert geometry_msgs.Twist.__name__ == "Twist"


def _tree(root):
    """Repo-relative paths of the .py files under ``root``."""
    found = []
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = [d for d in dirnames if d != "__pycache__"]
        for name in filenames:
            if name.endswith(".py"):
                found.append(os.path.relpath(os.path.join(dirpath, name), root))
    return sorted(found)


HAND_WRITTEN = ["__init__.py", "_dict.py", "_into.py", "_ints.py", "_lookup.py", "_plan.py", "_seq.py", "constants.py"]


def test_committed_modules_match_the_generator(tmp_path):
    assert msggen.main(["--shipped", "-o", str(tmp_path)]) == 0
    committed = os.path.join(REPO, "xrce", "msgs")
    names = _tree(tmp_path)
    assert names == [n for n in _tree(committed) if n not in HAND_WRITTEN]
    assert "geometry_msgs/_Twist.py" in names and "turtlebot3_msgs/_Sound_Service.py" in names
    match, mismatch, errors = filecmp.cmpfiles(tmp_path, committed, names, shallow=False)
    assert mismatch == [] and errors == [], "run: python -m xrce.tools.msggen --shipped"
    with open(os.path.join(committed, "geometry_msgs", "__init__.py")) as f:
        assert f.readline().startswith("# Generated by xrce/tools/msggen.py (python -m xrce.tools.msggen --shipped)")


def test_regenerating_removes_stale_generated_modules_only(tmp_path):
    (tmp_path / "std_msgs").mkdir()
    (tmp_path / "std_msgs" / "_Gone.py").write_text("# Generated by xrce/tools/msggen.py (x) from std_msgs/msg/Gone.\n")
    (tmp_path / "std_msgs" / "_mine.py").write_text("# written by hand\n")
    (tmp_path / "std_msgs.py").write_text("# Generated by xrce/tools/msggen.py (x) from the std_msgs interface definitions.\n")
    assert msggen.main(["--shipped", "-o", str(tmp_path)]) == 0
    assert not (tmp_path / "std_msgs" / "_Gone.py").exists()
    assert not (tmp_path / "std_msgs.py").exists()
    assert (tmp_path / "std_msgs" / "_mine.py").read_text() == "# written by hand\n"
    assert (tmp_path / "std_msgs" / "_String.py").exists()


def test_generator_on_custom_package(tmp_path, monkeypatch):
    pkg = tmp_path / "demo_msgs"
    (pkg / "msg").mkdir(parents=True)
    (pkg / "srv").mkdir()
    (pkg / "msg" / "Mixed.msg").write_text(
        "int32 LIMIT=10\nstring NAME=\"hi # there\"\nbool flag true\nstring<=5 short\nint16[<=3] few [1, 2]\n"
        "float32[2] pair [0.5, 1.5]\nuint8 tiny 7 # comment\nbyte[] blob\nInner inner\nInner[] inners\n")
    (pkg / "msg" / "Inner.msg").write_text("float64 v\nuint8 u\n")
    (pkg / "msg" / "Ask.msg").write_text("string q\n")
    (pkg / "srv" / "Ask.srv").write_text("Inner question\n---\nMixed[<=2] answers\n")
    (pkg / "srv" / "Count.srv").write_text("---\nuint32 n\n")
    out = tmp_path / "out"
    assert msggen.main([str(pkg), "-o", str(out)]) == 0
    assert sorted(os.listdir(out / "demo_msgs")) == [
        "_Ask.py", "_Ask_Service.py", "_Count.py", "_Inner.py", "_Mixed.py", "_Mixed_constants.py", "__init__.py"]
    import sys

    import xrce.msgs as runtime
    from xrce.msgs import _lookup

    # The generated package is found next to the shipped ones, as if it had been written there.
    monkeypatch.setattr(runtime, "__path__", list(runtime.__path__) + [str(out)])
    try:
        import xrce.msgs.demo_msgs as mod

        assert "xrce.msgs.demo_msgs._Mixed" not in sys.modules  # nothing loads before it is named
        m = mod.Mixed()
        assert "xrce.msgs.demo_msgs._Inner" in sys.modules and "xrce.msgs.demo_msgs._Ask" not in sys.modules
        assert (m.LIMIT, m.NAME, m.flag, m.few, m.pair, m.tiny) == (10, "hi # there", True, [1, 2], [0.5, 1.5], 7)
        m.inners = [mod.Inner(v=2.5, u=3)]
        m.short = "abcde"
        assert mod.Mixed.from_bytes(m.to_bytes()) == m
        assert mod.Mixed.from_dict(m.to_dict()) == m
        assert lookup("demo_msgs/Mixed") is mod.Mixed
        m.short = "abcdef"
        with pytest.raises(EncodeError):
            m.to_bytes()
        m.short, m.few = "", [1, 2, 3, 4]
        with pytest.raises(EncodeError):
            m.to_bytes()
        # msg/Ask and srv/Ask share a name: the descriptor takes a suffix, Request/Response do not.
        assert mod.Ask.ROS_TYPE == "demo_msgs/msg/Ask"
        assert mod.Ask_Request is mod.Ask_Service.Request and mod.Ask_Response is mod.Ask_Service.Response
        assert mod.Count.Response is mod.Count_Response and mod.Count_Request.from_bytes(b"\x00") == mod.Count_Request()
        assert mod.SERVICES == {"Ask": mod.Ask_Service, "Count": mod.Count}
        assert lookup("demo_msgs/srv/Ask") is mod.Ask_Service and lookup("demo_msgs/msg/Ask") is mod.Ask
        m.few = [3]
        reply = mod.Ask_Response(answers=[m, mod.Mixed()])
        assert mod.Ask_Response.from_bytes(reply.to_bytes()) == reply
        with pytest.raises(AttributeError):
            mod.Nope
        with pytest.raises(AttributeError):
            mod.Nope_Request
    finally:
        for name in [n for n in sys.modules if n.startswith("xrce.msgs.demo_msgs")]:
            del sys.modules[name]
        if hasattr(runtime, "demo_msgs"):
            delattr(runtime, "demo_msgs")
        for key in [k for k in _lookup._cache if k.startswith("demo_msgs")]:
            del _lookup._cache[key]


def test_importing_a_type_loads_only_its_own_dependencies():
    # A fresh interpreter: this process has long imported every type.
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from xrce.msgs.geometry_msgs import Twist\n"
        "from xrce.msgs.turtlebot3_msgs import SensorState\n"
        "print(sorted(m for m in sys.modules if m.startswith('xrce.msgs')))\n"
        "Twist().to_bytes()\n"
        "print('_plan' in sys.modules['xrce.msgs']._plan.__name__, Twist._P is not None)\n"
        "print(sorted(t.__name__ for t in sys.modules['xrce.msgs']._Message.__subclasses__() if t._P))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=REPO)
    assert result.returncode == 0, result.stderr
    imported, planned, with_plans = result.stdout.splitlines()
    # No plan is built on import: xrce.msgs._plan loads on a type's first encode or decode (CPython
    # keeps it, a board drops it again). CPython sets a type's constants on its class when it is
    # defined (a board only through load_constants).
    assert eval(imported) == [
        "xrce.msgs", "xrce.msgs.builtin_interfaces", "xrce.msgs.builtin_interfaces._Time", "xrce.msgs.constants",
        "xrce.msgs.geometry_msgs", "xrce.msgs.geometry_msgs._Twist", "xrce.msgs.geometry_msgs._Vector3",
        "xrce.msgs.std_msgs", "xrce.msgs.std_msgs._Header", "xrce.msgs.turtlebot3_msgs",
        "xrce.msgs.turtlebot3_msgs._SensorState", "xrce.msgs.turtlebot3_msgs._SensorState_constants",
    ]
    assert planned == "True True"
    # Twist packs both of its Vector3 parts itself: Vector3 keeps no plan until it is sent on its own.
    assert eval(with_plans) == ["Twist"]


@pytest.mark.parametrize("text,needle", [
    ("wstring w\n", "wstring"),
    ("int32 x 1.5\n", "bad value"),
    ("uint8 x 300\n", "out of range"),
    ("int32\n", "expected"),
    ("int32 a\nint32 a\n", "duplicate"),
    ("Nope x\n", "no input package defines"),
])
def test_generator_rejects_bad_definitions(tmp_path, capsys, text, needle):
    pkg = tmp_path / "bad_msgs"
    (pkg / "msg").mkdir(parents=True)
    (pkg / "msg" / "Bad.msg").write_text(text)
    assert msggen.main([str(pkg), "-o", str(tmp_path / "out")]) == 2
    assert needle in capsys.readouterr().err


def test_codec_objects_answer_unknown_and_dunder_names_with_attribute_error():
    # The methods xrce.wire.cdr_more attaches on first use go through the classes' __getattr__; a name
    # neither class has (a slotted instance's __dict__ included) must be a plain AttributeError,
    # not a recursion through that hook.
    writer, reader = CdrWriter(), CdrReader(b"\x00" * 8)
    for codec in (writer, reader):
        assert not hasattr(codec, "__dict__")
        assert not hasattr(codec, "no_such_method")
    writer.f64(2.5)
    assert CdrReader(bytes(writer.buf)).f64() == 2.5
