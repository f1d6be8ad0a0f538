"""The hand-written interfaces/ definitions are valid rosidl and reproduce the official type hashes.

Uses rosidl's own adapter (.msg/.srv -> .idl) and type-description generator from the wheels, with the
installed std_msgs/builtin_interfaces/geometry_msgs descriptions as dependencies.
"""

import contextlib
import io
import json
import os
import sys
from pathlib import Path

import pytest
from rosidl_adapter.msg import convert_msg_to_idl
from rosidl_adapter.srv import convert_srv_to_idl
from rosidl_generator_type_description import generate_type_hash

INTERFACES = Path(__file__).resolve().parents[2] / "xrce" / "ros_interfaces"
SHARE = Path(sys.prefix) / "share"

# From the jazzy build of ROBOTIS' turtlebot3_msgs (generated sensor_state__description.c).
OFFICIAL_HASHES = {
    "turtlebot3_msgs/msg/SensorState": "RIHS01_e35bc7db55e7a7aeb24990b6d7f189a2002ae442e0d9925077e29895f838ccea",
}


def _type_hashes(package, tmp_path):
    pkg_dir = INTERFACES / package
    idl_root = tmp_path / "idl"
    tuples = []
    with contextlib.redirect_stdout(io.StringIO()):  # the adapter narrates every file it writes
        for kind, convert in (("msg", convert_msg_to_idl), ("srv", convert_srv_to_idl)):
            for source in sorted((pkg_dir / kind).glob("*." + kind)):
                convert(pkg_dir, package, Path(kind) / source.name, idl_root / kind)
                tuples.append("%s:%s/%s.idl" % (idl_root, kind, source.stem))
    args = {
        "package_name": package,
        "output_dir": str(tmp_path / "out"),
        "idl_tuples": tuples,
        "include_paths": ["%s:%s" % (dep, SHARE / dep)
                          for dep in ("builtin_interfaces", "std_msgs", "geometry_msgs", "service_msgs")],
    }
    args_file = tmp_path / "args.json"
    args_file.write_text(json.dumps(args))
    hashes = {}
    for path in generate_type_hash(str(args_file)):
        with open(path) as f:
            for entry in json.load(f)["type_hashes"]:
                hashes[entry["type_name"]] = entry["hash_string"]
    return hashes


@pytest.mark.parametrize("package", ["turtlebot3_msgs", "tf2_msgs"])
def test_interfaces_parse_and_hash(package, tmp_path):
    hashes = _type_hashes(package, tmp_path)
    for source in (INTERFACES / package / "msg").glob("*.msg"):
        assert hashes["%s/msg/%s" % (package, source.stem)].startswith("RIHS01_")
    for type_name, expected in OFFICIAL_HASHES.items():
        if type_name.startswith(package + "/"):
            assert hashes[type_name] == expected


def test_generated_classes_follow_the_definition_files():
    from xrce.tools import msggen
    from xrce.tools import msg_parser
    from xrce.msgs import lookup

    for package in msggen.SHIPPED_FROM_REPO:
        _, messages, services = msg_parser.load_package(os.fspath(INTERFACES / package))
        specs = list(messages) + [s for srv in services for s in (srv.request, srv.response)]
        for spec in specs:
            cls = lookup(spec.ros_type)
            assert list(cls.__slots__) == [f.name for f in spec.fields]
            for constant in spec.constants:
                assert getattr(cls, constant.name) == constant.value
