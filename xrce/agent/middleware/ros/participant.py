"""A ROS domain's DDS participant made with the GIL released (``-m dds``).

rmw_fastrtps makes a context's DDS participant with the context's first node, and rclpy holds the
GIL throughout that call: measured on the loaded 2-core machine, 6-8 ms in which the loop's thread
did not run once, so every client of the agent waited while one joined another domain (and 8-19 ms
at load average 5). Here the executor thread makes that first node as an rmw node through ctypes,
which releases the GIL for the call: the participant is made then (3-4 ms, the loop running
meanwhile), the rclpy node made next only joins it (0.4-0.6 ms), and the rmw node is destroyed
right after (``DomainRuntime.make_node``).

Only for domains joined while clients are served: the agent's own domain is joined at start, before
anyone is served, and a serving agent imports no ctypes (tests/test_agent_footprint.py); a domain
joined later costs a DDS participant, beside which ctypes is little. ctypes rather than the
compiled helper (xrce/agent/engine/_fastpath.c): three C calls into libraries rclpy has loaded
already, with no headers or build step of ROS's. The three-argument
``rmw_create_node(context, name, namespace)`` is Humble's and later; ``rclpy.experimental`` (the
EventsExecutor) is Jazzy's and later. Where anything is missing the first rclpy node makes the
participant as before, GIL held.
"""

from __future__ import annotations

import logging

log = logging.getLogger("xrce.agent.ros")  # the ROS bridge's one name (domain.log)

# The rmw node's name: hidden (rclpy.node.HIDDEN_NODE_PREFIX), the agent's (AGENT_NODE_NAME).
_NAME = b"_xrce_agent"
_functions = None  # (rcl_context_get_rmw_context, rmw_create_node, rmw_destroy_node,
# rcutils_reset_error) once looked up, False where unavailable


def _library_path(name: str) -> str | None:
    """The path of a shared library this process has loaded (rclpy's librcl)."""
    suffix = "/" + name
    with open("/proc/self/maps") as maps:
        for line in maps:
            path = line.rstrip().rpartition(" ")[2]
            if path.endswith(suffix):
                return path
    return None


def _load():
    global _functions
    if _functions is None:
        try:
            import ctypes

            import rclpy.experimental  # noqa: F401  Jazzy or later (module docstring)

            path = _library_path("librcl.so")
            if path is None:
                raise OSError("librcl.so is not loaded")
            # rcl's handle: dlsym through it finds the rmw rcl itself calls (and rcutils).
            rcl = ctypes.CDLL(path)
            get_rmw_context = rcl.rcl_context_get_rmw_context
            get_rmw_context.restype = ctypes.c_void_p
            get_rmw_context.argtypes = [ctypes.c_void_p]
            create = rcl.rmw_create_node
            create.restype = ctypes.c_void_p
            create.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_char_p]
            destroy = rcl.rmw_destroy_node
            destroy.restype = ctypes.c_int
            destroy.argtypes = [ctypes.c_void_p]
            reset_error = rcl.rcutils_reset_error
            reset_error.restype = None
            reset_error.argtypes = []
            _functions = (get_rmw_context, create, destroy, reset_error)
        except Exception as exc:  # the first rclpy node makes the participant, GIL held
            log.debug("DDS participants are made with the GIL held: %s", exc)
            _functions = False
    return _functions or None


def available() -> bool:
    return _load() is not None


def open_participant(context) -> int | None:
    """Executor thread, before ``context``'s first node: make its DDS participant with a
    placeholder rmw node, the GIL released; the node's address for ``close_participant``, or None
    (unavailable, or rmw refused: the first rclpy node then tries and reports it)."""
    functions = _load()
    if functions is None:
        return None
    get_rmw_context, create, _destroy, reset_error = functions
    rmw_context = get_rmw_context(context.handle.pointer)
    node = create(rmw_context, _NAME, b"/") if rmw_context else None
    if not node:
        reset_error()  # the rclpy node's own error, if it fails too, is the one reported
        return None
    return node


def close_participant(node: int) -> None:
    """Executor thread: the placeholder goes, the participant stays with the context's rclpy
    node (or goes with it if that failed)."""
    functions = _load()
    if functions is not None and functions[2](node) != 0:
        functions[3]()
        log.warning("could not destroy the rmw node that made a DDS participant")
