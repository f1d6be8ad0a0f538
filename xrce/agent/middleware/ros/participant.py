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

A killed agent's shared-memory ports (issue 51, ``bench/restart/board_restart.py``): Fast DDS on one
host sends user data through shared memory, one port per participant, named after its UDP user
port (``/dev/shm/fastrtps_port<N>``, its reader's ``flock`` on ``..._el``). A participant killed
with SIGKILL leaves its port behind with its dead reader registered; the restarted agent takes the same
UDP ports, so the same port number, finds the old one a zombie (the ``_el`` file unlocked), and
replaces it with a fresh segment. A ROS node that had the old one open keeps writing into it, its
mapping still valid but read by no one, until its shared-memory watchdog finds the dead reader's
counter frozen (a 1 s health check, seen twice): measured 1.2-2.7 s before rclpy's first reliable
sample reached the restarted agent, 0.1 s after a SIGINT (a clean exit unregisters its reader, and
the writer reopens at once). Holding the zombies' ``_el`` locks while the participant is made
(``dead_ports_held``, the domain's user ports only) makes Fast DDS take them for live ports and
move to the next free port number, which no peer has open: its writers open it fresh on discovering
the participant (first sample at the board 0.05-0.43 s after the banner, medians 0.10 s UDP and
0.29 s serial, against 1.7 s for both before). Discovery is untouched (its ports are UDP and
stay the same); the locks are released once the participant exists, and the zombies are left to
Fast DDS, which resets one when a later participant takes its number.
"""

from __future__ import annotations

import contextlib
import logging
import os

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


# Where Fast DDS (boost.interprocess) keeps its shared-memory ports on Linux; "fastrtps" is Fast DDS
# 2's domain name for them, "fastdds" Fast DDS 3's.
SHM_DIR = "/dev/shm"
_PORT_LOCK_PREFIXES = ("fastrtps_port", "fastdds_port")


def user_port(number: int, domain_id: int) -> bool:
    """Whether ``number`` is a participant's user unicast port in ``domain_id``, with the RTPS
    port parameters Fast DDS and rmw_fastrtps keep by default (base 7400, domain gain 250,
    offset 11, participant gain 2): the only ports a peer writes a participant's samples to."""
    offset = number - (7400 + 250 * domain_id + 11)
    return 0 <= offset < 250 - 11 and offset % 2 == 0


def hold_dead_ports(domain_id: int, directory: str = SHM_DIR) -> list[int]:
    """Lock every shared-memory user port lock file of ``domain_id`` nobody holds (its reader
    died): the open, locked descriptors, to be closed once the participant exists
    (``dead_ports_held``). Other ports (other domains, other programs' numbers) stay untouched."""
    try:
        names = os.listdir(directory)
    except OSError:  # no /dev/shm (not Linux): Fast DDS keeps its ports elsewhere
        return []
    import fcntl  # here: a serving agent that never joins a domain does not need it

    held = []
    for name in names:
        prefix = next((p for p in _PORT_LOCK_PREFIXES if name.startswith(p)), None)
        number = name[len(prefix):-len("_el")] if prefix and name.endswith("_el") else ""
        if not (number.isdigit() and user_port(int(number), domain_id)):
            continue
        try:
            fd = os.open(os.path.join(directory, name), os.O_RDONLY | os.O_CLOEXEC | os.O_NOFOLLOW)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:  # held: a live participant's port
            os.close(fd)
            continue
        held.append(fd)
    return held


@contextlib.contextmanager
def dead_ports_held(domain_id: int, directory: str = SHM_DIR):
    """While a domain's participant is made: dead participants' shared-memory ports look taken,
    so Fast DDS gives the new one a port number no peer has a stale mapping of (module
    docstring). Yields how many were held."""
    held = hold_dead_ports(domain_id, directory)
    if held:
        log.debug("%d dead participants' shared-memory ports held while the participant is made",
                  len(held))
    try:
        yield len(held)
    finally:
        for fd in held:
            os.close(fd)


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
