"""``xrce-ros interface show`` with ros2interface's options and output: the definition file as
written, each nested message's definition below its field, indented by a tab per level.

ros2 finds the file through the ament index; a venv of PyPI wheels sets no AMENT_PREFIX_PATH, so
the file is looked for in the ``share/<package>`` beside the Python package rclpy imports for that
name (the wheels, an ``xrce-agent build-interfaces`` build, a sourced ROS: each installs both under
one prefix). Lines are read with ``rosidl_adapter``'s parser, as ros2interface reads them.
"""

from __future__ import annotations

import importlib.util
import os
import sys

from xrce.tools.ros_cli.arguments import CommandError, usage_exit

NAME = "interface"
HELP = "Show information about ROS interfaces"
SEPARATOR = "---"  # between request and response, goal, result and feedback


def add_verbs(verbs):
    parser = verbs.add_parser("show", help="Output the interface definition")
    comments = parser.add_mutually_exclusive_group()
    comments.add_argument("--all-comments", action="store_true",
                          help="Show all comments, including for nested interface definitions")
    comments.add_argument("--no-comments", action="store_true",
                          help="Show no comments or whitespace")
    parser.add_argument("type", help="Show an interface definition (e.g. "
                                     "'std_msgs/msg/String'); '-' reads it from stdin (e.g. "
                                     "'xrce-ros topic type /chatter | xrce-ros interface show -')")
    parser.set_defaults(run=show)


def interface_path(name):
    """The definition file of ``pkg/kind/Name``; ros2's sentences for a bad or unknown name."""
    parts = name.split("/")
    if len(parts) != 3:
        raise CommandError("Invalid name '%s'. Expected three parts separated by '/'" % name)
    if not all(parts) or ".." in parts:
        raise CommandError("Invalid name '%s'. Must not contain empty parts or '..'" % name)
    package, kind, leaf = parts
    try:
        spec = importlib.util.find_spec(package) if package.isidentifier() else None
    except (ImportError, ValueError):
        spec = None
    locations = list(spec.submodule_search_locations or ()) if spec is not None else []
    for location in locations:
        # <prefix>/lib/pythonX.Y/site-packages/<package>: the prefix is three levels up (a fourth
        # for /usr/local/lib/... beside data in /usr/share).
        for prefix in (os.path.dirname(location).rsplit(os.sep, up)[0] for up in (3, 4)):
            share = os.path.join(prefix, "share", package)
            if os.path.isdir(share):
                path = os.path.join(share, kind, leaf + "." + kind)
                if not os.path.isfile(path):  # ros2 then looks for an .idl and names that
                    raise CommandError("Could not find the interface '%s.idl'"
                                       % os.path.join(share, kind, leaf))
                return path
    from xrce.tools.ros_cli.messages import missing_type_reason

    raise CommandError("Unknown package '%s' (%s)" % (package, missing_type_reason(package, leaf)))


def _parsed(package, message, text):
    from rosidl_adapter.parser import parse_message_string

    if text == SEPARATOR:
        return None
    try:
        return parse_message_string(pkg_name=package, msg_name=message, message_string=text)
    except Exception as error:  # the file's own syntax error: name it, not a traceback
        raise CommandError("%s/%s: %s" % (package, message, error)) from None


def _shown_line(text, spec, with_comments):
    """The line as ros2interface shows it: as written with comments; without, None for a blank or
    comment-only line and the line up to its trailing comment otherwise."""
    if with_comments or spec is None:
        return text
    if not text or spec.annotations.get("comment"):
        return None
    entries = spec.fields or spec.constants
    comment = entries[0].annotations.get("comment") if entries else None
    if comment:
        text = text[:text.find(comment[0]) - 1].strip()
    return text


def _nested_type(spec):
    """``pkg/msg/Name`` of the line's field when it is a message (arrays of them too)."""
    if spec is None or not spec.fields:
        return None
    field_type = str(spec.fields[0].type)
    if "/" not in field_type:
        return None
    return field_type.split("[", 1)[0].replace("/", "/msg/")


def show_lines(name, with_comments=True, nested_comments=False, depth=0):
    """The lines ``ros2 interface show`` prints for ``name``."""
    path = interface_path(name)
    package, _, leaf = name.split("/")
    with open(path) as definition:
        texts = [line.rstrip() for line in definition]
    lines = []
    for text in texts:
        spec = _parsed(package, leaf, text)
        shown = _shown_line(text, spec, with_comments)
        if shown is not None:
            lines.append("\t" * depth + shown if shown else "")
        nested = _nested_type(spec)
        if nested is not None:
            lines += show_lines(nested, nested_comments, nested_comments, depth + 1)
    return lines


def show(args):
    name = args.type
    if name == "-":
        if sys.stdin.isatty():
            usage_exit("expected stdin pipe")
        name = sys.stdin.readline().strip()
    if not name:
        usage_exit("the passed value is empty")
    try:
        import rosidl_adapter.parser  # noqa: F401
    except ImportError:
        raise CommandError("rosidl_adapter is not installed: it reads interface files "
                           "(ros-jazzy-rosidl-adapter)") from None
    print("\n".join(show_lines(name, not args.no_comments, args.all_comments)))
