"""Generate MicroPython-safe XCDR1 message classes from ROS 2 .msg/.srv files (CPython-only tool).

Each ROS package becomes a Python package in the output directory (normally ``xrce/msgs``) with
one module per message type and per service (``geometry_msgs/_Twist.py``) and an ``__init__.py``
that imports a type's module the first time its name is looked up: importing a whole package's
classes costs tens of KB of MicroPython heap, and a board usually needs two or three types.
The generated code is plain Python in the MicroPython subset: ``__slots__`` classes, precompiled
``struct`` formats for runs of fixed-size primitives, no dataclasses/typing/f-strings.

    python -m xrce.msggen PKG_DIR [PKG_DIR ...] -o OUTDIR
    python -m xrce.msggen --shipped [-o OUTDIR]      # the set committed in xrce/msgs
"""

import argparse
import ast
import os
import re
import sys

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

MAX_STAR_POSITION = 24

SHIPPED_FROM_VENV = ("builtin_interfaces", "std_msgs", "geometry_msgs", "sensor_msgs", "nav_msgs")
SHIPPED_FROM_REPO = ("tf2_msgs", "turtlebot3_msgs")
SHIPPED_COMMAND = "python -m xrce.msggen --shipped"

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
        self.fields = []
        self.constants = []

    @property
    def dds_name(self):
        return "%s::%s::dds_::%s_" % (self.package, self.kind, self.name)

    @property
    def ros_type(self):
        return "%s/%s/%s" % (self.package, self.kind, self.name)


class ServiceSpec:
    def __init__(self, package, name, request, response):
        self.package = package
        self.name = name
        self.request = request
        self.response = response


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
    for lineno, raw in enumerate(text.splitlines(), 1):
        loc = "%s:%d" % (where, lineno)
        stripped = raw.strip()
        if not stripped or stripped.startswith("#"):
            continue
        m = re.match(r"^(\S+)\s+([A-Za-z][A-Za-z0-9_]*)\s*=\s*(.*)$", stripped)
        if m:
            ftype = _parse_type(m.group(1), package, loc)
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
        ftype = _parse_type(parts[0], package, loc)
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
    if not messages and not services:
        raise MsgGenError("%s: no msg/*.msg or srv/*.srv files" % pkg_dir)
    return package, messages, services


# ---------------------------------------------------------------------------------------------
# Code generation


def _is_runnable(ftype):
    """Fields that can share one precompiled struct format: fixed-size numeric/bool scalars and
    fixed arrays of non-octet numerics (octet arrays are copied as bytes, bool arrays need checks)."""
    if not ftype.is_primitive:
        return False
    if ftype.array is None:
        return True
    return ftype.array == "fixed" and PRIMITIVES[ftype.base][2] in ("int", "float")


def plan_runs(fields):
    """Group consecutive fields into steps: ("run", [fields]) or ("one", field).

    A run only grows while the next field needs no padding inside it and its alignment does not
    exceed the run's first field: aligning once to the first field's size then makes the packed
    layout identical to field-by-field CDR whatever phase the run starts at.
    """
    steps = []
    run = []
    offset = 0
    for field in fields:
        ft = field.type
        if _is_runnable(ft):
            code, size, _ = PRIMITIVES[ft.base]
            count = ft.array_size if ft.array == "fixed" else 1
            if run:
                first_align = PRIMITIVES[run[0].type.base][1]
                # MicroPython records *args positions in a small-int bitmap: keep every unpacked
                # array among the first MAX_STAR_POSITION arguments of pack_into.
                star_ok = ft.array is None or len(run) + 3 < MAX_STAR_POSITION
                if size <= first_align and offset % size == 0 and star_ok:
                    run.append(field)
                    offset += size * count
                    continue
                steps.append(("run", run))
            run = [field]
            offset = size * count
            continue
        if run:
            steps.append(("run", run))
            run = []
        steps.append(("one", field))
    if run:
        steps.append(("run", run))
    return steps


