"""Interface types by name and messages to and from YAML, as ros2cli shows and reads them.

ros2cli uses ``rosidl_runtime_py`` for this, which the PyPI wheels do not carry; this module gives
the same YAML (field order, truncation marks, PyYAML's scalars, one line however long) from what
every generated rclpy class has: ``get_fields_and_field_types()`` and ``SLOT_TYPES``.
"""

from __future__ import annotations

import array
import importlib
import importlib.util
import os
import sys

import numpy
import yaml
from rosidl_parser.definition import (AbstractNestedType, Array, BoundedSequence, BasicType,
                                      AbstractString, AbstractWString, NamespacedType, NamedType)

from xrce.tools.ros_cli.arguments import UsageError


# ----------------------------------------------------------------------------- types by name

def interface_class(type_name, kind):
    """The rclpy class of ``pkg/kind/Name`` or ``pkg/Name`` (``kind``: msg, srv or action); a name
    that is not one is a UsageError, with ros2cli's sentence."""
    parts = type_name.split("/")
    if len(parts) == 2:
        parts = [parts[0], kind, parts[1]]
    what = {"msg": "message", "srv": "service", "action": "action"}[kind]
    if len(parts) != 3 or parts[1] != kind or not all(p.isidentifier() for p in parts):
        raise UsageError("The passed %s type is invalid: %r" % (what, type_name))
    try:
        cls = getattr(importlib.import_module("%s.%s" % (parts[0], kind)), parts[2])
    except (AttributeError, ImportError, ValueError):
        raise UsageError("The passed %s type is invalid: %r (%s)"
                         % (what, type_name, missing_type_reason(parts[0], parts[2]))) from None
    members = {"msg": ("get_fields_and_field_types",), "srv": ("Request", "Response"),
               "action": ("Goal", "Result", "Feedback")}[kind]
    if not all(hasattr(cls, member) for member in members):
        raise UsageError("The passed type is not a %s: %r" % (what, type_name))
    return cls


# The interface packages that come with xrce (xrce/ros_interfaces/): build-interfaces' default.
_SHIPPED_INTERFACES = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(
    __file__)))), "ros_interfaces")


def build_command(package):
    """The ``xrce-agent build-interfaces`` line that builds ``package`` for this venv's rclpy (the
    agent's and every other program's: xrce.agent.interfaces.registry)."""
    if os.path.isfile(os.path.join(_SHIPPED_INTERFACES, package, "package.xml")):
        return "xrce-agent build-interfaces --package %s" % package
    return "xrce-agent build-interfaces DIR --package %s" % package


def missing_type_reason(package, type_name):
    """Why ``package``'s ``type_name`` cannot be imported here, with the command that fixes it
    when a build can: the package is in no place this venv imports from, or it is one xrce built
    and the type was added to its files since."""
    try:
        present = importlib.util.find_spec(package) is not None
    except (ImportError, ValueError):
        present = False
    if not present:
        where = "" if build_command(package).startswith("xrce-agent build-interfaces --") else (
            ", DIR holding %s/ with its package.xml" % package)
        return "package %s is not built for this venv: `%s`%s" % (package, build_command(package), where)
    try:
        from xrce.agent.interfaces.registry import is_registered

        built_by_xrce = is_registered(package)
    except ImportError:
        built_by_xrce = False
    if built_by_xrce:
        return "%s has no %s: if it was added since, rebuild: `%s`" % (package, type_name, build_command(package))
    return "no such type in this venv"


def _nested_class(namespaced_type):
    module = importlib.import_module(".".join(namespaced_type.namespaces))
    return getattr(module, namespaced_type.name)


def _is_message(value):
    return hasattr(value, "get_fields_and_field_types")


# ----------------------------------------------------------------------------- message → YAML

def _type_label(value_type):
    if isinstance(value_type, BasicType):
        return value_type.typename
    if isinstance(value_type, AbstractString):
        return "string"
    if isinstance(value_type, AbstractWString):
        return "wstring"
    if isinstance(value_type, NamedType):
        return value_type.name
    if isinstance(value_type, NamespacedType):
        return "/".join(value_type.namespaced_name())
    return "unknown"


def _array_summary(value, slot_type):
    """What --no-arr prints in place of an array or sequence field."""
    label = _type_label(slot_type.value_type)
    if isinstance(slot_type, Array):
        return "<array type: %s[%d]>" % (label, slot_type.size)
    if isinstance(slot_type, BoundedSequence):
        return "<sequence type: %s[%d], length: %d>" % (label, slot_type.maximum_size, len(value))
    return "<sequence type: %s, length: %d>" % (label, len(value))


def message_to_dict(msg, truncate_length=None, no_arr=False, no_str=False):
    """The message as plain dicts and lists in field order, long strings and arrays cut to
    ``truncate_length`` with a ``...`` mark."""
    fields = {}
    for name, slot_type in zip(msg.get_fields_and_field_types(), msg.SLOT_TYPES):
        fields[name] = _plain(getattr(msg, name), slot_type, truncate_length, no_arr, no_str)
    return fields


