"""Generate MicroPython-safe XCDR1 message classes from ROS 2 .msg/.srv files (CPython-only tool).

Each ROS package becomes a Python package in the output directory (normally ``xrce/msgs``) with
one module per message type and per service (``geometry_msgs/_Twist.py``) and an ``__init__.py``
that imports a type's module the first time its name is looked up: importing a whole package's
classes costs tens of KB of MicroPython heap, and a board usually needs two or three types.
A generated module holds no code: each class is a table (field names and specs, defaults,
constants) given to ``xrce.msgs._define``, and one shared runtime encodes and decodes every type
(per-type methods would cost a board heap for every type it loads).

The definitions are parsed by xrce.tools.msg_parser; this module turns the specs into code.

    python -m xrce.tools.msggen PKG_DIR [PKG_DIR ...] -o OUTDIR
    python -m xrce.tools.msggen --shipped [-o OUTDIR]      # the set committed in xrce/msgs
"""

import argparse
import os
import re
import sys

from xrce.tools.msg_parser import PRIMITIVES, MsgGenError, load_actions, load_package

# unique_identifier_msgs, action_msgs and rcl_interfaces: what a board's action server/client and
# parameter server (xrce.client.actions, xrce.client.parameters) speak; test_msgs for its Fibonacci
# action, the one rclc's examples and the micro-ROS capture use.
SHIPPED_FROM_VENV = ("builtin_interfaces", "std_msgs", "geometry_msgs", "sensor_msgs", "nav_msgs",
                     "unique_identifier_msgs", "action_msgs", "rcl_interfaces")
# Packages of which only these types are generated (test_msgs is a test fixture package: the rest of it
# would be dead weight in the wheel).
SHIPPED_ONLY = {"test_msgs": ("Fibonacci",)}
SHIPPED_FROM_REPO = ("tf2_msgs", "turtlebot3_msgs")
SHIPPED_COMMAND = "python -m xrce.tools.msggen --shipped"


# ---------------------------------------------------------------------------------------------
# Code generation


def _class_ref(base, package, deps):
    """The expression generated code uses for a nested type; recorded in ``deps`` so the module
    imports it. Types of other packages are named through their package (two packages may both
    define e.g. Point), which adds no name a board has not interned already: an alias such as
    ``_std_msgs_Header`` would stay in its string pool for good (~30 bytes each)."""
    deps.add(base)
    pkg, name = base.split("/")
    if pkg == package:
        return name
    return "%s.%s" % (pkg, name)


def _item_spec(ftype, package, deps):
    """The spec of one value of ``ftype`` (ignoring its array part); see xrce/msgs/__init__.py."""
    if ftype.is_nested:
        return _class_ref(ftype.base, package, deps)
    if ftype.is_string:
        return '"s"' if ftype.string_bound is None else '("s", %d)' % ftype.string_bound
    code, _, kind = PRIMITIVES[ftype.base]
    return '"?"' if kind == "bool" else '"%s"' % code


def _field_spec(ftype, package, deps):
    item = _item_spec(ftype, package, deps)
    if ftype.array is None:
        return item
    if ftype.array == "fixed":
        return '("F", %d, %s)' % (ftype.array_size, item)
    return '("S", %r, %s)' % (ftype.array_size, item)


def _default_value(field):
    """The Python literal of a field's default from the .msg file (None when it has none)."""
    ft = field.type
    d = field.default
    if d is None:
        return None
    kind = PRIMITIVES[ft.base][2] if ft.is_primitive else "string"
    if ft.array is None:
        return repr(float(d)) if kind == "float" else repr(d)
    if kind == "octet":
        return repr(bytes(d))
    if kind == "float":
        d = [float(v) for v in d]
    return repr(list(d))