def _run_format(run):
    """struct format of a run, repeated codes folded into counts ("<6d", "<7d36d" -> "<43d")."""
    pieces = []
    for f in run:
        code = PRIMITIVES[f.type.base][0]
        count = f.type.array_size if f.type.array == "fixed" else 1
        if pieces and pieces[-1][0] == code:
            pieces[-1][1] += count
        else:
            pieces.append([code, count])
    return "<" + "".join((str(n) if n != 1 else "") + c for c, n in pieces)


def _run_size(run):
    return sum(PRIMITIVES[f.type.base][1] * (f.type.array_size if f.type.array == "fixed" else 1) for f in run)


def _class_ref(base, package, deps):
    """The name generated code uses for a nested type; recorded in ``deps`` so the module imports
    it. Types of other packages get a package prefix: two packages may both define e.g. Point."""
    deps.add(base)
    pkg, name = base.split("/")
    if pkg == package:
        return name
    return "_%s_%s" % (pkg, name)


def _default_expr(field, package, deps):
    ft = field.type
    d = field.default
    if ft.is_nested:
        if ft.array == "seq":
            return "[]"
        ref = _class_ref(ft.base, package, deps)
        if ft.array == "fixed":
            return "[%s() for _ in range(%d)]" % (ref, ft.array_size)
        return "%s()" % ref
    kind = PRIMITIVES[ft.base][2] if ft.is_primitive else "string"
    if ft.array is None:
        if d is None:
            return {"bool": "False", "float": "0.0", "int": "0", "octet": "0", "string": '""'}[kind]
        if kind == "float":
            return repr(float(d))
        return repr(d)
    if kind == "octet":
        if d is None:
            d = [0] * ft.array_size if ft.array == "fixed" else []
        return repr(bytes(d))
    if d is None:
        zero = {"bool": False, "float": 0.0, "int": 0, "string": ""}[kind]
        if ft.array == "fixed":
            return "[%r] * %d" % (zero, ft.array_size)
        return "[]"
    if kind == "float":
        d = [float(v) for v in d]
    return repr(list(d))


class Leaf:
    """One value the encoder touches: a top-level field, or a field of a nested struct inlined
    into its parent (XCDR1 structs add no alignment of their own, so inlining keeps the bytes)."""

    def __init__(self, expr, label, ftype):
        self.expr = expr  # "self.linear.x"
        self.label = label  # "linear.x", for error messages
        self.type = ftype
        self.var = None  # decode variable, set by _flatten


def _inlinable(ftype, registry):
    if not ftype.is_nested or ftype.array is not None:
        return False
    return bool(registry[ftype.base].fields)  # an empty struct carries a dummy octet instead


def _flatten(spec, registry, expr, label, leaves, package, deps):
    """Append leaves of ``spec`` and return the decode expression that rebuilds it."""
    parts = []
    for f in spec.fields:
        fexpr = "%s.%s" % (expr, f.name)
        flabel = f.name if not label else "%s.%s" % (label, f.name)
        if _inlinable(f.type, registry):
            child = registry[f.type.base]
            ref = _class_ref(f.type.base, package, deps)
            parts.append("%s(%s)" % (ref, _flatten(child, registry, fexpr, flabel, leaves, package, deps)))
            continue
        leaf = Leaf(fexpr, flabel, f.type)
        leaf.var = "v%d" % len(leaves)
        leaves.append(leaf)
        parts.append(leaf.var)
    return ", ".join(parts)


