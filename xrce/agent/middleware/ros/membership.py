"""The ROS domains ``RosMiddleware`` (``xrce.agent.middleware.ros.ros_middleware``) has joined,
and what it keeps per domain besides its clients' entities: its part ``RosDomains``.

A domain is joined when a client's participant first asks for it (its thread and rclpy context:
``xrce.agent.middleware.ros.domain``), the default domain too: an agent without clients has no DDS
participant. A domain whose last client participant has gone is left ``linger_s`` later
(``DOMAIN_LINGER_S``, ``--domain-linger``) unless a participant comes back meanwhile; listeners
hear of each domain joined and left.

At start the CLI has the default domain (``ROS_DOMAIN_ID``, else 0, where most boards'
participants go) prepared (``prepare_default``): its thread, rclpy context and executor are made
then, and the modules a first creation imports, so a first board pays only its DDS participant in
its CREATE (so are the domains a fleet file's rules name, ``--fleet``) (issue 51 item 6: a fresh agent's first node + 4 entities took 2.45x eProsima's agent,
1.5x prepared; bench/microros/entity_creation.py). No DDS participant is made, so at rest the
agent is still nowhere in ROS nor on the network, and idle (bench/agent/domain_prepare.py: 0 ns
on a CPU over 60 s, for 1 MB and two sleeping threads). The default domain left after its last
board is prepared again.

Under a Fast DDS Discovery Server (``ROS_DISCOVERY_SERVER``) the default domain's participant is
made at start too and kept for the agent's life: a participant made by a board's CREATE reached
the other clients of the server about a second later, and a subscriber waiting for the board lost
that second of samples (30 of 40 at 10 Hz), where the participant made at start is known by then
(40 of 40; tests/ros/test_discovery_server.py). Such a participant talks to its server at rest,
not to every port of the network.

Per domain the agent may also have publishers of its own (``AgentPublisher``, e.g. /diagnostics)
and micro-ROS' graph publication (``xrce.agent.middleware.ros.graph``), kept only while a client
reads the graph topic there.
"""

from __future__ import annotations

import os
import threading

from xrce.agent.middleware import MAX_DOMAIN_ID
from xrce.agent.middleware import MiddlewareError
from xrce.agent.middleware.ros import DOMAIN_LINGER_S  # noqa: F401  (re-exported for callers)
from xrce.agent.middleware.ros.domain import ENCAPSULATION_LE, DomainRuntime, log
from xrce.agent.middleware.ros.graph import GRAPH_TYPE, GraphFeed
from xrce.agent.middleware.ros.raw_types import raw_message_type


class AgentPublisher:
    """A publisher of the agent's own that takes CDR bodies (no encapsulation header), on the
    agent's hidden node (``DomainRuntime.host``, visible). Made by a job the loop does not wait
    for: until then it has no reader and writes nothing."""

    __slots__ = ("publisher", "matched_events", "_make")

    def __init__(self, make, matched_events: bool):
        self._make = make  # node -> (rclpy publisher, matched events or not)
        self.publisher = None
        self.matched_events = matched_events  # as asked for, until the RMW has said

    def attach(self, node) -> None:
        self.publisher, self.matched_events = self._make(node)

    def write(self, body: bytes) -> None:
        publisher = self.publisher
        if publisher is not None:
            publisher.publish(ENCAPSULATION_LE + body)

    def subscriber_count(self) -> int:
        publisher = self.publisher
        return 0 if publisher is None else publisher.get_subscription_count()


def default_domain_id(environ=None) -> int | None:
    """The domain a board's participant most often asks for: ``ROS_DOMAIN_ID``, else 0; None
    when the variable is no domain id (a board's participant is then refused as usual)."""
    text = (os.environ if environ is None else environ).get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return 0
    try:
        domain_id = int(text)
    except ValueError:
        return None
    return domain_id if 0 <= domain_id <= MAX_DOMAIN_ID else None


def _warm_up() -> None:
    """A prepared domain's thread, before its first job: what a board's first creations import
    (the type-drift check's parser and classes, ``sample_check``), 3-5 ms of the first
    datawriter's CREATE where modules compile at import."""
    from xrce.agent.middleware.ros import sample_check

    sample_check.prepare()


def _leave_domain(domain: DomainRuntime, timeout_s: float) -> None:
    domain.stop(timeout_s)
    from xrce.agent.heap import return_free_heap

    return_free_heap()  # the domain's DDS buffers, freed, go back to the system