def _gen_message(spec, registry, out, deps):
    """``Name = _define(ros type, field names, field specs, defaults, constants=True)``: a table
    that the shared runtime in xrce/msgs/__init__.py interprets (no per-type code: on a board every
    generated function costs heap). The type's constants go to a module of their own
    (generate_constants_module)."""
    package = spec.package
    fields = spec.fields
    specs = [_field_spec(f.type, package, deps) for f in fields]
    if all(len(s) == 3 and s[0] == '"' for s in specs):
        spec_text = '"%s"' % "".join(s[1] for s in specs)
    else:
        spec_text = "(%s)" % "".join("%s, " % s for s in specs)
    defaults = [(f.name, _default_value(f)) for f in fields if f.default is not None]
    args = ["%r" % spec.ros_type, "(%s)" % "".join("%r, " % f.name for f in fields), spec_text]
    if defaults:
        args.append("{%s}" % ", ".join("%r: %s" % item for item in defaults))
    if spec.constants:
        args.append("constants=True")
    out.append("")
    out.append("%s = _define(" % spec.name)
    for arg in args:
        out.append("    %s," % arg)
    out.append(")")


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


# What generated modules take from the shared runtime (xrce/msgs/__init__.py), by module.
RUNTIME_NAMES = (
    ("xrce.msgs", ("_define",)),
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
    # Through the package, whose __getattr__ defines a type once and keeps the class: a board drops
    # a message module once its class is kept (xrce.msgs._type_attr), so importing the module by its
    # own name again would define the type a second time.
    for base in sorted(deps):
        pkg, name = base.split("/")
        if pkg == package:
            lines.append("from xrce.msgs.%s import %s" % (pkg, name))
    other = sorted(set(base.split("/")[0] for base in deps) - {package})
    if other:
        lines.append("from xrce.msgs import %s" % ", ".join(other))
    return lines


def generate_message_module(spec, registry, command=SHIPPED_COMMAND):
    """Source of xrce/msgs/<package>/_<Type>.py: one message class and the imports it needs."""
    deps = set()
    body = []
    _gen_message(spec, registry, body, deps)
    head = ["# Generated by xrce/tools/msggen.py (%s) from %s. Do not edit." % (command, spec.ros_type)]
    return "\n".join(head + _imports(spec.package, body, deps) + body) + "\n"


def constants_module_name(spec):
    """Module of a type's CONSTANT=value definitions: ``_BatteryState_constants``, or
    ``_LoadMap_Response_constants`` for a service's request or response."""
    return module_name(spec.ros_type.rsplit("/", 1)[1]) + "_constants"


def generate_constants_module(spec, command=SHIPPED_COMMAND):
    """Source of xrce/msgs/<package>/_<Type>_constants.py. Not in the type's module: a board interns
    every name a module it loads holds, and keeps them (sensor_msgs/BatteryState's 23 names are 1 KB),
    so it loads these only through xrce.msgs.constants.load_constants; CPython sets them on every class."""
    lines = ["# Generated by xrce/tools/msggen.py (%s) from %s. Do not edit." % (command, spec.ros_type),
             "# The constants of %s: set on the class by xrce.msgs.constants.load_constants." % spec.name]
    for c in spec.constants:
        value = float(c.value) if c.type.base in ("float32", "float64") else c.value
        lines.append("%s = %r" % (c.name, value))
    return "\n".join(lines) + "\n"


def generate_service_module(srv, class_name, registry, command=SHIPPED_COMMAND):
    """Source of xrce/msgs/<package>/_<Service>.py: request, response and their descriptor."""
    deps = set()
    body = []
    _gen_message(srv.request, registry, body, deps)
    _gen_message(srv.response, registry, body, deps)
    _gen_service(srv, body, class_name)
    head = ["# Generated by xrce/tools/msggen.py (%s) from %s/srv/%s. Do not edit." % (command, srv.package, srv.name)]
    return "\n".join(head + _imports(srv.package, body, deps) + body) + "\n"


def _gen_descriptor(out, class_name, attributes):
    out.append("")
    out.append("")
    out.append("class %s:" % class_name)
    for name, value in attributes:
        out.append("    %s = %s" % (name, value))


def generate_action_module(action, class_name, registry, command=SHIPPED_COMMAND):
    """Source of xrce/msgs/<package>/_<Action>.py: the action's eight message types (Goal, Result,
    Feedback, the SendGoal and GetResult requests and responses, FeedbackMessage), a descriptor for
    each of its two services and the action's descriptor, which names them all."""
    deps = set()
    body = []
    for spec in action.messages:
        _gen_message(spec, registry, body, deps)
    for srv in (action.send_goal, action.get_result):
        _gen_descriptor(body, srv.name, (
            ("Request", srv.request.name), ("Response", srv.response.name),
            ("TYPE_NAME_REQUEST", repr(srv.request.dds_name)),
            ("TYPE_NAME_RESPONSE", repr(srv.response.dds_name)), ("ROS_TYPE", repr(srv.ros_type))))
    _gen_descriptor(body, class_name, (
        ("Goal", action.goal.name), ("Result", action.result.name), ("Feedback", action.feedback.name),
        ("FeedbackMessage", action.feedback_message.name), ("SendGoal", action.send_goal.name),
        ("GetResult", action.get_result.name),
        ("ROS_TYPE", repr("%s/action/%s" % (action.package, action.name)))))
    deps -= set(spec.ros_base for spec in action.messages)  # defined in this very module
    head = ["# Generated by xrce/tools/msggen.py (%s) from %s/action/%s. Do not edit." % (
        command, action.package, action.name)]
    return "\n".join(head + _imports(action.package, body, deps) + body) + "\n"


def generate_package_init(package, service_classes, command=SHIPPED_COMMAND, action_classes=()):
    """Source of xrce/msgs/<package>/__init__.py: resolves type names to their modules on first use."""
    lines = [
        "# Generated by xrce/tools/msggen.py (%s) from the %s interface definitions. Do not edit." % (command, package),
        "# Every type has its own module (_<Type>.py, _<Service>.py), imported the first time its name is",
        "# looked up here, so a board holds only the types it uses. SERVICES maps services to descriptors.",
        "from xrce.msgs import _type_attr",
        "",
        "# Service descriptor classes; Name_Request/Name_Response live in the same module.",
    ]
    if action_classes:
        # Action descriptors join them: their modules (the action's every type) stay loaded on a
        # board in the same way, with no code of its own in the runtime every board loads.
        lines.append("# And action descriptor classes, whose modules hold every type of the action.")
    lines += [
        "_SERVICE_CLASSES = (%s)" % "".join("%r, " % name for name in list(service_classes) + list(action_classes)),
        "",
        "",
        "def __getattr__(name):",
        "    return _type_attr(globals(), name)",
    ]
    return "\n".join(lines) + "\n"


def action_class_name(action, message_names, service_classes):
    """Like service_class_name: an "_Action" suffix when a message or service has the name."""
    if action.name in message_names or action.name in service_classes:
        return action.name + "_Action"
    return action.name


def package_class_names(messages, services, actions=()):
    """The names a board imports from the generated package: its messages, then the service and
    action descriptors (each service's Name_Request/Name_Response come with its descriptor)."""
    message_names = set(m.name for m in messages)
    service_classes = [service_class_name(srv, message_names) for srv in services]
    action_classes = [action_class_name(a, message_names, service_classes) for a in actions]
    return [m.name for m in messages] + service_classes + action_classes


def generate_package(package, messages, services, registry, command=SHIPPED_COMMAND, actions=()):
    """{file name inside xrce/msgs/<package>/: source text} for one ROS package."""
    message_names = set(m.name for m in messages)
    action_classes = []
    files = {}
    for spec in messages:
        files[module_name(spec.name) + ".py"] = generate_message_module(spec, registry, command)
    service_classes = []
    for srv in services:
        class_name = service_class_name(srv, message_names)
        service_classes.append(class_name)
        files[module_name(class_name) + ".py"] = generate_service_module(srv, class_name, registry, command)
    for action in actions:
        class_name = action_class_name(action, message_names, service_classes)
        action_classes.append(class_name)
        files[module_name(class_name) + ".py"] = generate_action_module(action, class_name, registry, command)
    action_specs = [s for action in actions for s in (action.goal, action.result, action.feedback)]
    for spec in list(messages) + [s for srv in services for s in (srv.request, srv.response)] + action_specs:
        if spec.constants:
            files[constants_module_name(spec) + ".py"] = generate_constants_module(spec, command)
    files["__init__.py"] = generate_package_init(package, service_classes, command, action_classes)
    return files


GENERATED_MARK = "# Generated by xrce/tools/msggen.py"


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


def _all_messages(messages, actions):
    return list(messages) + [spec for action in actions for spec in action.messages]


def build_registry(packages, actions=None):
    registry = {}
    for package, messages, services in packages:
        for m in _all_messages(messages, (actions or {}).get(package, ())):
            registry["%s/%s" % (package, m.name)] = m
    return registry


def _generated_already(base, outdir):
    """Whether ``pkg/Name`` is a message module generated in ``outdir`` before (an action's
    unique_identifier_msgs/UUID when only the action's own package is given)."""
    if outdir is None:
        return False
    pkg, name = base.split("/")
    return _is_generated(os.path.join(outdir, pkg, module_name(name) + ".py"))


def check_references(packages, actions=None, outdir=None):
    """Fail early on nested types that no given package (or none generated in ``outdir``) defines."""
    actions = actions or {}
    known = set()
    for package, messages, services in packages:
        for m in _all_messages(messages, actions.get(package, ())):
            known.add("%s/%s" % (package, m.name))
    for package, messages, services in packages:
        specs = _all_messages(messages, actions.get(package, ()))
        specs += [s for srv in services for s in (srv.request, srv.response)]
        for spec in specs:
            for f in spec.fields:
                if f.type.is_nested and f.type.base not in known and not _generated_already(f.type.base, outdir):
                    raise MsgGenError("%s: field %s uses %s, which no input package defines" % (
                        spec.where or spec.ros_type, f.name, f.type.base))


def shipped_package_dirs():
    # This file is xrce/tools/msggen.py: the repository is three folders up.
    repo = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    share = os.path.join(sys.prefix, "share")
    dirs = [os.path.join(share, p) for p in SHIPPED_FROM_VENV]
    dirs += [os.path.join(repo, "xrce", "ros_interfaces", p) for p in SHIPPED_FROM_REPO]
    return dirs


def _load(pkg_dir, shipped):
    name = os.path.basename(os.path.normpath(pkg_dir))
    if shipped and name in SHIPPED_ONLY:
        return name, [], []  # not even parsed: test_msgs has types this generator refuses (wstring)
    return load_package(pkg_dir)


def _only_shipped_actions(package, actions, shipped):
    if shipped and package in SHIPPED_ONLY:
        return [a for a in actions if a.name in SHIPPED_ONLY[package]]
    return actions


def shipped_partial_dirs():
    """The packages of SHIPPED_ONLY, of which only the named actions are generated."""
    return [os.path.join(sys.prefix, "share", p) for p in SHIPPED_ONLY]


def default_outdir():
    return os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "msgs")


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m xrce.tools.msggen", description=__doc__.splitlines()[0])
    parser.add_argument("packages", nargs="*", help="package directories holding msg/ and/or srv/")
    parser.add_argument("-o", "--outdir", default=None, help="where the <package>/ directories are written")
    parser.add_argument("--shipped", action="store_true",
                        help="regenerate the packages committed in xrce/msgs (venv share + interfaces/)")
    args = parser.parse_args(argv)
    dirs = list(args.packages)
    if args.shipped:
        dirs = shipped_package_dirs() + shipped_partial_dirs() + dirs
        command = SHIPPED_COMMAND
    else:
        command = "python -m xrce.tools.msggen " + " ".join(os.path.basename(os.path.normpath(d)) for d in dirs)
    if not dirs:
        parser.error("give package directories or --shipped")
    outdir = args.outdir or default_outdir()
    try:
        packages = [_load(d, args.shipped) for d in dirs]
        actions = dict((package, _only_shipped_actions(package, load_actions(d), args.shipped))
                       for (package, _, _), d in zip(packages, dirs))
        check_references(packages, actions, default_outdir())
    except MsgGenError as e:
        print("msggen: %s" % e, file=sys.stderr)
        return 2
    os.makedirs(outdir, exist_ok=True)
    registry = build_registry(packages, actions)
    for package, messages, services in packages:
        write_package(outdir, package, generate_package(package, messages, services, registry, command,
                                                        actions[package]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
