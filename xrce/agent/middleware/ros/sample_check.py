"""Whether a board's sample can be the type this agent has for it (issue 52's type drift).

The agent moves samples as CDR and never decodes them; a board whose classes were generated from
another version of a ``.msg`` than the agent's package (``float64 voltage`` on one side,
``float32`` on the other, a field added or removed) then feeds ROS garbage in silence. Decoding
the sample with the agent's definition tells: a sample that is not the type reads past its end or
leaves bytes unread. Only ``xrce.agent.engine.type_drift`` calls this, for a few samples per
endpoint, never per sample.

The definition is the package's own ``.msg`` file (``share/<package>/msg/<Type>.msg`` of the ROS in
use or of a package the agent built, nested types likewise), read by the client's generator's
parser (``xrce.tools.msg_parser``) into the client's table-driven classes (``xrce.msgs._define``),
whose decoder then reads the sample. Not rclpy's Python classes: the agent imports none (its
raw types come from the C type supports alone, ``raw_types``), and one import of Imu or Odometry
costs ~20 MB with numpy. A type the agent carries by name (no package), a package without its
``.msg`` files or a definition the parser refuses (wstring) cannot be checked: no check.
"""

from __future__ import annotations

import os
from typing import Callable, Dict, Optional

from xrce import DecodeError
from xrce.wire.cdr import CdrReader

MAX_TYPES = 1024  # definitions kept (per agent process): a flood of type names must not grow it
_classes: Dict[str, object] = {}  # "pkg/Name" -> the class, or None where it cannot be made
_hashes: Dict[str, Optional[str]] = {}  # "pkg/msg/Name" -> its RIHS01 hash here, or None


def prepare() -> None:
    """Import what a first check needs, ahead of it (``membership.prepare``, at start)."""
    from xrce.msgs import _define  # noqa: F401
    from xrce.tools import msg_parser  # noqa: F401


def checker(dds_type: str) -> Optional[Callable[[bytes], Optional[str]]]:
    """``check(sample) -> None | why`` for samples (CDR behind their encapsulation) of the message
    type ``dds_type`` (``pkg::msg::dds_::Name_``), or None where this agent cannot tell."""
    parts = dds_type.split("::")
    if len(parts) != 4 or parts[1] != "msg" or parts[2] != "dds_" or not parts[3].endswith("_"):
        return None
    cls = _message_class("%s/%s" % (parts[0], parts[3][:-1]), ())
    if cls is None:
        return None

    def check(sample: bytes) -> Optional[str]:
        reader = CdrReader(bytes(sample))
        try:
            cls.decode(reader)
        except (DecodeError, ValueError, UnicodeError):
            return "its %d bytes do not decode as this type (it reads past their end)" % len(sample)
        if reader.pos < len(sample):
            return ("%d of its %d bytes are left unread after the type's last field"
                    % (len(sample) - reader.pos, len(sample)))
        return None
    return check


def package_type_hash(dds_type: str) -> Optional[str]:
    """The RIHS01 hash of the message type ``dds_type`` as this agent's package has it: the type
    description rosidl wrote beside its ``.msg`` (``share/<package>/msg/<Type>.json``, whether ROS
    installed the package or the agent built it); None where there is none."""
    parts = dds_type.split("::")
    if len(parts) != 4 or parts[1] != "msg" or parts[2] != "dds_" or not parts[3].endswith("_"):
        return None
    package, name = parts[0], parts[3][:-1]
    key = "%s/msg/%s" % (package, name)
    if key in _hashes:
        return _hashes[key]
    found = None
    path = _definition_file(package, name)
    if path is not None:
        import json

        try:
            with open(path[: -len(".msg")] + ".json", encoding="utf-8") as description:
                for entry in json.load(description).get("type_hashes", ()):
                    if entry.get("type_name") == key:
                        found = entry.get("hash_string")
                        break
        except (OSError, ValueError, AttributeError):
            found = None
    if len(_hashes) < MAX_TYPES:
        _hashes[key] = found
    return found


def _definition_file(package: str, name: str) -> Optional[str]:
    from xrce.agent.interfaces import ros_install as rosenv

    prefixes = list(rosenv.ament_prefixes())
    try:
        from xrce.agent.interfaces import registry

        finder = registry._FINDER
        entry = finder.entries.get(package) if finder is not None else None
        if entry is not None:
            prefixes.append(entry["prefix"])
    except ImportError:
        pass
    for prefix in prefixes:
        path = os.path.join(prefix, "share", package, "msg", name + ".msg")
        if os.path.isfile(path):
            return path
    return None


def _message_class(base: str, outer: tuple):
    """The client's class for ``pkg/Name`` from its ``.msg`` file, nested types first; None where
    it cannot be made (no file, a definition the parser refuses, a type nested in itself)."""
    if base in _classes:
        return _classes[base]
    if base in outer:
        return None
    from xrce.msgs import _define
    from xrce.tools.msg_parser import PRIMITIVES, MsgGenError, parse_message_text

    package, name = base.split("/")
    path = _definition_file(package, name)
    cls = None
    if path is not None:
        try:
            with open(path, encoding="utf-8") as definition:
                spec = parse_message_text(definition.read(), package, name)
            specs = []
            for field in spec.fields:
                item = _item_spec(field.type, PRIMITIVES, outer + (base,))
                if item is None:
                    raise MsgGenError("%s: field %s cannot be checked" % (base, field.name))
                if field.type.array == "fixed":
                    item = ("F", field.type.array_size, item)
                elif field.type.array == "seq":
                    item = ("S", field.type.array_size, item)
                specs.append(item)
            cls = _define("%s/msg/%s" % (package, name), tuple(f.name for f in spec.fields), tuple(specs))
        except (OSError, UnicodeError, MsgGenError):
            cls = None
    if len(_classes) < MAX_TYPES:
        _classes[base] = cls
    return cls


def _item_spec(field_type, primitives, outer):
    if field_type.is_nested:
        return _message_class(field_type.base, outer)
    if field_type.is_string:
        return "s" if field_type.string_bound is None else ("s", field_type.string_bound)
    code, _, kind = primitives[field_type.base]
    return "?" if kind == "bool" else code
