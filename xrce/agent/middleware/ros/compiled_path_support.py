"""What the engine's compiled receive path (``xrce.agent.engine.compiled.fastpath``) gets of the ROS
middleware's entities: ``RosCompiledPathSupport``, the middleware's ``CompiledPathSupport``
(``RosMiddleware.compiled_path_support()``). The addresses of the rcl publishers, subscriptions
and services C uses instead of rclpy, and the hand-over of a replier's request identities.
"""

from __future__ import annotations

from xrce.agent.middleware import CompiledPathSupport, EntityKey


class RosCompiledPathSupport(CompiledPathSupport):
    """``records``: the middleware's ``EntityRecords``; ``services``: its ``RosServices``, which
    count the requests that timed out (``requests_timed_out``) wherever they were held."""

    # The compiled path starts its identities this far beyond the record's last: a request
    # rclpy's executor is taking while the path takes the replier over keeps a number of its own.
    SEQUENCE_GAP = 1 << 16

    def __init__(self, records, services, request_timeout_s: float):
        self._records = records
        self._services = services
        self.request_timeout_s = request_timeout_s

    def count_timed_out_requests(self, count: int) -> None:
        self._services.count_timed_out(count)

    def publisher_address(self, writer: EntityKey) -> int | None:
        """The address of a datawriter's rcl_publisher_t, for the compiled UDP path, which must
        forget it before ``delete``; None if rclpy hides it, or if its samples are rewritten on
        the way (``roundtrip``): C would publish them as they came."""
        record = self._records.get(writer)
        if record is None or record.kind != "datawriter" or record.rewrite is not None:
            return None
        return getattr(getattr(record.publisher, "handle", None), "pointer", None)

    def subscription_address(self, reader: EntityKey) -> int | None:
        """The address of a datareader's rcl_subscription_t, for the compiled UDP path, which
        takes its samples from then on and must let go of it before ``delete``; None if rclpy
        hides it, or if its samples are translated for its board (``roundtrip``): C would
        deliver them as they came."""
        record = self._records.get(reader)
        if record is None or record.kind != "datareader" or record.translated:
            return None
        return getattr(getattr(record.subscription, "handle", None), "pointer", None)

    def replier_service(self, replier: EntityKey):
        """What the compiled UDP path needs to take a replier's requests and send its replies
        itself: (rcl_service_t address, (request type support, create, destroy) capsules, the
        same of the response, identity prefix, last sequence number, request timeout in s or 0
        for never); None if rclpy hides any of it. The path then gives the identities, also to
        the requests rclpy's executor still delivers (``replier_sequence_from``)."""
        record = self._records.get(replier)
        if record is None or record.kind != "replier" or record.closed or record.service is None:
            return None
        address = getattr(getattr(record.service, "handle", None), "pointer", None)
        srv = record.service.srv_type
        parts = []
        for message in (srv.Request, srv.Response):
            capsules = (getattr(message, "_TYPE_SUPPORT", None),
                        getattr(message, "_CREATE_ROS_MESSAGE", None),
                        getattr(message, "_DESTROY_ROS_MESSAGE", None))
            if None in capsules:
                return None
            parts.append(capsules)
        if not address:
            return None
        return (address, parts[0], parts[1], record.identity_prefix,
                record.sequence + self.SEQUENCE_GAP,
                self.request_timeout_s if record.expires else 0.0)

    def replier_sequence_from(self, replier: EntityKey, next_sequence) -> None:
        """From now on the replier's identities come from ``next_sequence()`` (None: from the
        record again)."""
        record = self._records.get(replier)
        if record is not None and record.kind == "replier":
            record.next_sequence = next_sequence
