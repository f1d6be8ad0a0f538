"""Parse ROS 2 ``.msg``/``.srv`` definitions into ``MessageSpec``/``ServiceSpec`` (CPython-only tool).

The first half of ``python -m xrce.tools.msggen``, which turns the specs into code; the tests read field
metadata from here too. Errors (``MsgGenError``) name the file and line of the definition.
"""

import ast
import os
import re

# ROS primitive name -> (struct code, size/alignment, python kind)
# kind: "int", "float", "bool", "octet" (uint8-like: arrays of them are carried as bytes)
PRIMITIVES = {
    "bool": ("B", 1, "bool"),
    "byte": ("B", 1, "octet"),
    "char": ("B", 1, "octet"),
    "uint8": ("B", 1, "octet"),
    "int8": ("b", 1, "int"),
    "int16": ("h", 2, "int"),
    "uint16": ("H", 2, "int"),
    "int32": ("i", 4, "int"),
    "uint32": ("I", 4, "int"),
    "int64": ("q", 8, "int"),
    "uint64": ("Q", 8, "int"),
    "float32": ("f", 4, "float"),
    "float64": ("d", 8, "float"),
}
INT_RANGES = {
    "bool": (0, 1), "byte": (0, 255), "char": (0, 255), "uint8": (0, 255), "int8": (-128, 127),
    "int16": (-(1 << 15), (1 << 15) - 1), "uint16": (0, (1 << 16) - 1),
    "int32": (-(1 << 31), (1 << 31) - 1), "uint32": (0, (1 << 32) - 1),
    "int64": (-(1 << 63), (1 << 63) - 1), "uint64": (0, (1 << 64) - 1),
}

_NAME_RE = re.compile(r"^[a-zA-Z][a-zA-Z0-9_]*$")
_TYPE_RE = re.compile(r"^([a-zA-Z][a-zA-Z0-9_]*/)?([a-zA-Z][a-zA-Z0-9_]*)(<=\d+)?(\[(<=)?(\d*)\])?$")


class MsgGenError(Exception):
    """A definition the generator cannot turn into code; the message names file and line."""


class FieldType:
    """A parsed field type: base (primitive name, "string" or "pkg/Type"), string bound, array shape."""

    def __init__(self, base, string_bound=None, array=None, array_size=None):
        self.base = base
        self.string_bound = string_bound
        # array: None (scalar), "fixed" (T[N]), "seq" (T[] or T[<=N]; array_size is the bound or None)
        self.array = array
        self.array_size = array_size

    @property
    def is_primitive(self):
        return self.base in PRIMITIVES

    @property
    def is_string(self):
        return self.base == "string"

    @property
    def is_nested(self):
        return not self.is_primitive and not self.is_string


class Field:
    def __init__(self, name, ftype, default=None):
        self.name = name
        self.type = ftype
        self.default = default  # python value already converted, or None


class Constant:
    def __init__(self, name, ftype, value):
        self.name = name
        self.type = ftype
        self.value = value


class MessageSpec:
    def __init__(self, package, name, kind="msg"):
        self.package = package
        self.name = name  # class name: "Twist", "GetMap_Request"
        self.kind = kind  # "msg" or "srv"
        self.where = None  # the definition's file, as errors name it ("pkg/msg/Name.msg")
        self.fields = []
        self.constants = []

    @property
    def dds_name(self):
        return "%s::%s::dds_::%s_" % (self.package, self.kind, self.name)

    @property
    def ros_type(self):
        return "%s/%s/%s" % (self.package, self.kind, self.name)

    @property
    def ros_base(self):
        """How a field names this type: "pkg/Name" (an action's parts are nested by that name too)."""
        return "%s/%s" % (self.package, self.name)


class ServiceSpec:
    def __init__(self, package, name, request, response, kind="srv"):
        self.package = package
        self.name = name
        self.request = request
        self.response = response
        self.kind = kind  # "srv", or "action" for an action's SendGoal/GetResult

    @property
    def ros_type(self):
        return "%s/%s/%s" % (self.package, self.kind, self.name)