def _gen_encode_step(step, package, out):
    kind, item = step
    if kind == "run":
        run = item
        fmt = _run_format(run)
        args = []
        for f in run:
            if f.type.array == "fixed":
                out.append("        if len(%s) != %d:" % (f.expr, f.type.array_size))
                out.append("            _bad_len(%r, %d)" % (f.label, f.type.array_size))
                args.append("*" + f.expr)
            elif f.type.base == "bool":
                args.append("1 if %s else 0" % f.expr)
            else:
                args.append(f.expr)
        align = PRIMITIVES[run[0].type.base][1]
        out.append("        try:")
        # Floats cannot be truncated by struct, so float-only runs skip MicroPython's read-back
        # range check (_pack_into), which allocates a tuple of every value per sample.
        packer = "_pack_floats" if all(PRIMITIVES[f.type.base][0] in "fd" for f in run) else "_pack_into"
        out.append("            %s(%r, w.buf, _put(w, %d, %d), %s)" % (packer, fmt, align, _run_size(run), ", ".join(args)))
        out.append("        except _PACK_ERRORS:")
        # The message's repr names the culprit; a label string per run would cost every board heap.
        out.append("            _bad_values(self)")
        return
    f = item
    ft = f.type
    v = f.expr
    if ft.is_nested:
        if ft.array is None:
            out.append("        %s.encode(w)" % v)
            return
        if ft.array == "fixed":
            out.append("        if len(%s) != %d:" % (v, ft.array_size))
            out.append("            _bad_len(%r, %d)" % (f.label, ft.array_size))
        else:
            out.append("        w.u32(_seq_len(%s, %r, %r))" % (v, ft.array_size, f.label))
        out.append("        for item in %s:" % v)
        out.append("            item.encode(w)")
        return
    if ft.is_string:
        if ft.array is None:
            out.append("        _put_string(w, %s, %r)" % (v, ft.string_bound))
            return
        if ft.array == "fixed":
            out.append("        if len(%s) != %d:" % (v, ft.array_size))
            out.append("            _bad_len(%r, %d)" % (f.label, ft.array_size))
        else:
            out.append("        w.u32(_seq_len(%s, %r, %r))" % (v, ft.array_size, f.label))
        out.append("        for item in %s:" % v)
        out.append("            _put_string(w, item, %r)" % (ft.string_bound,))
        return
    code, size, pkind = PRIMITIVES[ft.base]
    # Primitive scalars always land in runs, so only arrays and sequences reach this point.
    if pkind == "octet":
        if ft.array == "fixed":
            out.append("        _put_octets(w, %s, %d, None, %r)" % (v, ft.array_size, f.label))
        else:
            out.append("        _put_octets(w, %s, None, %r, %r)" % (v, ft.array_size, f.label))
        return
    if ft.array == "fixed":
        out.append("        if len(%s) != %d:" % (v, ft.array_size))
        out.append("            _bad_len(%r, %d)" % (f.label, ft.array_size))
    else:
        out.append("        w.u32(_seq_len(%s, %r, %r))" % (v, ft.array_size, f.label))
    if pkind == "bool":
        out.append("        _put_array(w, [1 if b else 0 for b in %s], 'B', 1)" % v)
    else:
        out.append("        _put_array(w, %s, %r, %d)" % (v, code, size))


