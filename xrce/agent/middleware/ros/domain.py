"""The threads behind ``RosMiddleware`` (``xrce.agent.middleware.ros.ros_middleware``): one rclpy
context and executor thread per ROS domain, the jobs the asyncio loop hands to it; the samples it
hands back to the loop are ``xrce.agent.middleware.ros.handoff``'s.

Threading model (measured on the 2-core dev machine, Twist, peer in another process):

- EventsExecutor (default, ``XRCE_ROS_EXECUTOR=single`` to switch): publisher -> on_data 47-75k
  msg/s, SingleThreadedExecutor 5-6k msg/s; write() -> rclpy subscriber 74-95k calls/s either way;
  200 clients (node + writer + reader) created in 3.9 s (5.5 ms median per create) vs 7.0 s.

- One rclpy ``Context`` per ROS domain, created on its executor thread when the first participant
  of that domain appears; that participant's node is the thread's first job, the wake-up and the
  agent's own entities come after the client's first burst (``DomainRuntime._serve_first_burst``).
- Every call that touches the executor's entity set (creating/destroying nodes, publishers,
  subscriptions, clients, services; ``call_async``) runs ON that executor thread: the engine's
  thread submits a job and, for creation, waits for its result. The reason is the rclpy 7.1
  ``EventsExecutor``: calling ``wake()``/``add_node()`` on it from another thread while it spins
  deadlocks (observed: every time, within milliseconds), and node/entity creation wakes the executor.
  SingleThreadedExecutor tolerates cross-thread creation, but it delivers raw subscriptions about
  ten times slower (measured when the executor was chosen; no bench here keeps that
  figure), so both go through the same job queue.
- Nothing polls: ``post``/``call`` wake the executor thread through a private wake topic (a
  guard condition for the SingleThreadedExecutor), ``xrce.agent.middleware.ros.wake``.
- Publishing and sending service responses need no executor and happen directly on the engine's
  thread: rcl publish/send_response are thread-safe.
- Data from ROS reaches the engine on the executor thread itself when the engine's lock is free
  and nothing of that reader waits for the loop (TurtleBot3 load, bench/agent/cost.py, medians
  of 3: the agent's main thread 2.0 -> 1.7 % of a core and 147 -> 128 switch-ins a second, the
  whole agent 2.8 -> 2.5 %); otherwise through a bounded per-reader hand-off drained on the loop
  (``call_soon_threadsafe`` once per batch, drop-oldest when the loop falls behind).
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import logging
import queue
import threading
import time

import rclpy
import rclpy.task
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from xrce.agent.middleware import MiddlewareError
from xrce.agent.middleware.ros import participant
from xrce.agent.middleware.ros.agent_node import AgentNode
from xrce.agent.middleware.ros.wake import ExecutorWake

# The whole ROS bridge logs under one name, the one it had as a single module, so that existing
# log filters keep matching.
log = logging.getLogger("xrce.agent.ros")

# CDR_LE, options 0: what the XRCE agent always puts in front of a sample going into DDS (§14).
ENCAPSULATION_LE = b"\x00\x01\x00\x00"
ENCAPSULATION_SIZE = 4

# rcl's log file (spdlog, ~/.ros/log/<exe>_<pid>_<time>.log) stays closed: rcl and rmw messages
# still reach stderr through rcl's console output, the agent's own go through Python logging, and
# the file cost 0.24 MB resident (measured, TurtleBot3 load) and stayed empty all the same (one
# per agent start, thousands on a test machine).
ROS_ARGS = ["--ros-args", "--disable-external-lib-logs"]
NO_TYPE_DESCRIPTION = Parameter("start_type_description_service", value=False)
# How long the executor thread waits in rclpy when nothing happens; it only bounds how late a
# stop request is seen if its wake-up sample were lost, nothing else runs on this period.
IDLE_WAIT_S = 5.0
# A domain's first burst of jobs (DomainRuntime._serve_first_burst).
FIRST_BURST_IDLE_S = 0.05
FIRST_BURST_MAX_S = 0.25

AGENT_NODE_NAME = "_xrce_agent"

EXECUTOR_EVENTS = "events"
EXECUTOR_SINGLE = "single"


class DomainRuntime:
    """One rclpy context and its executor thread; runs entity jobs on that thread."""

    def __init__(self, domain_id: int, executor_kind: str, idle_wait_s: float = IDLE_WAIT_S,
                 warm_up=None):
        """Only starts the thread: the rclpy context and executor are made on it (``_start``),
        so that joining a domain never holds up the caller (the loop) beyond a thread start.
        Jobs submitted meanwhile queue up; if the context cannot start they fail with the
        reason, and ``failed`` holds it. ``warm_up()`` runs on the thread right after the
        context, before any job (``RosDomains.prepare``)."""
        if executor_kind not in (EXECUTOR_EVENTS, EXECUTOR_SINGLE):
            raise MiddlewareError("unknown executor %r" % (executor_kind,))
        self.domain_id = domain_id
        self.executor_kind = executor_kind
        self.context: Context | None = None
        self.executor = None
        self.failed: BaseException | None = None  # why the context or executor did not start
        # The domain's DDS participant exists: rmw_fastrtps made it with the first node.
        self.joined = False
        self._events = executor_kind == EXECUTOR_EVENTS
        self._idle_wait_s = idle_wait_s
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._running = True
        self._stopped = rclpy.task.Future()  # completed on the executor thread by stop()
        self.nodes: set[Node] = set()
        self.client_nodes: list[Node] = []  # in the order they came
        # The node hosting the agent's own entities (the wake topic, RosMiddleware's agent
        # publishers, the graph topic's writer): a client's, or the anchor (host()).
        self.agent_node: Node | None = None
        self._anchor: Node | None = None  # the hidden ``_xrce_agent`` (_move_host says when)
        # A hosting client's node went: the agent's entities stay on the anchor from then on.
        self._anchored = False
        self._hosted: list = []  # moved with the host (DDS-level)
        self._pinned: list = []  # on the anchor for good (ROS topics)
        self._wake_item: ExecutorWake | None = None  # made by make_wake
        # Wakes the executor thread for a job: the wake item's own from make_wake on, called
        # with no hop between; until then the thread blocks on the queue itself.
        self._wake = _no_wake
        self._retired: list = []  # destroyers waiting for a safe callback (retire())
        self._start_lock = threading.Lock()
        self._started_up = False  # the first burst is over (post_after_start)
        self._after_start: list = []  # jobs posted for then
        self._warm_up = warm_up
        self.thread = threading.Thread(target=self._run, name="xrce-ros-domain-%d" % domain_id,
                                       daemon=True)
        self.thread.start()

    def _start(self) -> None:
        """Executor thread, first thing: the domain's rclpy context and executor. No DDS
        participant yet: rmw_fastrtps makes it with the context's first node."""
        context = Context()
        rclpy.init(args=ROS_ARGS, context=context, domain_id=self.domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.context = context
        if self._events:
            from rclpy.experimental import EventsExecutor
            self.executor = EventsExecutor(context=context)
        else:
            self.executor = SingleThreadedExecutor(context=context)

    def make_node(self, name: str, namespace: str | None = None) -> Node:
        """A node of this domain as the agent needs it, not yet in the executor (call on the
        executor thread). Without parameter services, /rosout publisher, type description
        service or /parameter_events publisher (``AgentNode``): each costs DDS endpoints, memory
        and discovery traffic, and an agent may host hundreds of nodes."""
        # The context's first node makes the DDS participant: with the GIL released (participant).
        # A killed agent's shared-memory ports are held meanwhile (participant.dead_ports_held).
        held = contextlib.nullcontext() if self.joined else \
            participant.dead_ports_held(self.domain_id)
        with held:
            placeholder = None if self.joined else participant.open_participant(self.context)
            try:
                node = AgentNode(name, namespace=namespace, context=self.context,
                                 start_parameter_services=False, enable_rosout=False,
                                 use_global_arguments=False,
                                 parameter_overrides=[NO_TYPE_DESCRIPTION])
            finally:
                if placeholder is not None:
                    participant.close_participant(placeholder)
        self.joined = True
        return node

    # -- the node that hosts the agent's own entities --------------------------------------------
    #
    # The wake topic (or guard condition) and the graph topic's writer need a node, and a node
    # shows in every ROS node listing, which micro_ros_agent's never do (its graph participant
    # has no node). Both are DDS-level, outside ROS listings: they live on the first client's
    # node, and once that node goes, on the hidden anchor node ``_xrce_agent`` (``ros2 node list``
    # leaves it out), which keeps the domain's DDS participant (rmw creates it with a context's
    # first node and destroys it with its last) and the wake-up alive between clients
    # (``_move_host`` says why they do not follow the next client). Moving them is
    # create-then-destroy, on this thread: nothing is ever without its entity. What the agent
    # publishes as a ROS topic (RosMiddleware.agent_publisher: /diagnostics) stays on the anchor
    # (``visible``): it is the agent's, and under a client's node a board would list it as its
    # own; so with /diagnostics on, the anchor stays too.

    def make_wake(self) -> None:
        """Executor thread: the wake-up, on the first client's node when the domain has one,
        else on the anchor; from then on the thread spins. ``_run`` makes it after the domain's
        first burst of jobs; RosMiddleware.start asks for it at once in its own domain."""
        if self._wake_item is not None:
            return
        if self.agent_node is None:
            self.agent_node = self.client_nodes[0] if self.client_nodes else \
                self._anchor or self._raise_anchor()
        wake = self._wake_item = ExecutorWake(self._events, self._on_wake, self.retire)
        self._wake = wake.wake
        self.host(wake)

    def post_after_start(self, job) -> None:
        """Run ``job`` on the executor thread after the domain's first burst of jobs (see
        ``_serve_first_burst``): for the agent's own entities, which a client joining this
        domain should not wait behind."""
        with self._start_lock:
            if not self._started_up:
                self._after_start.append(job)
                return
        self.post(job)

    def _raise_anchor(self) -> Node:
        # Hidden (rclpy.node.HIDDEN_NODE_PREFIX): even while it exists, ros2 node list leaves it
        # out.
        node = self._anchor = self.make_node(AGENT_NODE_NAME)
        self.executor.add_node(node)
        self.nodes.add(node)
        return node

    def host(self, item, visible: bool = False) -> None:
        """Executor thread: ``item.attach(node)`` now, on the hosting node, and
        ``item.move(old, new)`` whenever the host changes; ``unhost`` ends it. A ``visible``
        item (a ROS topic's endpoint) is attached to the anchor, for good."""
        if visible:
            if self._anchor is None:
                self._raise_anchor()
            item.attach(self._anchor)
            self._pinned.append(item)
            return
        item.attach(self.agent_node)
        self._hosted.append(item)

    def unhost(self, item) -> None:
        """Executor thread: ``item`` is no longer moved (it destroyed its entities itself)."""
        if item in self._hosted:
            self._hosted.remove(item)

    # Every move makes the hosted endpoints anew, and Fast DDS (2.14, EDP's matched-status maps)
    # keeps ~60 bytes for every local endpoint that ever matched, for the participant's life.
    # Moving from one board to the next as each goes cost the agent ~1 MB/h at a board life a
    # second (bench/churn/churn.py, issue 39). So the anchor hands the entities to the first client that
    # comes (the graph then shows only clients' nodes), and once a hosting client's node goes they
    # stay on the anchor: at most two moves in a domain's life.
    def _move_host(self, new: Node) -> None:
        old, self.agent_node = self.agent_node, new
        for item in list(self._hosted):
            try:
                item.move(old, new)
            except Exception:
                log.exception("domain %d: cannot move %r to another node", self.domain_id, item)

    def add_client_node(self, node: Node) -> None:
        """Executor thread: a client's node joins the executor; the agent's entities move onto
        it from the anchor, which goes."""
        self.executor.add_node(node)
        self.nodes.add(node)
        self.client_nodes.append(node)
        if self.agent_node is None:  # the domain's first burst: its wake-up comes onto this one
            self.agent_node = node
            return
        anchor = self._anchor
        if anchor is not None and self.agent_node is anchor and not self._anchored:
            self._move_host(node)
            if not self._pinned:
                self._anchor = None
                self.retire(lambda: self._destroy_node(anchor))  # it hosted the wake-up

    def remove_client_node(self, node: Node) -> None:
        """Executor thread: destroy a client's node, the agent's entities moved off it first, to
        the anchor for good (``_move_host``)."""
        if node in self.client_nodes:
            self.client_nodes.remove(node)
        if self.agent_node is node:
            self._anchored = True
            self._move_host(self._anchor or self._raise_anchor())
            self.retire(lambda: self._destroy_node(node))  # it hosted the wake-up (wake.py)
            return
        self._destroy_node(node)

    def _destroy_node(self, node: Node) -> None:
        self.executor.remove_node(node)
        self.nodes.discard(node)
        node.destroy_node()

    def retire(self, destroy) -> None:
        """Executor thread: ``destroy()`` from the next wake-up callback of the current wake
        entity, when no callback of what it destroys can be running."""
        self._retired.append(destroy)

    def _on_wake(self, current: bool) -> None:
        """Wake-up callback (executor thread); ``current``: of the wake entity attached last."""
        if self._retired and current:
            retired, self._retired = self._retired, []
            for destroy in retired:
                try:
                    destroy()
                except Exception:
                    log.exception("domain %d: destroying a moved entity failed", self.domain_id)
        self._run_jobs()

    def _run_jobs(self) -> None:
        while True:
            try:
                item = self._jobs.get_nowait()
            except queue.Empty:
                return
            self._run_job(*item)

    def _run_job(self, result, job) -> None:
        if result is not None and not result.set_running_or_notify_cancel():
            return
        try:
            value = job()
        except BaseException as exc:  # handed to the submitter, never lost
            if result is not None:
                result.set_exception(exc)
            else:
                log.exception("ROS job failed in domain %d", self.domain_id)
        else:
            if result is not None:
                result.set_result(value)

    def _stop_spinning(self) -> None:
        self._running = False
        if not self._stopped.done():
            self._stopped.set_result(True)

    def _fail_queued(self) -> None:
        """The context did not start: every job queued fails with the reason."""
        error = MiddlewareError("cannot start ROS domain %d: %s" % (self.domain_id, self.failed))
        while True:
            try:
                result, _job = self._jobs.get_nowait()
            except queue.Empty:
                return
            if result is not None and result.set_running_or_notify_cancel():
                result.set_exception(error)

    def _serve_first_burst(self) -> None:
        """Until the wake-up exists, serve the queue directly, blocking on it: from the first
        job (a client's node, in a domain a client joins) until no job has come for
        ``FIRST_BURST_IDLE_S`` (a client's set-up CREATEs come closer together), at most
        ``FIRST_BURST_MAX_S``. So the wake-up and the agent's own entities (the anchor,
        /diagnostics) are made after that client's set-up, not between its node and its STATUS
        (the rclpy calls hold the GIL the loop needs to answer: the STATUS came 2-3 ms after
        the node when the wake-up was made right after it). Subscriptions made meanwhile
        deliver once the thread spins, at most ``FIRST_BURST_MAX_S`` later."""
        result, job = self._jobs.get()
        self._run_job(result, job)
        deadline = time.monotonic() + FIRST_BURST_MAX_S
        while self._running and self._wake_item is None:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return
            try:
                result, job = self._jobs.get(timeout=min(FIRST_BURST_IDLE_S, remaining))
            except queue.Empty:
                return
            self._run_job(result, job)

    def _run(self) -> None:
        try:
            self._start()
        except BaseException as exc:  # handed to every job, never lost
            log.error("cannot start ROS domain %d: %s", self.domain_id, exc)
            self.failed = exc
            self._fail_queued()
            return
        if self._warm_up is not None:
            try:
                self._warm_up()
            except Exception:  # only a head start lost: each piece loads again when needed
                log.debug("domain %d: warm-up failed", self.domain_id, exc_info=True)
            self._warm_up = None
        self._serve_first_burst()
        if self._running:
            try:
                self.make_wake()
            except Exception:  # jobs are then only seen when each wait times out
                log.exception("cannot create the agent node of ROS domain %d", self.domain_id)
        with self._start_lock:
            self._started_up = True
            after_start, self._after_start = self._after_start, []
        for job in after_start:
            if self._running:
                self._run_job(None, job)
        # What the join allocated for itself (a first one loads Fast DDS, the type supports and
        # the profile) goes back to the system, as it did when the default domain was joined
        # at start: 0.4-0.7 MB less resident under the TurtleBot3 load, for 0.2-0.5 ms here.
        from xrce.agent.heap import return_free_heap

        return_free_heap()
        while self._running:
            self._run_jobs()
            try:
                if self._events:
                    self.executor.spin_until_future_complete(self._stopped,
                                                             timeout_sec=self._idle_wait_s)
                else:
                    self.executor.spin_once(timeout_sec=self._idle_wait_s)
            except ExternalShutdownException:
                break
            except Exception:
                # A failing callback must not take the whole domain down with it.
                log.exception("ROS executor callback failed in domain %d", self.domain_id)
        self._run_jobs()

    def post(self, job) -> None:
        """Run ``job`` on the executor thread, not waiting for it."""
        self._jobs.put((None, job))
        self._wake()

    def submit(self, job) -> concurrent.futures.Future:
        """Run ``job`` on the executor thread; the future of its result."""
        if self.failed is not None:
            raise MiddlewareError("cannot start ROS domain %d: %s" % (self.domain_id, self.failed))
        if not self.thread.is_alive():
            raise MiddlewareError("ROS executor of domain %d is not running" % self.domain_id)
        result: concurrent.futures.Future = concurrent.futures.Future()
        self._jobs.put((result, job))
        if self.failed is not None:  # the thread failed as this was queued: it may not see it
            self._fail_queued()
        self._wake()
        return result

    def call(self, job, timeout_s: float):
        """Run ``job`` on the executor thread and return its result (or raise its exception)."""
        result = self.submit(job)
        try:
            return result.result(timeout_s)
        except concurrent.futures.TimeoutError:
            result.cancel()
            raise MiddlewareError("ROS executor of domain %d did not answer within %.1f s"
                                  % (self.domain_id, timeout_s)) from None

    def _destroy_all_nodes(self) -> None:
        self._wake = _no_wake  # its node goes too
        self._hosted.clear()
        self._pinned.clear()
        self._retired.clear()  # their nodes are all destroyed below
        for node in list(self.nodes):
            self.executor.remove_node(node)
            node.destroy_node()
        self.nodes.clear()
        self.client_nodes.clear()
        self.agent_node = self._anchor = None

    def _finish(self) -> None:
        try:
            self._destroy_all_nodes()
        finally:
            self._stop_spinning()

    def stop(self, timeout_s: float) -> None:
        """Destroy every node, stop and join the thread, shut the context down. Blocking."""
        if self.thread.is_alive():
            try:
                self.call(self._finish, timeout_s)
            except Exception:
                log.exception("destroying the nodes of domain %d failed", self.domain_id)
                self._running = False
            self.thread.join(timeout_s)
        if self.thread.is_alive():
            log.error("ROS executor thread of domain %d did not stop", self.domain_id)
            return
        self._destroy_all_nodes()
        if self.executor is not None:
            self.executor.shutdown()
        if self.context is not None:
            self.context.try_shutdown()


def _no_wake() -> None:
    """No wake entity (yet, or its node is gone)."""
