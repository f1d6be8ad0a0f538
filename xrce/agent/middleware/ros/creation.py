"""Entity creation on a ROS domain's executor thread without holding up the loop (``-m dds``).

Every rclpy node, publisher, subscription, client and service is made on its domain's executor
thread (``xrce.agent.middleware.ros.domain``). The loop used to wait for each (up to ``entity_timeout_s``),
and every other client with it. With ``park_creation`` (the CLI's agent) a ``create_*`` submits
the job and raises ``TypeNotReady``: the engine parks only the creating client's processing and
retries its CREATE when the job is done or timed out, and the retry takes the job's result.
"""

from __future__ import annotations

import concurrent.futures

from xrce.agent.middleware import EntityKey, MiddlewareError, TypeNotReady
from xrce.agent.middleware.ros.domain import log


class Creation:
    """An entity being created on an executor thread (``ParkedCreation.create_on_executor``)."""

    __slots__ = ("job", "context", "domain", "node", "parked", "taken")

    def __init__(self, job, context, domain, node):
        self.job = job  # the executor job's future
        self.context = context
        self.domain = domain  # a domain with an entity being created in it stays joined
        self.node = node  # the node the entity is made in (None: a participant's own node)
        self.parked = concurrent.futures.Future()  # done when the job is, or at the timeout
        self.taken = False

    def settle(self) -> None:
        try:
            self.parked.set_result(None)
        except concurrent.futures.InvalidStateError:
            pass  # settled already (the job and the timeout raced)


def on_executor(participant, job, timeout_s: float):
    """``job``'s result, run on the executor thread of ``participant``'s domain; the loop waits
    up to ``timeout_s``. Whatever it raises comes out as a MiddlewareError."""
    try:
        return participant.domain.call(job, timeout_s)
    except MiddlewareError:
        raise
    except Exception as exc:
        raise MiddlewareError("%s: %s" % (type(exc).__name__, exc)) from exc


class ParkedCreation:
    """The entities being created on an executor thread while their client is parked.
    ``run``: the ``RunContext`` (the loop); ``leave_if_unused(domain)``: told when an untaken
    creation is undone, the domain may have nothing left in it (``RosDomains``)."""

    def __init__(self, run, park_creation: bool, entity_timeout_s: float, leave_if_unused):
        self._run = run
        self.park_creation = park_creation
        self.entity_timeout_s = entity_timeout_s
        self._leave_if_unused = leave_if_unused
        # key -> Creation, taken by the CREATE when the engine retries it.
        self._creating: dict = {}

    def creation_of(self, key: EntityKey) -> Creation | None:
        """The creation of ``key`` under way, if any (a participant's retry takes its domain)."""
        return self._creating.get(key)

    def in_domain(self, domain) -> bool:
        """Whether an entity is being created in ``domain`` (which then stays joined)."""
        return any(creation.domain is domain for creation in self._creating.values())

    def pending(self) -> int:
        """How many creations are under way (tests)."""
        return len(self._creating)

    def pending_creation(self, key: EntityKey, participant):
        """The creation a parked CREATE of ``key`` submitted, if its retry may take it: not when
        the node it was made in is not ``participant``'s any more. Stream 0 is not parked, so a
        client can delete its participant and create it again (and the publisher, same ids)
        while a datawriter's creation waits: taking that would hand out an rclpy entity of a
        destroyed node (InvalidHandle at first use). Forgotten here, a new one is submitted;
        the timer undoes the stale one (``_undo_untaken``)."""
        creation = self._creating.get(key)
        if creation is not None and creation.node is not participant.node:
            del self._creating[key]
            return None
        return creation

    def create_on_executor(self, key: EntityKey, participant, job, undo, context=None):
        """``(job's result, context)``, ``job`` creating ``key``'s rclpy entity on the domain's
        executor thread. With ``park_creation`` the loop does not wait for it: the first call
        submits ``job`` and raises TypeNotReady, the engine parks this client (and only it) and
        retries the CREATE when the job is done or ``entity_timeout_s`` has passed; the retry
        gets the result and the ``context`` the first call gave (an entity's record that the job's
        callbacks hold). A result nobody takes within ``entity_timeout_s`` after the job ended
        (the client went away meanwhile) is undone with ``undo(result)`` on the executor."""
        if not self.park_creation:
            return on_executor(participant, job, self.entity_timeout_s), context
        creation = self.pending_creation(key, participant)
        if creation is not None:
            if not creation.job.done() and not creation.parked.done():
                # Resumed early: another creation of this client (one on stream 0, which is not
                # parked) ended first. Not the timeout: wait on for this one.
                raise TypeNotReady("%r is being created on the ROS executor" % (key,),
                                   creation.parked)
            del self._creating[key]
            if not creation.job.done():  # the timeout: what the job makes later is undone
                raise MiddlewareError("ROS executor of domain %d did not answer within %.1f s"
                                      % (participant.domain.domain_id, self.entity_timeout_s))
            creation.taken = True
            try:
                return creation.job.result(), creation.context
            except MiddlewareError:
                raise
            except Exception as exc:
                raise MiddlewareError("%s: %s" % (type(exc).__name__, exc)) from exc
        loop = self._run.loop()
        try:
            submitted = participant.domain.submit(job)
        except MiddlewareError:
            raise
        creation = self._creating[key] = Creation(submitted, context, participant.domain,
                                                    participant.node)
        timer = loop.call_later(self.entity_timeout_s, creation.settle)

        def ended(_future) -> None:  # executor thread
            creation.settle()
            try:
                loop.call_soon_threadsafe(timer.cancel)
                loop.call_soon_threadsafe(loop.call_later, self.entity_timeout_s,
                                          self._undo_untaken, key, creation, participant, undo)
            except RuntimeError:  # the loop has closed: the agent is gone
                pass

        submitted.add_done_callback(ended)
        raise TypeNotReady("%r is being created on the ROS executor" % (key,), creation.parked)

    def _undo_untaken(self, key: EntityKey, creation: Creation, participant, undo) -> None:
        try:
            self._undo_if_untaken(key, creation, participant, undo)
        finally:
            # The creation's last use: its job's future keeps ``ended`` (above), which keeps the
            # creation, which keeps the future and its result (a client's node, publisher...).
            # Cut here, that cycle goes by reference counting, not minutes later when Python
            # next collects its oldest generation (bench/churn/churn.py: ~20 MB/h at a board a second).
            creation.job = None

    def _undo_if_untaken(self, key: EntityKey, creation: Creation, participant, undo) -> None:
        if creation.taken:
            return
        if self._creating.get(key) is creation:
            del self._creating[key]
        if creation.job.cancelled() or creation.job.exception() is not None:
            return
        result = creation.job.result()
        log.debug("entity %r was created for a client that never took it: destroyed", key)
        try:
            participant.domain.post(lambda: undo(result))
        except MiddlewareError:
            pass  # the domain has stopped: its nodes went with it
        self._leave_if_unused(participant.domain)
