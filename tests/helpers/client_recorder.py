"""A real client ``Session`` over a transport that only records what it sends (no agent): for
checking the requests and samples the client's parameter and action code puts on the wire against
what rclc put there in tests/golden/microros/actions_params.jsonl."""

from client_capture import SAMPLE_IDENTITY_SIZE, _submessages
from xrce.client.session import Session
from xrce.transports.custom import CustomTransport

_CREATE, _WRITE_DATA = 1, 7


class RecordingSession:
    def __init__(self):
        self.sent = []
        transport = CustomTransport(lambda user: True, lambda user: True, self._write,
                                    lambda user, buf, size, timeout_ms: 0, framing=False)
        # Large history: nothing acknowledges, and a full window would make the session wait.
        self.session = Session(transport, auto_recover=False, history=64)

    def _write(self, user, data):
        self.sent.append(bytes(data))
        return len(data)

    def take(self):
        """[(submessage id, object id, body)] of everything sent since the last call."""
        self.session.flush()
        out = []
        for message in self.sent:
            for sub_id, payload in _submessages(message):
                out.append((sub_id, payload[2] << 8 | payload[3], payload[4:]))
        self.sent = []
        return out

    def creations(self):
        return [(oid, body) for sub_id, oid, body in self.take() if sub_id == _CREATE]

    def writes(self):
        return [(oid, body) for sub_id, oid, body in self.take() if sub_id == _WRITE_DATA]

    def serve(self, replier_id, identity, request_body):
        """Hand a request to the replier's callback as the session's input path does; returns the
        reply body it wrote (after its sample identity). Everything it wrote stays in ``last_writes``."""
        callback, msg_class = self.session._readers[replier_id]
        callback(identity, msg_class.from_bytes(request_body))
        self.last_writes = self.writes()
        replies = [body for oid, body in self.last_writes if oid == replier_id]
        assert len(replies) == 1 and replies[0][:SAMPLE_IDENTITY_SIZE] == identity, replies
        return replies[0][SAMPLE_IDENTITY_SIZE:]
