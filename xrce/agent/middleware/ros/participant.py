"""A ROS domain's DDS participant made with the GIL released (``-m dds``).

rmw_fastrtps makes a context's DDS participant with the context's first node, and rclpy holds the
GIL throughout that call: measured on the loaded 2-core machine, 6-8 ms in which the loop's thread
did not run once, so every client of the agent waited while one joined another domain (and 8-19 ms
at load average 5). Here the executor thread makes that first node as an rmw node through the
agent's compiled helper (``_rostypes.participant_node``), which releases the GIL for the call: the
participant is made then (3-4 ms, the loop running meanwhile), the rclpy node made next only joins
it (0.4-0.6 ms), and the rmw node is destroyed right after (``DomainRuntime.make_node``).

The compiled helper rather than ctypes: a serving agent imports no ctypes (its classes stay
resident, tests/agent/test_agent_footprint.py), and importing it took 11 ms on the loaded machine, more
than the call saves. The helper's three-argument ``rmw_create_node(context, name, namespace)`` is
Humble's and later; ``rclpy.experimental`` (the EventsExecutor) is Jazzy's and later. Without the
helper the first rclpy node makes the participant as before, GIL held.
"""

from __future__ import annotations

import logging

from xrce.agent.middleware.ros import compiled

log = logging.getLogger("xrce.agent.ros")  # the ROS bridge's one name (domain.log)

# The rmw node's name: hidden (rclpy.node.HIDDEN_NODE_PREFIX), the agent's (AGENT_NODE_NAME).
_NAME = "_xrce_agent"
_helper = None  # the compiled helper once looked up, False where it cannot serve


def _load():
    global _helper
    if _helper is None:
        try:
            import rclpy.experimental  # noqa: F401  Jazzy or later (module docstring)
        except ImportError as exc:
            log.debug("DDS participants are made with the GIL held: %s", exc)
            _helper = False
        else:
            _helper = compiled.helper() or False
            if not _helper:
                log.debug("DDS participants are made with the GIL held: compiled helper %s",
                          compiled.missing)
    return _helper or None


def available() -> bool:
    return _load() is not None


def open_participant(context) -> int | None:
    """Executor thread, before ``context``'s first node: make its DDS participant with a
    placeholder rmw node, the GIL released; the node's address for ``close_participant``, or None
    (no helper, or rmw refused: the first rclpy node then tries and reports why)."""
    helper = _load()
    if helper is None:
        return None
    return helper.participant_node(context.handle.pointer, _NAME)


def close_participant(node: int) -> None:
    """Executor thread: the placeholder goes; the participant stays with the context's rclpy node
    (or goes with the placeholder if that node failed)."""
    helper = _load()
    if helper is not None and not helper.participant_node_destroy(node):
        log.warning("could not destroy the rmw node that made a DDS participant")
