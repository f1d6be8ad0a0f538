"""The node every ``xrce-ros`` verb runs on: its own rclpy context, a hidden node (the leading
underscore keeps it out of ``node list``, as ros2cli's ``_ros2cli_<pid>``), an executor the verb
spins in short steps so that Ctrl-C is seen between them, and the graph queries with ros2cli's
filters for hidden names."""

from __future__ import annotations

import os
import time

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import HIDDEN_NODE_PREFIX, Node
from rclpy.signals import SignalHandlerOptions
from rclpy.topic_or_service_is_hidden import topic_or_service_is_hidden

NODE_NAME_PREFIX = HIDDEN_NODE_PREFIX + "xrce_ros"
SPIN_STEP_S = 0.1  # the longest Ctrl-C waits for
# ros2cli without its daemon answers from what 0.5 s of discovery found; on a busy machine that is
# often nothing, or a node without its topics yet (Fast DDS matches participants first, their
# endpoints after). Past --spin-time the wait goes on while the graph still changes, or while it
# holds no node but this one, until it has been quiet this long, and this much longer at most.
GRAPH_QUIET_S = 0.3
GRAPH_SETTLE_MAX_S = 2.0


class CliNode:
    """``with CliNode(spin_time=0.5) as cli: cli.node ...`` — joined to the graph and, after
    ``spin_time`` seconds of discovery (ros2cli's DirectNode waits the same), ready to query it."""

    def __init__(self, name=None, spin_time=0.0):
        self.context = Context()
        # Python's own SIGINT handling (KeyboardInterrupt between spin steps) rather than rclpy's,
        # which would shut the context down under a verb that is still printing.
        rclpy.init(args=[], context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        try:
            self.node = Node(name or "%s_%d" % (NODE_NAME_PREFIX, os.getpid()),
                             context=self.context, start_parameter_services=False)
            self.executor = SingleThreadedExecutor(context=self.context)
            self.executor.add_node(self.node)
        except BaseException:
            self.context.try_shutdown()
            raise
        if spin_time:
            self.discover(spin_time)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        self.executor.remove_node(self.node)
        self.node.destroy_node()
        self.executor.shutdown(timeout_sec=1.0)
        self.context.try_shutdown()

    def discover(self, spin_time):
        """Spin ``spin_time`` seconds, then until the graph holds another node and has been quiet
        for GRAPH_QUIET_S (GRAPH_SETTLE_MAX_S more at most)."""
        self.spin_for(spin_time)
        last = self._graph_snapshot()
        quiet_since = time.monotonic()
        give_up = quiet_since + GRAPH_SETTLE_MAX_S
        while time.monotonic() < give_up:
            if len(last[0]) > 1 and time.monotonic() - quiet_since >= GRAPH_QUIET_S:
                return
            self.spin_once(0.05)
            now = self._graph_snapshot()
            if now != last:
                last, quiet_since = now, time.monotonic()

    def _graph_snapshot(self):
        node = self.node
        return (sorted(node.get_node_names_and_namespaces()),
                sorted((n, tuple(t)) for n, t in node.get_topic_names_and_types()),
                sorted((n, tuple(t)) for n, t in node.get_service_names_and_types()))

    def spin_once(self, timeout_s=SPIN_STEP_S):
        self.executor.spin_once(timeout_sec=timeout_s)

    def spin_for(self, seconds):
        deadline = time.monotonic() + seconds
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return
            self.spin_once(min(left, SPIN_STEP_S))

    def spin_until(self, predicate, timeout_s=None):
        """Spin until ``predicate()`` is true (True) or ``timeout_s`` passed (False); no timeout
        waits as long as it takes, like ros2cli's waits."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while not predicate():
            if deadline is not None and time.monotonic() >= deadline:
                return False
            self.spin_once()
        return True

    def spin_until_done(self, future, timeout_s=None):
        return self.spin_until(future.done, timeout_s)

    # ------------------------------------------------------------------------- graph

    def topic_names_and_types(self, include_hidden=False):
        return [(name, types) for name, types in self.node.get_topic_names_and_types()
                if include_hidden or not topic_or_service_is_hidden(name)]

    def service_names_and_types(self, include_hidden=False):
        return [(name, types) for name, types in self.node.get_service_names_and_types()
                if include_hidden or not topic_or_service_is_hidden(name)]

    def node_full_names(self, include_hidden=False):
        """Full names of the nodes in the graph, this one excluded when hidden ones are not asked
        for (it is hidden itself); a node with an empty name is never listed, as in ros2cli."""
        names = []
        for name, namespace in self.node.get_node_names_and_namespaces():
            if include_hidden or (name and not name.startswith(HIDDEN_NODE_PREFIX)):
                names.append(namespace + ("" if namespace.endswith("/") else "/") + name)
        return names


def checked_name(name, is_service=False):
    """``name`` as rclpy expands it for a node in ``/``; a name rclpy refuses raises its
    NameValidationException (``cli`` makes that a one-line usage error) before any node uses it."""
    from rclpy.expand_topic_name import expand_topic_name
    from rclpy.validate_full_topic_name import validate_full_topic_name

    try:
        full_name = expand_topic_name(name, NODE_NAME_PREFIX, "/")
    except ValueError as error:  # what rclpy's expansion raises for a malformed name
        from rclpy.exceptions import InvalidTopicNameException

        raise InvalidTopicNameException(name, str(error), 0) from None
    validate_full_topic_name(full_name, is_service=is_service)
    return full_name


def is_hidden_name(name):
    """ros2node's test for a hidden topic, service or action of a node: any part of the name
    starts with the hidden prefix (``/patrol/_action/status``), not only the last one."""
    return any(part.startswith(HIDDEN_NODE_PREFIX) for part in name.split("/"))


def absolute_node_name(name):
    return name if name.startswith("/") else "/" + name


def split_node_name(full_name):
    """(name, namespace) of a node name as ros2node splits it (a leading / added)."""
    namespace, _, name = ("/" + full_name.lstrip("/")).rpartition("/")
    return name, namespace or "/"
