"""The rclc side of tests/golden/microros/actions_params.jsonl (see its README), boiled down for the
client's parameter and action tests: what each CREATE made (name, types, QoS), the requests the
agent delivered to each replier and the replies rclc wrote, paired by sample identity, and the
samples rclc wrote to each datawriter."""

import json
import re
from pathlib import Path

CAPTURE = Path(__file__).resolve().parents[1] / "golden" / "microros" / "actions_params.jsonl"
_CREATE, _WRITE_DATA, _READ_DATA, _DATA = 1, 7, 8, 9
SAMPLE_IDENTITY_SIZE = 24


def _submessages(data):
    offset = 4 if data[0] >= 0x80 else 8
    while offset + 4 <= len(data):
        sub_id, length = data[offset], data[offset + 2] | (data[offset + 3] << 8)
        yield sub_id, data[offset + 4:offset + 4 + length]
        offset = (offset + 4 + length + 3) & ~3


class RclcCapture:
    def __init__(self, path=CAPTURE):
        self.entities = {}  # object id -> (kind, [printable strings of its representation], body)
        self.requests = {}  # replier object id -> [(sample identity, request body)]
        self.replies = {}  # replier object id -> {sample identity: reply body}
        self.writes = {}  # datawriter object id -> [sample body]
        readers = {}
        for line in path.read_text().splitlines():
            record = json.loads(line)
            data = bytes.fromhex(record["hex"])
            for sub_id, payload in _submessages(data):
                request_id = payload[0] << 8 | payload[1]
                object_id = payload[2] << 8 | payload[3]
                body = payload[4:]
                if record["dir"] == "c2a" and sub_id == _CREATE:
                    texts = [t.decode() for t in re.findall(rb"[ -~]{4,}", body[1:])]
                    self.entities[object_id] = (body[0], texts, body)
                elif record["dir"] == "c2a" and sub_id == _READ_DATA:
                    readers[request_id] = object_id
                elif record["dir"] == "a2c" and sub_id == _DATA and request_id in readers:
                    identity = body[:SAMPLE_IDENTITY_SIZE]
                    self.requests.setdefault(readers[request_id], []).append(
                        (identity, body[SAMPLE_IDENTITY_SIZE:]))
                elif record["dir"] == "c2a" and sub_id == _WRITE_DATA:
                    kind = self.entities.get(object_id, (0,))[0]
                    if kind == 8:  # replier
                        self.replies.setdefault(object_id, {})[body[:SAMPLE_IDENTITY_SIZE]] = \
                            body[SAMPLE_IDENTITY_SIZE:]
                    else:
                        self.writes.setdefault(object_id, []).append(body)

    def replier(self, service_name):
        """Object id of the replier serving ``service_name``."""
        for object_id, (kind, texts, _) in self.entities.items():
            if kind == 8 and texts and texts[0] == service_name:
                return object_id
        raise KeyError(service_name)

    def writer_of(self, topic):
        """(datawriter object id, its representation body) for DDS topic ``topic`` ('rt/...')."""
        for topic_id, (kind, texts, _) in self.entities.items():
            if kind == 2 and texts and texts[0] == topic:
                for object_id, (wkind, _, body) in self.entities.items():
                    # A datawriter's binary representation starts with its topic's id.
                    if wkind == 5 and body[8:10] == bytes((topic_id >> 8, topic_id & 0xFF)):
                        return object_id, body
        raise KeyError(topic)

    def exchanges(self, service_name):
        """[(request body, reply body)] of one service, in the order the requests came."""
        replier = self.replier(service_name)
        answered = self.replies.get(replier, {})
        return [(request, answered.get(identity)) for identity, request in self.requests.get(replier, [])]