class ActionSpec:
    """An ``.action`` as rosidl expands it: its Goal, Result and Feedback messages, the SendGoal and
    GetResult services and the FeedbackMessage topic type, all named ``<Action>_<Part>`` in
    ``<package>::action::dds_`` (the cancel service and the status topic are action_msgs' own)."""

    def __init__(self, package, name, goal, result, feedback):
        self.package = package
        self.name = name
        self.goal = goal
        self.result = result
        self.feedback = feedback
        uuid = FieldType("unique_identifier_msgs/UUID")
        send_request = MessageSpec(package, name + "_SendGoal_Request", "action")
        send_request.fields = [Field("goal_id", uuid), Field("goal", FieldType(goal.ros_base))]
        send_response = MessageSpec(package, name + "_SendGoal_Response", "action")
        send_response.fields = [Field("accepted", FieldType("bool")),
                                Field("stamp", FieldType("builtin_interfaces/Time"))]
        result_request = MessageSpec(package, name + "_GetResult_Request", "action")
        result_request.fields = [Field("goal_id", uuid)]
        result_response = MessageSpec(package, name + "_GetResult_Response", "action")
        result_response.fields = [Field("status", FieldType("int8")),
                                  Field("result", FieldType(result.ros_base))]
        self.feedback_message = MessageSpec(package, name + "_FeedbackMessage", "action")
        self.feedback_message.fields = [Field("goal_id", uuid),
                                        Field("feedback", FieldType(feedback.ros_base))]
        self.send_goal = ServiceSpec(package, name + "_SendGoal", send_request, send_response, "action")
        self.get_result = ServiceSpec(package, name + "_GetResult", result_request, result_response,
                                      "action")

    @property
    def messages(self):
        """Every message type of the action, each after the types it nests."""
        return [self.goal, self.result, self.feedback, self.send_goal.request,
                self.send_goal.response, self.get_result.request, self.get_result.response,
                self.feedback_message]


def _parse_type(text, package, where):
    m = _TYPE_RE.match(text)
    if not m:
        raise MsgGenError("%s: cannot parse type %r" % (where, text))
    pkg, base, sbound, arr, arr_bounded, arr_n = m.groups()
    if base == "wstring":
        raise MsgGenError("%s: wstring is not supported by this generator" % where)
    if base == "time" or base == "duration":  # ROS 1 spellings still seen in old files
        pkg, base = "builtin_interfaces/", base.capitalize()
    string_bound = None
    if sbound:
        if base != "string":
            raise MsgGenError("%s: only strings take a <=N bound: %r" % (where, text))
        string_bound = int(sbound[2:])
    if pkg:
        full = pkg + base
    elif base in PRIMITIVES or base == "string":
        full = base
    elif base == "Header":
        full = "std_msgs/Header"
    else:
        full = package + "/" + base
    array = array_size = None
    if arr:
        if arr_bounded:
            array, array_size = "seq", int(arr_n)
        elif arr_n:
            array, array_size = "fixed", int(arr_n)
        else:
            array = "seq"
    return FieldType(full, string_bound, array, array_size)


def _strip_comment(line):
    # '#' starts a comment except inside a quoted string default/constant.
    quote = None
    for i, ch in enumerate(line):
        if quote:
            if ch == quote:
                quote = None
        elif ch in "\"'":
            quote = ch
        elif ch == "#":
            return line[:i]
    return line


def _convert_scalar(ftype, text, where):
    text = text.strip()
    base = ftype.base
    try:
        if base == "bool":
            low = text.lower()
            if low in ("true", "1"):
                return True
            if low in ("false", "0"):
                return False
            raise ValueError(text)
        if base == "string":
            if len(text) >= 2 and text[0] == text[-1] and text[0] in "\"'":
                return ast.literal_eval(text)
            return text
        if base in ("float32", "float64"):
            return float(text)
        value = int(text, 0)
    except (ValueError, SyntaxError):
        raise MsgGenError("%s: bad value %r for %s" % (where, text, base))
    lo, hi = INT_RANGES[base]
    if not lo <= value <= hi:
        raise MsgGenError("%s: value %r out of range for %s" % (where, value, base))
    return value


def _convert_default(ftype, text, where):
    if ftype.is_nested:
        raise MsgGenError("%s: nested fields cannot have defaults" % where)
    if ftype.array is None:
        return _convert_scalar(ftype, text, where)
    text = text.strip()
    if not (text.startswith("[") and text.endswith("]")):
        raise MsgGenError("%s: array default must be [..]: %r" % (where, text))
    inner = text[1:-1].strip()
    items = [s for s in _split_array(inner)] if inner else []
    values = [_convert_scalar(ftype, s, where) for s in items]
    if ftype.array == "fixed" and len(values) != ftype.array_size:
        raise MsgGenError("%s: default has %d items, array needs %d" % (where, len(values), ftype.array_size))
    if ftype.array == "seq" and ftype.array_size is not None and len(values) > ftype.array_size:
        raise MsgGenError("%s: default exceeds the sequence bound" % where)
    return values


def _split_array(inner):
    out, cur, quote = [], "", None
    for ch in inner:
        if quote:
            cur += ch
            if ch == quote:
                quote = None
        elif ch in "\"'":
            quote = ch
            cur += ch
        elif ch == ",":
            out.append(cur.strip())
            cur = ""
        else:
            cur += ch
    out.append(cur.strip())
    return out