def _gen_decode_step(step, package, out, deps):
    kind, item = step
    if kind == "run":
        run = item
        fmt = _run_format(run)
        align = PRIMITIVES[run[0].type.base][1]
        size = _run_size(run)
        if all(f.type.array is None for f in run):
            targets = [f.var for f in run]
            out.append("        %s%s = _unpack_from(%r, r.buf, _take(r, %d, %d))" % (
                ", ".join(targets), "," if len(targets) == 1 else "", fmt, align, size))
            for f in run:
                if f.type.base == "bool":
                    out.append("        %s = _bool(%s)" % (f.var, f.var))
        else:
            out.append("        vals = _unpack_from(%r, r.buf, _take(r, %d, %d))" % (fmt, align, size))
            idx = 0
            for f in run:
                if f.type.array == "fixed":
                    out.append("        %s = list(vals[%d:%d])" % (f.var, idx, idx + f.type.array_size))
                    idx += f.type.array_size
                else:
                    conv = "_bool(vals[%d])" if f.type.base == "bool" else "vals[%d]"
                    out.append("        %s = %s" % (f.var, conv % idx))
                    idx += 1
        return
    f = item
    ft = f.type
    t = f.var
    if ft.is_nested:
        ref = _class_ref(ft.base, package, deps)
        if ft.array is None:
            out.append("        %s = %s.decode(r)" % (t, ref))
        elif ft.array == "fixed":
            out.append("        %s = [%s.decode(r) for _ in range(%d)]" % (t, ref, ft.array_size))
        else:
            out.append("        %s = [%s.decode(r) for _ in range(_count(r, %r, 1))]" % (t, ref, ft.array_size))
        return
    if ft.is_string:
        if ft.array is None:
            out.append("        %s = _get_string(r, %r)" % (t, ft.string_bound))
        elif ft.array == "fixed":
            out.append("        %s = [_get_string(r, %r) for _ in range(%d)]" % (t, ft.string_bound, ft.array_size))
        else:
            out.append("        %s = [_get_string(r, %r) for _ in range(_count(r, %r, 4))]" % (
                t, ft.string_bound, ft.array_size))
        return
    code, size, pkind = PRIMITIVES[ft.base]
    count = str(ft.array_size) if ft.array == "fixed" else "_count(r, %r, %d)" % (ft.array_size, size)
    if pkind == "octet":
        out.append("        %s = r.raw(%s)" % (t, count))
    elif pkind == "bool":
        out.append("        %s = [_bool(b) for b in r.raw(%s)]" % (t, count))
    else:
        out.append("        %s = _get_array(r, %s, %r, %d)" % (t, count, code, size))


def _gen_message(spec, registry, out, deps):
    package = spec.package
    fields = spec.fields
    out.append("")
    out.append("")
    out.append("class %s(_Message):" % spec.name)
    out.append("    __slots__ = (%s)" % "".join("%r, " % f.name for f in fields))
    out.append("    TYPE_NAME = %r" % spec.dds_name)
    out.append("    ROS_TYPE = %r" % spec.ros_type)
    # The dict helpers infer every other field's shape from a default instance; a list of
    # messages may be empty by default, so its item type is spelled out.
    items = [f for f in fields if f.type.is_nested and f.type.array is not None]
    if items:
        out.append("    _ITEMS = (%s)" % "".join(
            "(%r, %s), " % (f.name, _class_ref(f.type.base, package, deps)) for f in items))
    for c in spec.constants:
        value = float(c.value) if c.type.base in ("float32", "float64") else c.value
        out.append("    %s = %r" % (c.name, value))
    out.append("")
    params = "".join(", %s=None" % f.name for f in fields)
    out.append("    def __init__(self%s):" % params)
    if not fields:
        out.append("        pass")
    for f in fields:
        out.append("        self.%s = %s if %s is None else %s" % (
            f.name, _default_expr(f, package, deps), f.name, f.name))
    out.append("")
    leaves = []
    rebuild = _flatten(spec, registry, "self", "", leaves, package, deps)
    steps = plan_runs(leaves)
    out.append("    def encode(self, w):")
    if not fields:
        # The rosidl typesupports give an empty struct one dummy octet.
        out.append("        w.u8(0)")
    for step in steps:
        _gen_encode_step(step, package, out)
    out.append("")
    out.append("    @classmethod")
    out.append("    def decode(cls, r):")
    if not fields:
        out.append("        r.u8()")
        out.append("        return cls()")
    else:
        for step in steps:
            _gen_decode_step(step, package, out, deps)
        out.append("        return cls(%s)" % rebuild)


def service_class_name(srv, message_names):
    """The descriptor is named after the service unless a message of the package already has that
    name (turtlebot3_msgs has both msg/Sound and srv/Sound); then it gets a "_Service" suffix."""
    return srv.name + "_Service" if srv.name in message_names else srv.name


def module_name(class_name):
    """Module of a message or service descriptor class inside its package. The underscore keeps the
    submodule, which imports bind as an attribute of the package, from hiding the class there."""
    return "_" + class_name


