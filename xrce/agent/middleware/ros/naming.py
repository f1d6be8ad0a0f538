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
- else a global name (``/tf``, ``/tf_static``, ``/clock`` by default) stays as it is, as a ROS
  user expects of namespacing: one ``/tf`` tree for the whole fleet;
- else the name is put under the namespace.

A node's namespace is the agent's namespace followed by the one the board gave its participant
(``robot3`` + ``ns/node`` is node ``node`` in ``/robot3/ns``).

This module imports nothing of ROS: the command line parses ``--ros-args`` with it before rclpy
loads, so a bad remap is one line and exit 2 without ROS' start-up time.
"""

from __future__ import annotations

import re

GLOBAL_NAMES = ("/tf", "/tf_static", "/clock")

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
    return name if namespace == "/" else namespace + _absolute(name)


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
        self.global_names = frozenset(_absolute(_checked(n, "global name")) for n in global_names)
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
