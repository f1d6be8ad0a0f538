"""The request/reply (ROS service) part of ``RosMiddleware``
(``xrce.agent.middleware.ros.ros_middleware``), ``RosServices``; its records are in
``xrce.agent.middleware.ros.service_records``.

An XRCE requester is an rclpy service client, an XRCE replier an rclpy service. A request waits
on the loop until its reply arrives or ``request_timeout_s`` passes (held, if its server is not
discovered yet, under one shared timer; at most MAX_PENDING_REQUESTS_PER_CLIENT per client); a
replier's incoming request gets a sample identity of its own and waits for the XRCE client's reply
just as long. Clients and services are made, and requests sent (``call_async``), on the domain's
executor thread (``xrce.agent.middleware.ros.domain``); a service response goes out from the loop thread, rcl
send_response being thread-safe.

A request for a replier goes to its XRCE client from the executor thread that took it, under the
engine's lock when that lock is free and none of the replier's requests wait for the loop (as a
reader's samples do, ``ReaderHandoff``); otherwise through the loop. Unanswered requests expire
under one timer for the whole agent, armed while any wait, instead of a timer per request, so a
request costs the loop no wake-up at all. Over a UDP link with the compiled path, the engine takes
a replier's rcl service away from the executor once the board reads it (``replier_service``,
xrce/agent/engine/compiled/_replier_out.c): requests and replies then pass no Python at all, and only the
requests rclpy's executor still delivers come this way, with identities from the compiled path's
counter (``replier_sequence_from``). Measured with bench/microros/service_roundtrip.py (the real
firmware's replier, an rclpy client, medians of interleaved rounds beside eProsima's agent).
"""

from __future__ import annotations

import os
import struct
import time

from rclpy.serialization import deserialize_message, serialize_message
from rclpy.service import Service

from xrce.agent.middleware import (
    EndpointQosSpec,
    EntityKey,
    ReplyCallback,
    RequestCallback,
    ServiceSpec,
)
from xrce.agent.observe.names import client_tag
from xrce.agent.middleware.ros.domain import ENCAPSULATION_LE, ENCAPSULATION_SIZE, log
from xrce.agent.middleware.ros.raw_types import (
    carries_cdr, library_service_type, named_service_type, raw_service_type,
)
from xrce.agent.middleware.ros.service_records import ReplierRecord, RequesterRecord
from xrce.agent.middleware.ros.types import qos_profile, service_class, service_ros_name


# Requests held for a server that is not discovered yet are checked together: one timer for the
# whole agent, armed only while some are held, first after SERVER_CHECK_FIRST_S, then less and less
# often up to SERVER_CHECK_MAX_S (each check asks every such requester once, however many requests
# it holds). It replaced a task per request waking every 10 ms: 2000 requests to a service with no
# server took 99 % of a core for their 10 s.
SERVER_CHECK_FIRST_S = 0.01
SERVER_CHECK_MAX_S = 0.1
# Requests of one XRCE client in flight (held, or sent and not answered yet); beyond, a request is
# refused. Each holds a deserialized request and an expiry timer for request_timeout_s.
MAX_PENDING_REQUESTS_PER_CLIENT = 256
# An action's get_result request is answered when its goal ends, which may be minutes later: rcl_action
# and micro_ros_agent wait for it as long as that takes, so those requests never expire here; a
# replier holds at most this many ROS-side ones (the oldest is forgotten first), a requester's count
# against MAX_PENDING_REQUESTS_PER_CLIENT.
MAX_HELD_RESULT_REQUESTS = 256
_RESULT_SERVICE_SUFFIX = "/_action/get_result"


def _expires(service_name: str) -> bool:
    """Whether requests of this ROS service expire after request_timeout_s."""
    return not service_name.endswith(_RESULT_SERVICE_SUFFIX)


