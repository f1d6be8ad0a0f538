"""One module per type, resolved lazily: what a board loads when it names a type, under real
MicroPython 1.27 from .py sources and from mpy-cross output, and the field tables the dict helpers
infer instead of every class carrying one."""

import pytest
from mp_harness import run_micropython

from xrce.tools import msggen
from xrce.tools import msg_parser
from xrce.msgs import lookup
from xrce.tools import mpy

RESOLUTION_SCRIPT = """
import sys
from xrce.msgs.geometry_msgs import Twist
loaded = sorted(m for m in sys.modules if m.startswith("xrce.msgs"))
print("LOADED", " ".join(loaded))
assert Twist.from_bytes(Twist().to_bytes()) == Twist()
from xrce.msgs import std_msgs
assert std_msgs.String(data="hi").to_bytes() == b"\\x03\\x00\\x00\\x00hi\\x00"
from xrce.msgs import nav_msgs, turtlebot3_msgs, lookup
assert nav_msgs.GetMap.Request is nav_msgs.GetMap_Request
assert turtlebot3_msgs.Sound_Service.Response is turtlebot3_msgs.Sound_Response
assert turtlebot3_msgs.Sound.ROS_TYPE == "turtlebot3_msgs/msg/Sound"
assert sorted(nav_msgs.SERVICES) == ["GetMap", "GetPlan", "LoadMap", "SetMap"]
assert lookup("turtlebot3_msgs/srv/Sound") is turtlebot3_msgs.Sound_Service
assert lookup("geometry_msgs::msg::dds_::Twist_") is Twist
for name in ("Nope", "Nope_Request", "_Twist_", "SERVICES_"):
    try:
        getattr(std_msgs, name)
        raise AssertionError(name)
    except AttributeError:
        pass
try:
    lookup("std_msgs/msg/Nope")
    raise AssertionError("lookup")
except KeyError:
    pass
assert Twist.from_dict({"linear": {"x": 1.5}}).to_dict()["linear"]["x"] == 1.5
# Each type is defined once, however it is reached: a board drops a message's module once the
# package keeps its class, so nothing may import that module again.
from xrce.msgs import geometry_msgs
assert Twist._S[0] is geometry_msgs.Vector3 and Twist._S[1] is geometry_msgs.Vector3
assert nav_msgs.Odometry._S[3]._S[0] is Twist is geometry_msgs.Twist
assert nav_msgs.GetPlan_Request._S[0] is geometry_msgs.PoseStamped
assert nav_msgs.GetPlan.Request is nav_msgs.GetPlan_Request
assert lookup("geometry_msgs/msg/Vector3") is geometry_msgs.Vector3
print("RESOLVED")
"""

# Import cost of one statement in a fresh interpreter, on top of the wire core every client has: the
# live heap it leaves (what a board keeps) and everything it allocated, garbage included (the harness
# collects between steps only; compiling .py sources and building the plans make that garbage).
FOOTPRINT_SCRIPT = """
import mpheap
import xrce, xrce.wire.cdr
def main():
    yield
    before = mpheap.live
    %s
    yield
    print("HEAP", mpheap.live - before, "ALLOCATED", mpheap.peak - before)
"""

IMPORTS = {
    "String": "from xrce.msgs.std_msgs import String",
    "Twist": "from xrce.msgs.geometry_msgs import Twist",
    "SensorState": "from xrce.msgs.turtlebot3_msgs import SensorState",
}
# Measured on 1.27.0 with per-type modules (.py), all allocation: 8.6, 10.7 and 15.1 KB. Importing
# the whole package instead, as the one-module-per-package layout did, cost 47, 93 and 63 KB. With
# tables and run plans built at import (.py): live 7.3, 8.0 and 10.7 KB; allocated 12.3, 14.4 and
# 19.7 KB. Plans built on a type's first encode or decode (none here), message modules dropped
# once their class is kept, names interned: live 7.1, 7.5 and 9.3 KB; allocated 10.6, 11.9 and
# 14.9 KB (interning makes a class per string, which is garbage at once).
PY_LIMITS = {"String": 8500, "Twist": 9500, "SensorState": 12500}

# The modules of Twist and Vector3 are dropped once the package keeps their classes.
EXPECTED_AFTER_TWIST = ["xrce.msgs", "xrce.msgs.geometry_msgs"]


def _heap(statement, **mount):
    result = run_micropython(FOOTPRINT_SCRIPT % statement, heap=4 * 1024 * 1024, timeout=60, stepped=True, **mount)
    assert result.returncode == 0, result.stdout + result.stderr
    words = result.stdout.split("HEAP ")[1].split()
    return int(words[0]), int(words[2])


def _assert_resolves(**mount):
    result = run_micropython(RESOLUTION_SCRIPT, heap=4 * 1024 * 1024, timeout=180, **mount)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "RESOLVED" in result.stdout
    loaded = result.stdout.split("LOADED ")[1].splitlines()[0].split()
    assert loaded == EXPECTED_AFTER_TWIST


def test_micropython_resolves_types_lazily_from_sources():
    _assert_resolves()


@pytest.fixture(scope="module")
def mpy_tree(tmp_path_factory):
    outdir = tmp_path_factory.mktemp("mpy")
    mpy.build_mpy(outdir)
    return outdir / "xrce"


def test_micropython_resolves_types_lazily_from_mpy(mpy_tree):
    _assert_resolves(mounts=[(mpy_tree, "/lib/xrce")], default_mount=False)


def test_importing_one_type_costs_a_few_kb_of_heap(mpy_tree, capsys):
    sources = {name: _heap(statement) for name, statement in IMPORTS.items()}
    compiled = {name: _heap(statement, mounts=[(mpy_tree, "/lib/xrce")], default_mount=False)
                for name, statement in IMPORTS.items()}
    with capsys.disabled():
        print("\nheap for one type, live (allocated) from .py / .mpy: " + ", ".join(
            "%s %d (%d) / %d (%d)" % ((name,) + sources[name] + compiled[name]) for name in IMPORTS))
    for name in IMPORTS:
        assert sources[name][0] <= PY_LIMITS[name], (name, sources[name])
        assert compiled[name][1] < sources[name][1], (name, compiled[name])  # no compiler run


def _kind(ftype):
    # The table the generator used to write onto every class: 0 value, 1 message, 2 list of
    # messages, 3 bytes (octet arrays).
    if ftype.is_nested:
        return 2 if ftype.array else 1
    if ftype.is_primitive and ftype.array and msg_parser.PRIMITIVES[ftype.base][2] == "octet":
        return 3
    return 0


def test_inferred_field_tables_match_the_definitions():
    packages = [msg_parser.load_package(d) for d in msggen.shipped_package_dirs()]
    checked = 0
    for _, messages, services in packages:
        for spec in list(messages) + [s for srv in services for s in (srv.request, srv.response)]:
            cls = lookup(spec.ros_type)
            expected = tuple(
                (f.name, _kind(f.type), lookup(f.type.base) if f.type.is_nested else None) for f in spec.fields)
            assert cls._FIELDS == expected, spec.ros_type
            checked += 1
    assert checked > 100