def parse_message_text(text, package, name, kind="msg", where=None):
    """Parse the body of a .msg (or one half of a .srv) into a MessageSpec."""
    where = where or "%s/%s/%s" % (package, kind, name)
    spec = MessageSpec(package, name, kind)
    spec.where = where
    for lineno, raw in enumerate(text.splitlines(), 1):
        loc = "%s:%d" % (where, lineno)
        stripped = raw.strip()
        if not stripped or stripped.startswith("#"):
            continue
        m = re.match(r"^(\S+)\s+([A-Za-z][A-Za-z0-9_]*)\s*=\s*(.*)$", stripped)
        if m:
            ftype = _parse_type(m.group(1), package, "%s: constant %s" % (loc, m.group(2)))
            if ftype.array or ftype.is_nested:
                raise MsgGenError("%s: constants must be primitive scalars or strings" % loc)
            value_text = m.group(3)
            if not ftype.is_string:
                value_text = _strip_comment(value_text)
            spec.constants.append(Constant(m.group(2), ftype, _convert_scalar(ftype, value_text, loc)))
            continue
        line = _strip_comment(stripped).strip()
        parts = line.split(None, 2)
        if len(parts) < 2:
            raise MsgGenError("%s: expected 'TYPE NAME [DEFAULT]'" % loc)
        ftype = _parse_type(parts[0], package, "%s: field %s" % (loc, parts[1]))
        if not _NAME_RE.match(parts[1]):
            raise MsgGenError("%s: bad field name %r" % (loc, parts[1]))
        default = _convert_default(ftype, parts[2], loc) if len(parts) == 3 else None
        spec.fields.append(Field(parts[1], ftype, default))
    names = [f.name for f in spec.fields] + [c.name for c in spec.constants]
    if len(set(names)) != len(names):
        raise MsgGenError("%s: duplicate field or constant name" % where)
    return spec


def load_package(pkg_dir):
    """Read msg/*.msg and srv/*.srv of one package directory; returns (name, messages, services)."""
    package = os.path.basename(os.path.normpath(pkg_dir))
    messages, services = [], []
    msg_dir = os.path.join(pkg_dir, "msg")
    if os.path.isdir(msg_dir):
        for fn in sorted(os.listdir(msg_dir)):
            if fn.endswith(".msg"):
                with open(os.path.join(msg_dir, fn)) as f:
                    messages.append(parse_message_text(f.read(), package, fn[:-4], "msg",
                                                       "%s/msg/%s" % (package, fn)))
    srv_dir = os.path.join(pkg_dir, "srv")
    if os.path.isdir(srv_dir):
        for fn in sorted(os.listdir(srv_dir)):
            if fn.endswith(".srv"):
                with open(os.path.join(srv_dir, fn)) as f:
                    text = f.read()
                halves = re.split(r"^---\s*$", text, flags=re.M)
                if len(halves) != 2:
                    raise MsgGenError("%s/srv/%s: expected exactly one '---' separator" % (package, fn))
                name = fn[:-4]
                where = "%s/srv/%s" % (package, fn)
                req = parse_message_text(halves[0], package, name + "_Request", "srv", where)
                resp = parse_message_text(halves[1], package, name + "_Response", "srv", where)
                services.append(ServiceSpec(package, name, req, resp))
    if not messages and not services and not load_actions(pkg_dir):
        raise MsgGenError("%s: no msg/*.msg, srv/*.srv or action/*.action files" % pkg_dir)
    return package, messages, services


def load_actions(pkg_dir):
    """The ActionSpec of each action/*.action of one package directory (Goal, Result and Feedback
    separated by two '---' lines)."""
    package = os.path.basename(os.path.normpath(pkg_dir))
    actions = []
    action_dir = os.path.join(pkg_dir, "action")
    if not os.path.isdir(action_dir):
        return actions
    for fn in sorted(os.listdir(action_dir)):
        if not fn.endswith(".action"):
            continue
        with open(os.path.join(action_dir, fn)) as f:
            text = f.read()
        parts = re.split(r"^---\s*$", text, flags=re.M)
        where = "%s/action/%s" % (package, fn)
        if len(parts) != 3:
            raise MsgGenError("%s: expected exactly two '---' separators" % where)
        name = fn[:-7]
        goal, result, feedback = (parse_message_text(part, package, name + "_" + suffix, "action", where)
                                  for part, suffix in zip(parts, ("Goal", "Result", "Feedback")))
        actions.append(ActionSpec(package, name, goal, result, feedback))
    return actions