class RosServices:
    """Requesters and repliers of the ROS middleware. Collaborators: ``run`` (``RunContext``: the
    loop, the engine's lock), ``records`` (``EntityRecords``: participants looked up, records
    kept), ``creation`` (``ParkedCreation``: rclpy clients and services made on the executor),
    ``collisions`` (``NameCollisions``: a replier's service name claimed)."""

    def __init__(self, run, records, creation, collisions, request_timeout_s: float):
        self._run = run
        self._records = records
        self._creation = creation
        self._collisions = collisions
        self.request_timeout_s = request_timeout_s
        self.requests_timed_out = 0
        self.requests_refused = 0
        self._refusal_logged = None
        # 12-byte guidPrefix for generated sample identities: random per agent run so identities
        # from two runs never collide in a client that survived an agent restart.
        self._guid_prefix = os.urandom(12)
        self._replier_counter = 0
        # requesters holding requests: {record: None}, made on first use
        self._awaiting_server = None
        self._server_check = None  # the one TimerHandle checking them
        self._server_check_delay = SERVER_CHECK_FIRST_S
        self._pending_by_client = None  # XRCE client key -> requests in flight
        # repliers holding requests for their XRCE client: {record: None}
        self._waiting_repliers = None
        self._reply_sweep = None  # None, True (asked from the executor thread) or the TimerHandle

    def count_timed_out(self, count: int) -> None:
        """``count`` requests held elsewhere (the compiled path) got no reply in time."""
        self.requests_timed_out += count

    # -- creation -----------------------------------------------------------------------------

    def _service_endpoint(self, key: EntityKey, participant: EntityKey, service: ServiceSpec,
                          qos: EndpointQosSpec, service_type=service_class):
        """What a requester and a replier both resolve first: (owner key, participant record,
        service class as ``service_type`` gives it, ROS service name, QoS profile)."""
        owner, participant_record = self._records.participant_of(participant, ("participant",))
        self._records.refuse_existing(key)
        return (owner, participant_record, service_type(service.request_type),
                participant_record.naming.name(service_ros_name(service.service_name, service.request_topic,
                                                  service.reply_topic)), qos_profile(qos))

    def create_requester(self, key: EntityKey, participant: EntityKey, service: ServiceSpec,
                         qos: EndpointQosSpec, on_reply: ReplyCallback) -> None:
        # A type known only by name sends the client's CDR bytes; otherwise Python messages.
        owner, participant_record, srv, service_name, profile = self._service_endpoint(
            key, participant, service, qos,
            lambda name: named_service_type(name) or service_class(name))
        self._run.loop()
        creation = self._creation.pending_creation(key, participant_record)
        record = creation.context if creation is not None else \
            RequesterRecord(owner, srv, on_reply, _expires(service_name))
        node = participant_record.node
        record.client, _ = self._creation.create_on_executor(
            key, participant_record,
            lambda: node.create_client(srv, service_name, qos_profile=profile),
            node.destroy_client, record)
        self._records.put(key, record)

    def create_replier(self, key: EntityKey, participant: EntityKey, service: ServiceSpec,
                       qos: EndpointQosSpec, on_request: RequestCallback) -> None:
        # The service type from the package's C libraries where it can be (CDR bytes both ways,
        # no Python package imported), made from its name where the package is nowhere, else
        # its Python classes.
        owner, participant_record, srv, service_name, profile = self._service_endpoint(
            key, participant, service, qos,
            lambda name: named_service_type(name) or library_service_type(name)
            or service_class(name))
        creation = self._creation.pending_creation(key, participant_record)
        if creation is not None:  # the retry of a parked CREATE (ParkedCreation.create_on_executor)
            record = creation.context
        else:
            self._replier_counter += 1
            # entityKey: 3 bytes of a per-agent replier counter; entityKind 0x02 = user writer
            # with key (the reply writer a DDS replier would own).
            prefix = self._guid_prefix + struct.pack(">I", self._replier_counter & 0xFFFFFF)[1:] \
                + b"\x02"
            record = ReplierRecord(owner, srv, on_request, prefix, self._run.loop(), self,
                                   self._run, _expires(service_name))
        node = participant_record.node

        def make_service():
            ros_service = node.create_service(srv, service_name, record.take, qos_profile=profile)
            ros_service.send_response = record.capture
            raw = srv if carries_cdr(srv) else raw_service_type(srv)
            if raw is not None:  # requests and replies cross as CDR bytes
                ros_service.srv_type = raw
                record.raw_reply = raw.Response
            return ros_service

        record.service, _ = self._creation.create_on_executor(key, participant_record, make_service,
                                                     node.destroy_service, record)
        self._records.put(key, record)
        self._collisions.claim_service(key, owner, record.service.srv_name)

    # -- data ---------------------------------------------------------------------------------

    def write_request(self, requester: EntityKey, correlation_id: int, sample: bytes) -> bool:
        record = self._records.get(requester)
        if record is None or record.kind != "requester":
            return False
        try:
            if carries_cdr(record.srv):  # a type known by name: its bytes as they are
                request = record.srv.Request(ENCAPSULATION_LE + bytes(sample))
            else:
                request = deserialize_message(ENCAPSULATION_LE + bytes(sample),
                                              record.srv.Request)
        except Exception as exc:
            log.warning("request for %r does not decode as %s: %s", requester,
                        record.srv.__name__, exc)
            return False
        loop = self._run.loop()
        previous = record.pending.pop(correlation_id, None)
        if previous is not None:  # the same request id again: the new one replaces it
            self._forget_request(record, previous)
            self._release(record)
            record.waiting.pop(correlation_id, None)
        if self._pending_by_client is None:
            self._pending_by_client = {}
        in_flight = self._pending_by_client.get(record.client_key, 0)
        if in_flight >= MAX_PENDING_REQUESTS_PER_CLIENT:
            self._refuse_request(record)
            return False
        self._pending_by_client[record.client_key] = in_flight + 1
        entry = [None, loop.call_later(self.request_timeout_s, self._expire_request, record,
                                       correlation_id) if record.expires else None]
        record.pending[correlation_id] = entry
        if record.client.service_is_ready():
            self._send_request(record, correlation_id, entry, request)
        else:
            # A request sent before the server is discovered is lost in DDS; the XRCE client
            # cannot know that, so hold it here until the server shows up (or it expires).
            record.waiting[correlation_id] = (entry, request)
            self._await_server(record)
        return True

    def _refuse_request(self, record: RequesterRecord) -> None:
        self.requests_refused += 1
        now = time.monotonic()
        if self._refusal_logged is None or now - self._refusal_logged >= 10.0:
            self._refusal_logged = now
            log.warning("client %s has %d service requests in flight: further ones are refused "
                        "(%d so far)", client_tag(record.client_key.to_bytes(4, "big")),
                        MAX_PENDING_REQUESTS_PER_CLIENT, self.requests_refused)

    def _release(self, record: RequesterRecord, count: int = 1) -> None:
        """``count`` of ``record``'s requests are no longer in flight."""
        counts = self._pending_by_client
        if counts is None or not count:
            return
        left = counts.get(record.client_key, 0) - count
        if left > 0:
            counts[record.client_key] = left
        else:
            counts.pop(record.client_key, None)

    def _await_server(self, record: RequesterRecord) -> None:
        if self._awaiting_server is None:
            self._awaiting_server = {}
        if record not in self._awaiting_server:
            self._awaiting_server[record] = None
            # A requester that starts waiting is checked soon, whatever the others' back-off.
            self._server_check_delay = SERVER_CHECK_FIRST_S
            if self._server_check is not None:
                self._server_check.cancel()
                self._server_check = None
        if self._server_check is None:
            self._server_check = self._run.loop().call_later(self._server_check_delay,
                                                       self._check_servers)

    def _check_servers(self) -> None:
        """The one timer: send what each requester holds once its server is there."""
        self._server_check = None
        for record in list(self._awaiting_server):
            if record.closed or not record.waiting:
                del self._awaiting_server[record]
                continue
            try:
                ready = record.client.service_is_ready()
            except Exception:  # destroyed meanwhile
                ready = False
            if not ready:
                continue
            del self._awaiting_server[record]
            held, record.waiting = record.waiting, {}
            for correlation_id, (entry, request) in held.items():
                if record.pending.get(correlation_id) is entry:
                    self._send_request(record, correlation_id, entry, request)
        if self._awaiting_server:
            self._server_check_delay = min(SERVER_CHECK_MAX_S, self._server_check_delay * 2)
            self._server_check = self._run.loop().call_later(self._server_check_delay,
                                                       self._check_servers)

    def close_requester(self, record: RequesterRecord) -> None:
        """The requester is deleted: forget what it holds (loop side)."""
        record.closed = True
        for entry in record.pending.values():
            self._forget_request(record, entry)
        self._release(record, len(record.pending))
        record.pending.clear()
        record.waiting.clear()
        if self._awaiting_server is not None:
            self._awaiting_server.pop(record, None)

    def _send_request(self, record: RequesterRecord, correlation_id: int, entry: list,
                      request) -> None:
        participant = self._records.get(record.participant)
        if participant is None:
            return
        loop = self._run.loop()

        def reply_arrived(future) -> None:  # executor thread
            try:
                reply = future.result()
                body = reply if reply.__class__ is bytes else \
                    serialize_message(reply)[ENCAPSULATION_SIZE:]
            except Exception:
                log.exception("service reply could not be serialized")
                return
            try:
                loop.call_soon_threadsafe(self._deliver_reply, record, correlation_id, entry, body)
            except RuntimeError:
                pass

        def send() -> None:  # executor thread: call_async may schedule on the executor
            if record.closed:
                return
            future = record.client.call_async(request)
            entry[0] = future
            future.add_done_callback(reply_arrived)

        participant.domain.post(send)

    def _deliver_reply(self, record: RequesterRecord, correlation_id: int, entry: list,
                       body: bytes) -> None:
        if record.closed or record.pending.get(correlation_id) is not entry:
            return
        del record.pending[correlation_id]
        self._release(record)
        if entry[1] is not None:
            entry[1].cancel()
        try:
            record.on_reply(correlation_id, body)
        except Exception:
            log.exception("on_reply failed")

    def _forget_request(self, record: RequesterRecord, entry: list) -> None:
        if entry[1] is not None:
            entry[1].cancel()
        if entry[0] is not None and record.client is not None:
            record.client.remove_pending_request(entry[0])

    def _expire_request(self, record: RequesterRecord, correlation_id: int) -> None:
        entry = record.pending.pop(correlation_id, None)
        if entry is not None:
            self._release(record)
            record.waiting.pop(correlation_id, None)
            self.requests_timed_out += 1
            log.warning("service request %d got no reply within %.1f s", correlation_id,
                        self.request_timeout_s)
            self._forget_request(record, entry)

    def deliver_in_transit(self, record: ReplierRecord) -> None:
        """Loop thread: the requests ``take`` could not deliver on the executor thread."""
        lock = self._run.engine_lock
        if lock is None:
            self._deliver_queued(record)
            return
        with lock:
            self._deliver_queued(record)

    def _deliver_queued(self, record: ReplierRecord) -> None:
        while record.in_transit:
            self.deliver_request(record, *record.in_transit.popleft())

    def deliver_request(self, record: ReplierRecord, identity: bytes, body: bytes,
                         header, on_loop: bool = True) -> None:
        """On the loop thread, or (``on_loop`` False) on the executor thread holding the
        engine's lock."""
        if record.closed:
            return
        if not record.expires:
            # A get_result is answered when its goal ends, however long that takes (neither
            # rcl_action nor micro_ros_agent times it out): bounded by count, not by time.
            if len(record.pending) >= MAX_HELD_RESULT_REQUESTS:
                del record.pending[next(iter(record.pending))]
                self.requests_timed_out += 1
                log.warning("replier holds %d result requests its XRCE client has not answered: "
                            "the oldest is forgotten", MAX_HELD_RESULT_REQUESTS)
            record.pending[identity] = (header, None)
        else:
            record.pending[identity] = (header, time.monotonic() + self.request_timeout_s)
            if self._waiting_repliers is None:
                self._waiting_repliers = {}
            self._waiting_repliers[record] = None
            if self._reply_sweep is None:
                if on_loop:
                    self._arm_reply_sweep()
                else:
                    self._reply_sweep = True
                    try:
                        self._run.loop().call_soon_threadsafe(self._arm_reply_sweep)
                    except RuntimeError:  # the loop has closed: the agent is going away
                        pass
        try:
            record.on_request(identity, body)
        except Exception:
            log.exception("on_request failed")

    def _arm_reply_sweep(self) -> None:
        """Loop thread: the one timer, due when the oldest waiting request expires."""
        lock = self._run.engine_lock
        if lock is not None:
            with lock:
                self._arm_reply_sweep_locked()
        else:
            self._arm_reply_sweep_locked()

    def _arm_reply_sweep_locked(self) -> None:
        if self._reply_sweep not in (None, True):
            return  # armed already
        waiting = self._waiting_repliers or {}
        due = min((next(iter(record.pending.values()))[1] for record in waiting
                   if record.pending), default=None)
        if due is None:
            self._reply_sweep = None
            return
        self._reply_sweep = self._run.loop().call_later(max(0.0, due - time.monotonic()),
                                                  self._sweep_replies)

    def _sweep_replies(self) -> None:
        """Loop thread: expire what waited ``request_timeout_s``, then arm for the next."""
        lock = self._run.engine_lock
        if lock is not None:
            lock.acquire()
        try:
            self._reply_sweep = None
            now = time.monotonic()
            for record in list(self._waiting_repliers or ()):
                pending = record.pending
                while pending:
                    identity, (_header, deadline) = next(iter(pending.items()))
                    if deadline > now:
                        break
                    del pending[identity]
                    self.requests_timed_out += 1
                    log.warning("replier got no reply from its XRCE client within %.1f s",
                                self.request_timeout_s)
                if not pending or record.closed:
                    del self._waiting_repliers[record]
            self._arm_reply_sweep_locked()
        finally:
            if lock is not None:
                lock.release()

    def write_reply(self, replier: EntityKey, sample_identity: bytes, sample: bytes) -> bool:
        record = self._records.get(replier)
        if record is None or record.kind != "replier":
            return False
        entry = record.pending.pop(bytes(sample_identity), None)
        if entry is None:
            return False
        header = entry[0]
        try:
            if record.raw_reply is not None:
                response = record.raw_reply(ENCAPSULATION_LE + bytes(sample))
            else:
                response = deserialize_message(ENCAPSULATION_LE + bytes(sample),
                                               record.srv.Response)
            Service.send_response(record.service, response, header)
        except Exception as exc:
            log.warning("reply on %r failed: %s", replier, exc)
            return False
        return True
