"""The names and the domain the agent gives a board's ROS entities (issue 53, "per agent").

One firmware image in every robot of a fleet names everything the same (``/cmd_vel``, node
``/turtlebot3_node``); the agent, not the board, then tells the robots apart, in the words a ROS
user already knows: ``xrce-agent udp4 -p 8888 --ros-args -r __ns:=/robot3 -r cmd_vel:=cmd_vel_safe``
and ``--domain N``. Names are decided here once, when an entity is created, never per sample.

What a board's name becomes (``Naming.name``), for ROS topics (``rt/``) and services (``rq/``,
``rr/``); a plain-DDS topic (no ROS prefix, ``xrce.agent.middleware.dds`` and the DDS-level topics
of ``types.dds_topic_to_ros``) keeps its name unless a remap names it (``dds_name``):

- a remap ``FROM:=TO`` whose FROM is the board's name (with or without its leading slash: the
  board's names are relative to the namespace it was given, as a ROS node's relative names are)
  gives TO; a relative TO is put under the namespace, an absolute one is taken as it is;
- else a global name (``/tf``, ``/tf_static``, ``/clock`` by default; ``/parameter_events`` and
  ``/rosout`` always, as rcl has them) stays as it is, as a ROS user expects of namespacing: one
  ``/tf`` tree for the whole fleet;
- else the name is put under the namespace.

A node's namespace is the agent's namespace followed by the one the board gave its participant
(``robot3`` + ``ns/node`` is node ``node`` in ``/robot3/ns``).

The way back (issue 53, "round trip"): a board reads names too (its graph queries, the
``node`` of a ParameterEvent), and unmodified firmware must find its own names there.
``Naming.board_name`` is the inverse of ``name`` (a remap's target gives its source, a name under
the namespace loses it, a global name stays), ``board_node_namespace`` of ``node_namespace`` and
``board_node`` of ``ros_node``; a ROS name no board name becomes (another robot's
``/robot2/cmd_vel``, the original of a remapped name) comes back as it is, absolute. Where they are
used: ``xrce.agent.middleware.ros.roundtrip``.

This module imports nothing of ROS: the command line parses ``--ros-args`` with it before rclpy
loads, so a bad remap is one line and exit 2 without ROS' start-up time.
"""

from __future__ import annotations

import re

# /parameter_events and /rosout are absolute in rcl itself: every node of a domain shares them,
# whatever its namespace, and ``ros2 param``/``ros2 topic echo /rosout`` look for them there; so
# they stay global whatever ``global_names`` (--global-topics) says; a remap still moves them.
RCL_GLOBAL_NAMES = ("/parameter_events", "/rosout")
GLOBAL_NAMES = ("/tf", "/tf_static", "/clock") + RCL_GLOBAL_NAMES

ACTION_PART = "/_action/"  # an action's hidden topics and services: /NAME/_action/...
_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
_NAME = re.compile(r"^/?%s(/%s)*$" % (_TOKEN, _TOKEN))


class NamingError(ValueError):
    """A bad ``--ros-args`` remap, namespace or domain: one line on the command line."""


def _checked(name: str, what: str) -> str:
    if not _NAME.match(name):
        raise NamingError("%s %r is not a valid ROS name" % (what, name))
    return name


def _absolute(name: str) -> str:
    return name if name.startswith("/") else "/" + name


def _join(namespace: str, name: str) -> str:
    # Absolute in the root namespace too: rclpy would put a relative remap target under the
    # board node's own namespace.
    return _absolute(name) if namespace == "/" else namespace + _absolute(name)