def _gen_service(srv, out, class_name):
    out.append("")
    out.append("")
    out.append("class %s:" % class_name)
    out.append("    Request = %s" % srv.request.name)
    out.append("    Response = %s" % srv.response.name)
    out.append("    TYPE_NAME_REQUEST = %r" % srv.request.dds_name)
    out.append("    TYPE_NAME_RESPONSE = %r" % srv.response.dds_name)
    out.append("    ROS_TYPE = %r" % ("%s/srv/%s" % (srv.package, srv.name)))


# What generated modules may take from the shared runtime, by module: xrce/msgs/__init__.py has what
# scalar and string fields need, _seq.py the array and sequence helpers. Each generated module
# imports only the names its code uses, so a board does not load or bind what it never calls.
RUNTIME_NAMES = (
    ("xrce.msgs", ("_PACK_ERRORS", "_Message", "_bad_values", "_bool", "_get_string", "_pack_floats",
                   "_pack_into", "_put", "_put_string", "_take", "_unpack_from")),
    ("xrce.msgs._seq", ("_bad_len", "_count", "_get_array", "_put_array", "_put_octets", "_seq_len")),
)


def _imports(package, body, deps):
    text = "\n".join(body)
    lines = []
    for module, names in RUNTIME_NAMES:
        used = [n for n in names if re.search(r"(?<![\w.])%s\b" % re.escape(n), text)]
        if not used:
            continue
        line = "from %s import %s" % (module, ", ".join(used))
        if len(line) <= 110:
            lines.append(line)
            continue
        lines.append("from %s import (" % module)
        current = "   "
        for name in used:
            piece = " %s," % name
            if len(current) + len(piece) > 100:
                lines.append(current)
                current = "   "
            current += piece
        lines.append(current)
        lines.append(")")
    # Full dotted imports only: MicroPython's "from package import _Module" asks the package's
    # __getattr__ first and does not fall back to importing the submodule when it raises.
    for base in sorted(deps):
        pkg, name = base.split("/")
        alias = _class_ref(base, package, set())
        lines.append("from xrce.msgs.%s.%s import %s%s" % (
            pkg, module_name(name), name, "" if alias == name else " as " + alias))
    return lines


def generate_message_module(spec, registry, command=SHIPPED_COMMAND):
    """Source of xrce/msgs/<package>/_<Type>.py: one message class and the imports it needs."""
    deps = set()
    body = []
    _gen_message(spec, registry, body, deps)
    head = ["# Generated by xrce/msggen.py (%s) from %s. Do not edit." % (command, spec.ros_type)]
    return "\n".join(head + _imports(spec.package, body, deps) + body) + "\n"


def generate_service_module(srv, class_name, registry, command=SHIPPED_COMMAND):
    """Source of xrce/msgs/<package>/_<Service>.py: request, response and their descriptor."""
    deps = set()
    body = []
    _gen_message(srv.request, registry, body, deps)
    _gen_message(srv.response, registry, body, deps)
    _gen_service(srv, body, class_name)
    head = ["# Generated by xrce/msggen.py (%s) from %s/srv/%s. Do not edit." % (command, srv.package, srv.name)]
    return "\n".join(head + _imports(srv.package, body, deps) + body) + "\n"


def generate_package_init(package, service_classes, command=SHIPPED_COMMAND):
    """Source of xrce/msgs/<package>/__init__.py: resolves type names to their modules on first use."""
    lines = [
        "# Generated by xrce/msggen.py (%s) from the %s interface definitions. Do not edit." % (command, package),
        "# Every type has its own module (_<Type>.py, _<Service>.py), imported the first time its name is",
        "# looked up here, so a board holds only the types it uses. SERVICES maps services to descriptors.",
        "from xrce.msgs import _type_attr",
        "",
        "# Service descriptor classes; Name_Request/Name_Response live in the same module.",
        "_SERVICE_CLASSES = (%s)" % "".join("%r, " % name for name in service_classes),
        "",
        "",
        "def __getattr__(name):",
        "    return _type_attr(globals(), name)",
    ]
    return "\n".join(lines) + "\n"