def _plain(value, slot_type, truncate_length, no_arr, no_str):
    if isinstance(value, bytes):  # a byte field: shown as the characters of its bytes
        text = "".join(chr(b) for b in value[:truncate_length])
        cut = truncate_length is not None and len(value) > truncate_length
        return text + "..." if cut else text
    if isinstance(value, str):
        if no_str:
            return "<string length: <%d>>" % len(value)
        if truncate_length is not None and len(value) > truncate_length:
            return value[:truncate_length] + "..."
        return value
    if isinstance(value, (list, tuple, array.array, numpy.ndarray)):
        if no_arr and slot_type is not None:
            return _array_summary(value, slot_type)
        cut = truncate_length is not None and len(value) > truncate_length
        items = [_plain(v, None, truncate_length, no_arr, no_str)
                 for v in (value[:truncate_length] if cut else value)]
        return items + ["..."] if cut else items
    if isinstance(value, numpy.generic):
        return value.item()
    if isinstance(value, (bool, int, float)):
        return value
    return message_to_dict(value, truncate_length, no_arr, no_str)


def message_to_yaml(msg, truncate_length=None, no_arr=False, no_str=False, flow_style=False):
    return yaml.dump(message_to_dict(msg, truncate_length, no_arr, no_str), allow_unicode=True,
                     width=sys.maxsize, default_flow_style=flow_style, sort_keys=False)


# ----------------------------------------------------------------------------- YAML → message

# The words YAML 1.1 (PyYAML's safe_load) reads as booleans when unquoted, by the value they give.
_YAML_BOOLEAN_WORDS = {True: ("y", "yes", "on", "true"), False: ("n", "no", "off", "false")}


def _unquoted_key_hint(key, slot_types):
    """For a key YAML did not read as a string (``{on: true}`` gives the key True), the field it
    most likely was and how to write it."""
    if isinstance(key, str):
        return ""
    if isinstance(key, bool):
        fields = [f for f in slot_types if f.lower() in _YAML_BOOLEAN_WORDS[key]]
        named = fields[0] if fields else _YAML_BOOLEAN_WORDS[key][2]
        return (": YAML reads an unquoted %s as the boolean %s: quote the key ('\"%s\": ...')"
                % (named, key, named))
    return ": YAML read the key as a %s: quote it ('\"%s\": ...')" % (type(key).__name__, key)


def parse_yaml_values(text):
    """The YAML a verb was given, which must be a mapping (``{}`` when none was given)."""
    try:
        values = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise UsageError("the values are not YAML: %s" % " ".join(str(error).split())) from None
    if values is None:
        values = {}
    if not isinstance(values, dict):
        raise UsageError("The passed value needs to be a dictionary in YAML format")
    return values


def set_message_fields(msg, values, expand_header_auto=False, expand_time_now=False):
    """Fill ``msg`` from a YAML mapping. With ``expand_header_auto`` a Header given as ``auto``,
    and with ``expand_time_now`` a Time given as ``now``, are left to be stamped at each publish:
    the setters for that are returned (``setter(time_msg)``)."""
    stamp_setters = []
    _fill(msg, values, expand_header_auto, expand_time_now, stamp_setters)
    return stamp_setters


def _fill(msg, values, header_auto, time_now, stamp_setters):
    if not isinstance(values, dict):
        raise TypeError("Value '%s' is expected to be a dictionary but is a %s"
                        % (values, type(values).__name__))
    slot_types = dict(zip(msg.get_fields_and_field_types(), msg.SLOT_TYPES))
    for name, given in values.items():
        if name not in slot_types:
            raise AttributeError("'%s' object has no attribute '%s'%s" % (
                type(msg).__name__, name, _unquoted_key_hint(name, slot_types)))
        current = getattr(msg, name)
        slot_type = slot_types[name]
        if _is_message(current):
            qualified = "%s/%s" % (type(current).__module__.split(".")[0], type(current).__name__)
            if header_auto and given == "auto" and qualified == "std_msgs/Header":
                stamp_setters.append(lambda stamp, header=current: setattr(header, "stamp", stamp))
                continue
            if time_now and given == "now" and qualified == "builtin_interfaces/Time":
                stamp_setters.append(lambda stamp, m=msg, n=name: setattr(m, n, stamp))
                continue
            _fill(current, given, header_auto, time_now, stamp_setters)
            continue
        if isinstance(slot_type, AbstractNestedType) and isinstance(slot_type.value_type,
                                                                    NamespacedType):
            if not isinstance(given, list):
                raise TypeError("Value '%s' of field '%s' is expected to be a list"
                                % (given, name))
            element_class = _nested_class(slot_type.value_type)
            elements = []
            for item in given:
                element = element_class()
                _fill(element, item, header_auto, time_now, stamp_setters)
                elements.append(element)
            setattr(msg, name, elements)
            continue
        if isinstance(current, array.array):
            value = array.array(current.typecode, given)
        elif isinstance(current, numpy.ndarray):
            value = numpy.array(given, dtype=current.dtype)
        elif type(given) is type(current):
            value = given
        elif isinstance(given, bool) and not isinstance(current, (bool, int, float)):
            # str(True) would send "True" for a string field given yes, on or true unquoted.
            raise TypeError("field '%s' wants %s, and YAML read the unquoted value as the "
                            "boolean %s (so it reads yes, no, on, off, true, false): quote it"
                            % (name, type(current).__name__, given))
        else:
            try:
                value = type(current)(given)  # 7 for a float field, a YAML string for a bytes one
            except (TypeError, ValueError) as error:
                if isinstance(given, (bool, int, float)):
                    raise TypeError("field '%s' wants %s, and YAML read %r as a %s (%s): quote it "
                                    "or give a value of the field's type"
                                    % (name, type(current).__name__, given,
                                       "boolean" if isinstance(given, bool) else "number", error)) from None
                raise
        setattr(msg, name, value)