class Naming:
    """The agent's namespace, remaps and global names; ``domain``: the ROS domain every
    participant is put in whatever the board asks for (None: the board's own)."""

    def __init__(self, namespace: str = "/", remaps=(), global_names=GLOBAL_NAMES,
                 domain: int | None = None):
        if namespace != "/":
            if not namespace.startswith("/"):
                raise NamingError("namespace %r is not absolute" % (namespace,))
            _checked(namespace, "namespace")
        self.namespace = namespace.rstrip("/") or "/"
        self.remaps = {}
        for source, target in remaps:
            self.remaps[_absolute(_checked(source, "remap source"))] = _checked(target, "remap target")
        self.global_names = frozenset(_absolute(_checked(n, "global name")) for n in global_names) \
            | frozenset(RCL_GLOBAL_NAMES)
        self.domain = domain

    @property
    def changes_names(self) -> bool:
        return self.namespace != "/" or bool(self.remaps)

    def describe(self) -> str:
        """The banner's words for what is given to boards."""
        parts = []
        if self.namespace != "/":
            parts.append("namespace %s" % self.namespace)
        parts.extend("%s -> %s" % (s, self.name(s)) for s in self.remaps)
        if self.domain is not None:
            parts.append("domain %d" % self.domain)
        return ", ".join(parts)

    def name(self, board_name: str) -> str:
        """The ROS name given to the board's fully qualified ROS name ``board_name``."""
        target = self.remaps.get(board_name)
        if target is not None:
            return target if target.startswith("/") else _join(self.namespace, target)
        action, hidden, rest = board_name.partition(ACTION_PART)
        if hidden and action in self.remaps:
            # rcl remaps an action by its name: its hidden topics and services go with it.
            return self.name(action) + ACTION_PART + rest
        if board_name in self.global_names:
            return board_name
        return _join(self.namespace, board_name)

    def dds_name(self, dds_topic: str) -> str:
        """The name given to a plain-DDS topic (no ROS prefix, ``types.dds_topic_to_ros`` kind
        "dds"): only a remap whose FROM names it moves it, to TO without a leading slash (a DDS
        topic has none; a namespace is a ROS idea, so it is not applied). ``dds_topic`` may carry
        rclpy's leading slash; the answer keeps its form."""
        target = self.remaps.get(_absolute(dds_topic))
        if target is None:
            return dds_topic
        bare = target.lstrip("/")
        return "/" + bare if dds_topic.startswith("/") else bare

    def node_namespace(self, board_namespace: str) -> str:
        return board_namespace if self.namespace == "/" else \
            _join(self.namespace, board_namespace).rstrip("/")

    def domain_id(self, board_domain: int) -> int:
        return board_domain if self.domain is None else self.domain

    def ros_node(self, board_node: str) -> str:
        """The fully qualified ROS name of the node the board calls ``board_node`` (``/ns/node``)."""
        namespace, _, node = board_node.rpartition("/")
        return self.node_namespace(namespace or "/").rstrip("/") + "/" + node

    # -- the way back (module docstring) ------------------------------------------------------

    @property
    def moves_nodes(self) -> bool:
        """Whether node names differ from the board's: a namespace (remaps name topics only)."""
        return self.namespace != "/"

    def board_name(self, ros_name: str) -> str:
        """The board's fully qualified name that ``name`` makes ``ros_name``; ``ros_name`` itself
        (absolute) when no board name becomes it."""
        for source in self.remaps:
            given = self.name(source)
            if given == ros_name:
                return source
            if ros_name.startswith(given + ACTION_PART) and \
                    self.name(source + ros_name[len(given):]) == ros_name:
                return source + ros_name[len(given):]
        if ros_name in self.global_names:
            return ros_name
        if self.namespace != "/" and ros_name.startswith(self.namespace + "/"):
            candidate = ros_name[len(self.namespace):]
            if self.name(candidate) == ros_name:
                return candidate
        return _absolute(ros_name)

    def board_node_namespace(self, ros_namespace: str) -> str:
        """The namespace the board gave a node ``node_namespace`` put in ``ros_namespace``; a
        namespace outside the agent's comes back as it is."""
        if self.namespace == "/":
            return ros_namespace
        if ros_namespace.rstrip("/") == self.namespace:
            return "/"
        if ros_namespace.startswith(self.namespace + "/"):
            return ros_namespace[len(self.namespace):]
        return ros_namespace

    def board_node(self, ros_node: str) -> str:
        """The board's fully qualified node name of the ROS node ``ros_node``."""
        namespace, _, node = ros_node.rpartition("/")
        return self.board_node_namespace(namespace or "/").rstrip("/") + "/" + node


def parse_ros_args(tokens) -> tuple[str | None, list]:
    """(namespace or None, [(FROM, TO)]) of the tokens of one ``--ros-args`` block.

    Only remaps (``-r``/``--remap``) mean something to the agent; anything else ROS accepts there
    (``-p``, ``--log-level``...) would be silently ignored, so it is refused instead."""
    namespace, remaps = None, []
    tokens = list(tokens)
    i = 0
    while i < len(tokens):
        flag = tokens[i]
        if flag in ("-r", "--remap"):
            if i + 1 >= len(tokens):
                raise NamingError("--ros-args %s needs FROM:=TO" % flag)
            rule = tokens[i + 1]
            i += 2
        elif flag.startswith("--remap="):
            rule = flag[len("--remap="):]
            i += 1
        else:
            raise NamingError("--ros-args: only -r/--remap FROM:=TO is supported here, not %r" % flag)
        source, sep, target = rule.partition(":=")
        if not sep or not source or not target:
            raise NamingError("--ros-args remap %r is not FROM:=TO" % rule)
        if source.startswith("__"):
            if source != "__ns":
                raise NamingError("--ros-args remap %r: only __ns:= of the special names is "
                                  "supported" % rule)
            if not target.startswith("/"):
                # rcl refuses it the same way ("not remapped to a fully qualified name").
                raise NamingError("--ros-args __ns:=%s: the namespace must be absolute (/%s)"
                                  % (target, target))
            namespace = target
        else:
            if ":" in source:
                raise NamingError("--ros-args remap %r: node-specific remaps (node:FROM:=TO) "
                                  "are not supported" % rule)
            remaps.append((_checked(source, "remap source"), _checked(target, "remap target")))
    return namespace, remaps


def split_ros_args(argv) -> tuple[list, list | None]:
    """``argv`` without its ``--ros-args ... [--]`` blocks, and those blocks' tokens (None when
    there was none): the agent's own ``-r`` (``--refs``) means something else outside them."""
    rest, ros, inside = [], None, False
    for token in argv:
        if inside:
            if token == "--":
                inside = False
            elif token == "--ros-args":
                continue
            else:
                ros.append(token)
        elif token == "--ros-args":
            inside = True
            ros = [] if ros is None else ros
        else:
            rest.append(token)
    return rest, ros