def generate_package(package, messages, services, registry, command=SHIPPED_COMMAND):
    """{file name inside xrce/msgs/<package>/: source text} for one ROS package."""
    message_names = set(m.name for m in messages)
    files = {}
    for spec in messages:
        files[module_name(spec.name) + ".py"] = generate_message_module(spec, registry, command)
    service_classes = []
    for srv in services:
        class_name = service_class_name(srv, message_names)
        service_classes.append(class_name)
        files[module_name(class_name) + ".py"] = generate_service_module(srv, class_name, registry, command)
    files["__init__.py"] = generate_package_init(package, service_classes, command)
    return files


GENERATED_MARK = "# Generated by xrce/msggen.py"


def _is_generated(path):
    try:
        with open(path) as f:
            return f.readline().startswith(GENERATED_MARK)
    except OSError:
        return False


def write_package(outdir, package, files):
    """Write one package directory; generated modules that are no longer produced (a removed type,
    or the old one-file-per-package layout) are deleted so they cannot be imported by mistake."""
    pkg_dir = os.path.join(outdir, package)
    os.makedirs(pkg_dir, exist_ok=True)
    old_layout = os.path.join(outdir, package + ".py")
    if _is_generated(old_layout):
        os.remove(old_layout)
    for name in sorted(os.listdir(pkg_dir)):
        path = os.path.join(pkg_dir, name)
        if name.endswith(".py") and name not in files and _is_generated(path):
            os.remove(path)
    for name in sorted(files):
        with open(os.path.join(pkg_dir, name), "w") as f:
            f.write(files[name])


def build_registry(packages):
    registry = {}
    for package, messages, services in packages:
        for m in messages:
            registry["%s/%s" % (package, m.name)] = m
    return registry


def check_references(packages):
    """Fail early on nested types that no given package defines."""
    known = set()
    for package, messages, services in packages:
        for m in messages:
            known.add("%s/%s" % (package, m.name))
    for package, messages, services in packages:
        specs = list(messages) + [s for srv in services for s in (srv.request, srv.response)]
        for spec in specs:
            for f in spec.fields:
                if f.type.is_nested and f.type.base not in known:
                    raise MsgGenError("%s: field %s uses %s, which no input package defines" % (
                        spec.ros_type, f.name, f.type.base))


def shipped_package_dirs():
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    share = os.path.join(sys.prefix, "share")
    dirs = [os.path.join(share, p) for p in SHIPPED_FROM_VENV]
    dirs += [os.path.join(repo, "xrce", "ros_interfaces", p) for p in SHIPPED_FROM_REPO]
    return dirs


def default_outdir():
    return os.path.join(os.path.dirname(os.path.abspath(__file__)), "msgs")


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m xrce.msggen", description=__doc__.splitlines()[0])
    parser.add_argument("packages", nargs="*", help="package directories holding msg/ and/or srv/")
    parser.add_argument("-o", "--outdir", default=None, help="where the <package>/ directories are written")
    parser.add_argument("--shipped", action="store_true",
                        help="regenerate the packages committed in xrce/msgs (venv share + interfaces/)")
    args = parser.parse_args(argv)
    dirs = list(args.packages)
    if args.shipped:
        dirs = shipped_package_dirs() + dirs
        command = SHIPPED_COMMAND
    else:
        command = "python -m xrce.msggen " + " ".join(os.path.basename(os.path.normpath(d)) for d in dirs)
    if not dirs:
        parser.error("give package directories or --shipped")
    outdir = args.outdir or default_outdir()
    try:
        packages = [load_package(d) for d in dirs]
        check_references(packages)
    except MsgGenError as e:
        print("msggen: %s" % e, file=sys.stderr)
        return 2
    os.makedirs(outdir, exist_ok=True)
    registry = build_registry(packages)
    for package, messages, services in packages:
        write_package(outdir, package, generate_package(package, messages, services, registry, command))
    return 0


if __name__ == "__main__":
    sys.exit(main())