class RosDomains:
    """The domains of the ROS middleware. ``run``: its ``RunContext`` (the loop); ``naming`` and
    ``fleet``: the names and rules boards get (the domains worth preparing); ``in_use(domain)``:
    whether a client participant is in a domain, or being made there (the middleware's
    records and parked creations)."""

    def __init__(self, run, naming, fleet, in_use, executor_kind: str, idle_wait_s: float,
                 entity_timeout_s: float, linger_s: float):
        self._run = run
        self._naming = naming
        self._fleet = fleet
        self._in_use = in_use
        self.executor_kind = executor_kind
        self.idle_wait_s = idle_wait_s
        self.entity_timeout_s = entity_timeout_s
        self.linger_s = linger_s
        self._closed = False
        self._domains: dict[int, DomainRuntime] = {}
        # Started at start, no participant asked for them yet (``prepare``).
        self._prepared: dict[int, DomainRuntime] = {}
        self._kept: set = set()  # joined at start for the agent's life (``prepare``)
        self._default_domain: int | None = None  # prepared again once left (prepare_default)
        # The agent's own node per domain (e.g. for /diagnostics), not tied to any XRCE client.
        self._agent_publishers: dict[tuple, object] = {}
        self._domain_listeners: list = []  # called with each domain id joined (loop thread)
        self._leave_listeners: list = []  # and with each domain id left
        # domain id -> the loop's timer that leaves a domain without participants
        self._lingering: dict = {}
        self._leaving: list = []  # threads stopping domains whose last participant went
        # domain id -> (GraphFeed, number of client readers of the graph topic there): the graph
        # is published only where a client asked for it (xrce.agent.middleware.ros.graph).
        self._graph_feeds: dict[int, list] = {}

    # -- what is joined (the middleware's callers and tests) -----------------------------------

    def runtime(self, domain_id: int) -> DomainRuntime | None:
        """The runtime of a domain joined (or being joined), None if there is none."""
        return self._domains.get(domain_id)

    def runtime_ids(self) -> list[int]:
        """The domains with a runtime, joined or being joined."""
        return list(self._domains)

    def prepared_runtime(self, domain_id: int) -> DomainRuntime | None:
        """The runtime of a domain prepared and not joined yet, None if there is none."""
        return self._prepared.get(domain_id)

    def prepared_ids(self) -> list[int]:
        return sorted(self._prepared)

    def lingering_ids(self) -> list[int]:
        """The domains without participants, to be left when their linger is over."""
        return list(self._lingering)

    # -- joining and leaving ------------------------------------------------------------------

    def prepare_default(self, environ=None) -> None:
        """The CLI's, at start: prepare the default domain; joined too under a Fast DDS
        Discovery Server (module docstring). RMWs other than rmw_fastrtps ignore the variable."""
        environ = os.environ if environ is None else environ
        # --domain: the one every board's participant is put in is the one worth preparing.
        domain_id = self._naming.domain if self._naming.domain is not None else \
            default_domain_id(environ)
        if domain_id is None:
            return
        server = bool(environ.get("ROS_DISCOVERY_SERVER", "").strip()) and \
            environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp").startswith("rmw_fastrtps")
        self._default_domain = domain_id
        self.prepare([domain_id], join=server)
        # A fleet file's domains (--fleet) are as likely a first board's: prepared, not joined.
        self.prepare(self._fleet_domains())

    def _fleet_domains(self) -> list:
        return sorted(self._fleet.domains()) if self._fleet is not None else []

    def prepare(self, domain_ids, join: bool = False) -> None:
        """At start: start ``domain_ids``' threads, rclpy contexts and executors now, not with
        their first client participant (module docstring); with ``join``, make their DDS
        participants too and keep them joined for the agent's life. Returns at once: the work
        is done on each domain's thread, the GIL released for the participant."""
        for domain_id in domain_ids:
            if self._closed or domain_id in self._domains or domain_id in self._prepared:
                continue
            try:
                domain = DomainRuntime(domain_id, self.executor_kind, self.idle_wait_s,
                                       warm_up=_warm_up)
            except Exception as exc:  # the first participant there tries again and says why
                log.debug("cannot prepare ROS domain %d: %s", domain_id, exc)
                continue
            if not join:
                # Out of ``_domains``: nothing of the agent's own (/diagnostics) is made in a
                # domain no participant has asked for, so it stays without a DDS participant.
                self._prepared[domain_id] = domain
                continue
            self._domains[domain_id] = domain
            self._kept.add(domain_id)
            domain.post(domain.make_wake)  # the hidden anchor, and the participant with it
            self.joined(domain_id)

    def domain(self, domain_id: int) -> tuple[DomainRuntime, bool]:
        """(the runtime of ``domain_id``, whether it was started now). Starting one only starts
        its thread, which makes the rclpy context and executor while the loop goes on: jobs queue
        up behind that (``DomainRuntime``), so a client joining a new domain holds up no other
        (its DDS participant is made with the GIL released too, ``ros.participant``).
        A domain whose context could not start is started again on the next call."""
        if self._closed:
            raise MiddlewareError("middleware is closed")
        lingering = self._lingering.pop(domain_id, None)
        if lingering is not None:  # a participant is back within the linger: the domain stays
            lingering.cancel()
        domain = self._domains.get(domain_id)
        if domain is not None and domain.failed is None:
            return domain, False
        if domain is not None:
            del self._domains[domain_id]
        prepared = self._prepared.pop(domain_id, None)
        if prepared is not None and prepared.failed is None:
            self._domains[domain_id] = prepared
            return prepared, True
        try:
            domain = DomainRuntime(domain_id, self.executor_kind, self.idle_wait_s)
        except MiddlewareError:
            raise
        except Exception as exc:
            raise MiddlewareError("cannot start ROS domain %d: %s" % (domain_id, exc)) from exc
        self._domains[domain_id] = domain
        return domain, True

    def joined(self, domain_id: int) -> None:
        """Tell the listeners (the agent's own publishers there): their jobs queue behind what
        was submitted before, the first client's node in a new domain."""
        for listener in list(self._domain_listeners):
            try:
                listener(domain_id)
            except Exception:
                log.warning("domain %d: a listener failed", domain_id, exc_info=True)

    def add_domain_listener(self, listener, left=None) -> None:
        """Call ``listener(domain_id)`` on the loop's thread for every ROS domain the agent has
        joined and joins from now on, and ``left(domain_id)`` for each it leaves."""
        self._domain_listeners.append(listener)
        if left is not None:
            self._leave_listeners.append(left)
        for domain_id in list(self._domains):
            listener(domain_id)

    def domain_ids(self) -> list[int]:
        """The ROS domains the agent has joined (one per domain its clients asked for), from when
        its DDS participant there exists."""
        return [domain_id for domain_id, domain in self._domains.items() if domain.joined]

    def leave_if_unused(self, domain: DomainRuntime) -> None:
        """Leave a domain once no client participant is in it (or being made there) for
        ``linger_s``; a participant made there meanwhile keeps it (``domain``). Not at once: a
        board that resets or reconnects within seconds (a serial board is replaced by its next
        life at its first CREATE_CLIENT, an rclc program restarted) would pay a domain join, and
        its ROS peers a new participant's discovery, each life (the figures behind
        ``DOMAIN_LINGER_S`` are in docs/PERFORMANCE.md)."""
        domain_id = domain.domain_id
        if self._closed or self._domains.get(domain_id) is not domain or \
                domain_id in self._kept or domain_id in self._lingering or self._in_use(domain):
            return
        if self.linger_s <= 0:
            self._leave(domain)
            return
        log.debug("ROS domain %d has no participant left: leaving it in %.1f s unless one comes",
                  domain_id, self.linger_s)
        self._lingering[domain_id] = self._run.loop().call_later(
            self.linger_s, self._linger_over, domain)

    def _linger_over(self, domain: DomainRuntime) -> None:
        if self._lingering.get(domain.domain_id) is None:
            return
        del self._lingering[domain.domain_id]
        if not self._closed and self._domains.get(domain.domain_id) is domain and \
                not self._in_use(domain):
            self._leave(domain)

    def _leave(self, domain: DomainRuntime) -> None:
        """Tear a domain down: its DDS participant, context and executor thread (one client
        joining domains 1..20 and deleting its participants there left 32 MB and 180 threads
        behind; now 3 MB and none, bench/hostile/ros.py). The thread is joined off the loop;
        ``close`` waits for it. Leave listeners hear of it first, while nothing is destroyed."""
        domain_id = domain.domain_id
        del self._domains[domain_id]
        feed = self._graph_feeds.pop(domain_id, None)
        if feed is not None:
            feed[0].stop()  # its periodic check; its writer goes with the domain's nodes
        for publisher_key in [k for k in self._agent_publishers if k[0] == domain_id]:
            del self._agent_publishers[publisher_key]
        for listener in list(self._leave_listeners):
            try:
                listener(domain_id)
            except Exception:
                log.warning("domain %d: a listener failed", domain_id, exc_info=True)
        log.debug("leaving ROS domain %d", domain_id)
        stopping = threading.Thread(target=_leave_domain, args=(domain, self.entity_timeout_s),
                                    name="xrce-leave-domain-%d" % domain_id, daemon=True)
        stopping.start()
        self._leaving = [thread for thread in self._leaving if thread.is_alive()] + [stopping]
        if domain_id == self._default_domain or domain_id in self._fleet_domains():
            # Ready again for the next board, still without a DDS participant (``prepare``).
            self.prepare([domain_id])

    # -- the agent's own publishers -----------------------------------------------------------

    def agent_publisher(self, domain_id: int, message_type, topic: str, depth: int = 10,
                        on_matched=None):
        """An ``AgentPublisher`` of the agent's own (``DomainRuntime.host``) in a domain already
        joined, made on first use and destroyed with the domain; None when the agent has not
        joined ``domain_id``. ``message_type`` is a ``raw_message_type``. Use from the loop thread
        (rcl publish is thread-safe). ``on_matched()``, given when the publisher is made, is
        called on the loop's thread whenever a subscription matches or unmatches it; where the
        RMW has no such event, ``publisher.matched_events`` is False."""
        domain = self._domains.get(domain_id)
        if domain is None or self._closed:
            return None
        publisher = self._agent_publishers.get((domain_id, topic))
        if publisher is not None:
            return publisher

        loop = self._run.loop()

        def matched(_info) -> None:  # on the executor thread
            try:
                loop.call_soon_threadsafe(on_matched)
            except RuntimeError:  # the loop has closed: the agent is gone
                pass

        def make_publisher(node):
            if on_matched is not None:
                from rclpy.event_handler import PublisherEventCallbacks
                try:
                    return node.create_publisher(
                        message_type, topic, depth,
                        event_callbacks=PublisherEventCallbacks(matched=matched)), True
                except Exception as exc:  # an RMW without the matched event
                    log.debug("%s: no matched events (%s)", topic, exc)
            return node.create_publisher(message_type, topic, depth), False

        def attach() -> None:
            domain.host(publisher, visible=True)
            if on_matched is not None:  # it may have readers already, or no matched events
                matched(None)

        # Not waited for: the loop goes on serving, and in a domain a client has just joined it
        # comes after that client's set-up.
        publisher = AgentPublisher(make_publisher, on_matched is not None)
        domain.post_after_start(attach)
        self._agent_publishers[(domain_id, topic)] = publisher
        return publisher

    # -- micro-ROS' graph topic -----------------------------------------------------------------

    def graph_reader_added(self, record, domain: DomainRuntime) -> None:
        """A client's reader of the graph topic (its ``ReaderRecord``) in ``domain``."""
        if record.graph_domain is not None:
            return
        record.graph_domain = domain.domain_id
        entry = self._graph_feeds.get(domain.domain_id)
        if entry is None or entry[0].domain is not domain:
            feed = GraphFeed(domain, raw_message_type(GRAPH_TYPE), self._run.loop())
            entry = self._graph_feeds[domain.domain_id] = [feed, 0]
            feed.start()
        entry[1] += 1

    def graph_reader_gone(self, record) -> None:
        domain_id, record.graph_domain = record.graph_domain, None
        entry = self._graph_feeds.get(domain_id)
        if entry is None:
            return
        entry[1] -= 1
        if entry[1] <= 0:
            del self._graph_feeds[domain_id]
            entry[0].stop()

    def graph_changed(self, domain: DomainRuntime) -> None:
        entry = self._graph_feeds.get(domain.domain_id)
        if entry is not None:
            entry[0].changed()

    def graph_feed(self, domain_id: int) -> GraphFeed | None:
        """The graph publication of a domain, None where no client asked for it."""
        entry = self._graph_feeds.get(domain_id)
        return entry[0] if entry is not None else None

    # -- closing ------------------------------------------------------------------------------

    def close(self) -> tuple[list, list]:
        """Forget every domain: (the runtimes to stop, the threads still stopping runtimes left
        before), for the middleware's ``close`` to wait for off the loop."""
        self._closed = True
        for lingering in self._lingering.values():
            lingering.cancel()
        self._lingering.clear()
        self._agent_publishers.clear()
        for feed, _readers in self._graph_feeds.values():
            feed.stop()
        self._graph_feeds.clear()
        self._domain_listeners.clear()
        self._leave_listeners.clear()
        domains = list(self._domains.values()) + list(self._prepared.values())
        self._domains.clear()
        self._prepared.clear()
        return domains, list(self._leaving)
