"""RIHS01 type hashes of a board's own messages, computed by rosidl's own code.

gen-msgs writes them into ``xrce/msgs/<package>/_hashes.py`` so that a board can declare a topic's
type hash when it creates the endpoint (``xrce.client.type_hash``) and the agent can name a board
whose classes come from another ``.msg`` than its package before any sample.

The hash is rosidl's, not a re-implementation: the ``.msg`` files go through rosidl_adapter to
``.idl`` and rosidl_generator_type_description computes the hash exactly as a colcon build of the
package does (``share/<package>/msg/<Type>.json``), from the type descriptions of the packages it
uses. Those come from wherever ROS installed them (the venv's ``share/``, a sourced ROS's
``AMENT_PREFIX_PATH``); the ones the client ships without ROS having them (turtlebot3_msgs, ...)
are computed from ``xrce/ros_interfaces/`` the same way. Without rosidl on the host (a venv without
the ROS wheels) nothing is written: ``HashesUnavailable`` says why, and gen-msgs says so in a line.
"""

import contextlib
import io
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

HASH_MODULE = "_hashes.py"
INTERFACES = Path(__file__).resolve().parents[1] / "ros_interfaces"


class HashesUnavailable(Exception):
    """No hash can be computed here (the message says why); gen-msgs writes the classes anyway."""


def _share_roots():
    roots = [Path(sys.prefix) / "share"]
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            roots.append(Path(prefix) / "share")
    return [root for root in roots if root.is_dir()]


def _installed_descriptions():
    """package name -> its share directory, for every package ROS installed with type descriptions."""
    found = {}
    for root in _share_roots():
        for package in sorted(root.iterdir()):
            if package.name in found:
                continue
            if any(package.joinpath(kind).is_dir() and next(package.joinpath(kind).glob("*.json"), None)
                   for kind in ("msg", "srv", "action")):
                found[package.name] = package
    return found


def _describe(package_dir, package, scratch, include_map):
    """Writes the package's type descriptions (JSON, with their hashes) under scratch/package;
    returns {type name: hash}. KeyError names a package none of include_map describes."""
    from rosidl_adapter.action import convert_action_to_idl
    from rosidl_adapter.msg import convert_msg_to_idl
    from rosidl_adapter.srv import convert_srv_to_idl
    from rosidl_generator_type_description import generate_type_hash

    idl_root = scratch / ("idl-" + package)
    out = scratch / package
    tuples = []
    with contextlib.redirect_stdout(io.StringIO()):  # the adapter narrates every file it writes
        for kind, convert in (("msg", convert_msg_to_idl), ("srv", convert_srv_to_idl),
                              ("action", convert_action_to_idl)):
            for source in sorted((Path(package_dir) / kind).glob("*." + kind)):
                convert(Path(package_dir), package, Path(kind) / source.name, idl_root / kind)
                tuples.append("%s:%s/%s.idl" % (idl_root, kind, source.stem))
    args = {"package_name": package, "output_dir": str(out), "idl_tuples": tuples,
            "include_paths": ["%s:%s" % item for item in include_map.items() if item[0] != package]}
    args_file = scratch / ("args-%s.json" % package)
    args_file.write_text(json.dumps(args))
    hashes = {}
    try:
        paths = generate_type_hash(str(args_file))
    except FileNotFoundError as error:  # a dependency's description the include map lacks
        raise KeyError(Path(error.filename).parent.parent.name)
    for path in paths:
        with open(path) as f:
            for entry in json.load(f)["type_hashes"]:
                hashes[entry["type_name"]] = entry["hash_string"]
    return hashes


def _needed_package(error):
    """The package a failed generate_type_hash looked for: its include map's KeyError names it."""
    return str(error.args[0]) if error.args else ""


def type_hashes(package_dirs):
    """{"pkg/msg/Type": "RIHS01_..."} for every message of the given packages (directories with
    msg/, srv/, action/, in any order; one may use another's types)."""
    try:
        import rosidl_adapter.msg  # noqa: F401
        import rosidl_generator_type_description  # noqa: F401
    except ImportError as error:
        raise HashesUnavailable("rosidl is not installed here (%s)" % error)
    from xrce.tools.msg_parser import load_package

    given = {load_package(str(d))[0]: Path(d) for d in package_dirs}
    include_map = {name: str(path) for name, path in _installed_descriptions().items()}
    for name in given:
        include_map.pop(name, None)  # the user's definition, not an installed one of that name
    scratch = Path(tempfile.mkdtemp(prefix="xrce-type-hashes-"))
    hashes = {}
    try:
        pending = list(given)
        done = set()
        while pending:
            package = pending[0]
            source = (given.get(package) or INTERFACES / package).resolve()  # rosidl_adapter asserts absolute paths
            include_map[package] = str(scratch / package)
            try:
                found = _describe(source, package, scratch, include_map)
            except KeyError as error:
                needed = _needed_package(error)
                if needed in pending or needed in done or not (
                        needed in given or (INTERFACES / needed).is_dir()):
                    raise HashesUnavailable(
                        "%s uses %s, whose type descriptions are not installed here (build it "
                        "with ROS, or give its package directory too)" % (package, needed or "a package"))
                pending.insert(0, needed)  # that one first, then this one again
                continue
            pending.pop(0)
            done.add(package)
            if package in given:
                hashes.update(found)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return {name: value for name, value in hashes.items()
            if name.split("/")[0] in given and name.split("/")[1] == "msg"}


def hash_module(package, hashes, command):
    """The text of xrce/msgs/<package>/_hashes.py: the package's message hashes by class name."""
    lines = ["# Generated by %s: the RIHS01 type hash of each message, as rosidl computes it from" % command,
             "# the .msg (rosidl_generator_type_description). Loaded only by xrce.client.type_hash,",
             "# for a board that declares its topics' type hashes at creation; nothing else imports it.",
             "HASHES = {"]
    for type_name in sorted(hashes):
        pkg, kind, name = type_name.split("/")
        if pkg == package and kind == "msg":
            lines.append("    %r: %r," % (name, hashes[type_name]))
    lines += ["}", ""]
    return "\n".join(lines)
