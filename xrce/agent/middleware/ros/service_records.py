"""The records of the ROS middleware's requesters and repliers (``xrce.agent.middleware.ros.services``):
an XRCE requester is an rclpy service client, an XRCE replier an rclpy service whose responses
are sent when the XRCE client writes its reply.
"""

from __future__ import annotations

import asyncio
import collections
import struct

from rclpy.serialization import serialize_message
from rclpy.service import Service

from xrce.agent.middleware import EntityKey, ReplyCallback, RequestCallback
from xrce.agent.middleware.ros.domain import ENCAPSULATION_SIZE


class TakenRequest:
    """What the replier's service callback returns instead of a response (see ReplierRecord)."""

    __slots__ = ("identity", "body")

    def __init__(self, identity: bytes, body: bytes):
        self.identity = identity
        self.body = body


class RequesterRecord:
    __slots__ = ("participant", "client", "srv", "on_reply", "pending", "waiting", "closed",
                 "client_key", "expires")
    kind = "requester"

    def __init__(self, participant: EntityKey, srv, on_reply: ReplyCallback, expires: bool = True):
        self.participant = participant
        self.expires = expires
        self.client_key = participant[0]  # the XRCE client's, for its pending-request quota
        self.client = None
        self.srv = srv
        self.on_reply = on_reply
        # correlation id -> [rclpy Future or None until sent, expiry TimerHandle or None]
        self.pending: dict[int, list] = {}
        # correlation id -> (entry, request) held until the service server is discovered
        self.waiting: dict[int, tuple] = {}
        self.closed = False


class ReplierRecord:
    """rclpy service whose responses are sent later, when the XRCE client writes its reply.

    rclpy calls ``service.callback(request, response)`` and then ``service.send_response(result,
    header)``. The events executor runs that synchronously and has no coroutine support, and
    blocking in the callback would stall every other entity of the domain for the client's
    round trip. So the callback only records the request and returns a ``TakenRequest``, and the
    instance's ``send_response`` is replaced by ``capture`` which keeps the request header; the
    real ``Service.send_response`` runs from ``write_reply`` on the loop thread.
    """

    __slots__ = ("participant", "service", "srv", "on_request", "pending", "closed",
                 "identity_prefix", "sequence", "loop", "services", "run", "expires",
                 "in_transit", "raw_reply", "next_sequence")
    kind = "replier"

    def __init__(self, participant: EntityKey, srv, on_request: RequestCallback,
                 identity_prefix: bytes, loop: asyncio.AbstractEventLoop, services, run,
                 expires: bool = True):
        self.participant = participant
        self.expires = expires
        self.service = None
        self.srv = srv
        self.on_request = on_request
        # identity -> (request header, monotonic deadline, or None where requests never expire
        # (`expires`)), in arrival (so deadline) order
        self.pending: dict[bytes, tuple] = {}
        self.closed = False
        self.identity_prefix = identity_prefix  # guidPrefix(12) + entityKey(3) + entityKind(1)
        self.sequence = 0
        self.loop = loop
        self.services = services  # the RosServices that delivers its requests
        self.run = run  # the RunContext: the engine's lock
        # Requests handed to the loop and not delivered yet (the engine's lock was taken): later
        # ones follow them through the loop rather than overtake them.
        self.in_transit: collections.deque = collections.deque()
        # The raw reply class when the service exchanges CDR bytes with rclpy
        # (raw_types.raw_service_type), else None: Python messages.
        self.raw_reply = None
        # Where identities come from once the compiled path serves the replier (it gives them
        # to the requests it takes itself): None while they are this record's.
        self.next_sequence = None

    def take(self, request, _unused_response) -> TakenRequest:
        """Service callback (executor thread): ``request`` is its CDR bytes (a raw service
        type), or a Python message."""
        sequence = self.next_sequence() if self.next_sequence is not None else None
        if sequence is None:
            self.sequence += 1
            sequence = self.sequence
        identity = self.identity_prefix + struct.pack("<iI", sequence >> 32,
                                                      sequence & 0xFFFFFFFF)
        if request.__class__ is bytes:
            return TakenRequest(identity, request)
        return TakenRequest(identity, serialize_message(request)[ENCAPSULATION_SIZE:])

    def capture(self, taken, header) -> None:
        """Stands in for ``service.send_response`` (executor thread)."""
        if not isinstance(taken, TakenRequest):
            Service.send_response(self.service, taken, header)
            return
        if self.closed:
            return
        lock = self.run.engine_lock
        if lock is not None and not self.in_transit and lock.acquire(blocking=False):
            try:  # never waits: the loop holds the lock while it waits for this thread
                self.services.deliver_request(self, taken.identity, taken.body, header,
                                              on_loop=False)
            finally:
                lock.release()
            return
        self.in_transit.append((taken.identity, taken.body, header))
        try:
            self.loop.call_soon_threadsafe(self.services.deliver_in_transit, self)
        except RuntimeError:
            self.closed = True


