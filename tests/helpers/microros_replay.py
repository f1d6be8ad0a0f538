"""Replaying real micro-ROS traffic (tests/golden/microros/, see its README) against a live agent.

``Capture`` reads one capture: the firmware's messages (c2a) and what eProsima's agent answered
(a2c), the latter boiled down to meaning: per boot and request id the STATUS (object id, status
code), the request ids that got a DATA, the INFO/TIMESTAMP_REPLY/STATUS_AGENT answers.

``Replayer`` sends the firmware's side to an agent through a ``Channel`` (a UDP socket per boot, or
a serial pseudo-terminal) and answers as the firmware's client library does:

- its reliable output is flow-controlled and retransmitted by the agent's ACKNACKs (the firmware
  waited for eProsima's; an agent that holds a message back, e.g. while a type builds, gets it
  again);
- it receives the agent's reliable stream as its client library does: in order, duplicates
  dropped, each reliable message and each HEARTBEAT answered with an ACKNACK naming the first
  message missing and the gaps after it (the C client acknowledges every reliable message it
  reads; the captures hold one ACKNACK per reliable message of eProsima's). The firmware's
  recorded ACKNACKs are rewritten to that same state of this agent's stream (the only bytes
  rewritten, as the README says; a test may also give the firmware another client key or
  domain: ``client_key``, ``domain_id``). Acknowledging by count of what eProsima sent would leave an
  agent that sends more (more or larger samples) waiting for acknowledgements, and
  acknowledging up to the highest number seen would hide a lost message;
- it waits where the firmware waited: for the STATUS of each CREATE/DELETE before the next
  message (rmw_microxrcedds creates and deletes synchronously), for the answer to a session-less
  message, and for the DATA answering a cancel READ_DATA (up to the firmware's 1 s, or longer).

What our agent answered is collected the same way as eProsima's, so a test compares the two.
"""

from __future__ import annotations

import gzip
import json
import os
import select
import socket
import threading
import time
from collections import defaultdict
from pathlib import Path

from xrce.wire import constants as C
from xrce import DecodeError
from xrce.wire.streams import InputReliableStream
from xrce.wire.submessages import AckNack, decode_message, encode_message

CAPTURES = Path(__file__).resolve().parents[1] / "golden" / "microros"
FIRMWARE_STREAM = 0x80  # the firmware's reliable output and the agent's reliable output to it
WINDOW = 8  # reliable messages the replay keeps in flight (the C client's history is 16)
INPUT_WINDOW = 64  # the agent's messages held ahead of a missing one (eProsima's sent 23 past one)


def _submessages(data: bytes, start: int):
    """(id, flags, payload bytes) of each submessage, without decoding (FRAGMENT pieces included)."""
    offset = start
    while offset + 4 <= len(data):
        sub_id, flags = data[offset], data[offset + 1]
        length = data[offset + 2] | (data[offset + 3] << 8)
        yield sub_id, flags, data[offset + 4:offset + 4 + length]
        offset = (offset + 4 + length + 3) & ~3


class Answers:
    """What an agent said, by meaning (the README's "compare by meaning, not bytes")."""

    def __init__(self):
        self.statuses = {}  # (boot, request id) -> (object id, status)
        self.data = defaultdict(int)  # (boot, request id) -> DATA count
        self.status_agent = []  # (boot, status) per STATUS_AGENT
        self.infos = defaultdict(int)  # boot -> INFO count
        self.timestamp_replies = defaultdict(int)
        # boot -> the agent's reliable stream 0x80 as the firmware receives it (in order)
        self.reliable = defaultdict(lambda: InputReliableStream(FIRMWARE_STREAM, INPUT_WINDOW))
        self.acked = {}  # boot -> first sequence number of ours the agent has not acknowledged
        self.heartbeats = defaultdict(int)
        # (boot, object id) -> the samples of its DATA in order (a replier's begin with the
        # request's 24-byte sample identity, which the firmware's reply echoes)
        self.samples = defaultdict(list)
        self._fragments = {}  # boot -> bytes of the FRAGMENTs of the message being reassembled

    def note(self, boot: int, message: bytes) -> bool:
        """Record one message from the agent; whether it calls for an ACKNACK (a reliable
        message or a HEARTBEAT, as the firmware's client library answers them)."""
        stream_id = message[1]
        if stream_id != FIRMWARE_STREAM:
            return self._note_in_order(boot, message)
        stream = self.reliable[boot]
        for ordered in stream.receive(message[2] | (message[3] << 8), message):
            self._note_in_order(boot, ordered)
        return True

    def _note_in_order(self, boot: int, message: bytes) -> bool:
        heartbeat = False
        start = 4 if message[0] >= 0x80 else 8
        for sub_id, flags, body in _submessages(message, start):
            if sub_id == C.FRAGMENT:
                # A sample larger than the MTU (reliable stream only): its DATA once whole.
                whole = self._fragments.pop(boot, b"") + body
                if flags & C.FLAG_LAST_FRAGMENT:
                    for inner_id, _inner_flags, inner in _submessages(whole, 0):
                        if inner_id == C.DATA and len(inner) >= 4:
                            self._note_data(boot, inner)
                else:
                    self._fragments[boot] = whole
            elif sub_id == C.STATUS and len(body) >= 6:
                self.statuses[(boot, (body[0] << 8) | body[1])] = ((body[2] << 8) | body[3], body[4])
            elif sub_id == C.DATA and len(body) >= 4:
                self._note_data(boot, body)
            elif sub_id == C.STATUS_AGENT and body:
                self.status_agent.append((boot, body[0]))
            elif sub_id == C.INFO:
                self.infos[boot] += 1
            elif sub_id == C.TIMESTAMP_REPLY:
                self.timestamp_replies[boot] += 1
            elif sub_id == C.ACKNACK and len(body) >= 5 and body[4] == FIRMWARE_STREAM:
                first = body[0] | (body[1] << 8)
                self.acked[boot] = max(self.acked.get(boot, 0), first)
            elif sub_id == C.HEARTBEAT and len(body) >= 5 and body[4] == FIRMWARE_STREAM:
                self.heartbeats[boot] += 1
                heartbeat = True
                for ordered in self.reliable[boot].on_heartbeat(body[0] | (body[1] << 8),
                                                                body[2] | (body[3] << 8)):
                    self._note_in_order(boot, ordered)
        return heartbeat

    def _note_data(self, boot: int, body: bytes) -> None:
        self.data[(boot, (body[0] << 8) | body[1])] += 1
        self.samples[(boot, (body[2] << 8) | body[3])].append(bytes(body[4:]))


class Capture:
    """One capture file: the firmware's messages by boot, and eProsima's answers."""

    def __init__(self, name: str):
        self.name = name
        path = CAPTURES / (name + ".jsonl")
        opened = path.open() if path.exists() else gzip.open(str(path) + ".gz", "rt")
        with opened as lines:
            self.records = [json.loads(line) for line in lines]
        self.steps = []  # (boot, bytes) of every c2a message
        self.times = []  # when each was sent, seconds into the recording
        self.eprosima = Answers()
        boot = 0
        for record in self.records:
            data = bytes.fromhex(record["hex"])
            if record["dir"] == "c2a":
                if data[0] == 0x80 and len(data) > 4 and data[4] == C.CREATE_CLIENT and \
                        any(step[0] == boot and step[1][4] == C.CREATE_CLIENT
                            for step in self.steps if step[1][0] == 0x80):
                    boot += 1  # the firmware came back (new UDP source port)
                self.steps.append((boot, data))
                self.times.append(record["t"])
            else:
                self.eprosima.note(boot, data)
        self.boots = boot + 1

    def requests(self, kinds=(C.CREATE, C.DELETE)):
        """(boot, request id, submessage id) of every CREATE/DELETE (or ``kinds``) the firmware sent."""
        found = []
        for boot, data in self.steps:
            if data[0] < 0x80 or data[0] == 0x80:
                continue
            for sub_id, _flags, body in _submessages(data, 4):
                if sub_id in kinds and len(body) >= 2:
                    found.append((boot, (body[0] << 8) | body[1], sub_id))
        return found

    def cancel_reads(self):
        """(boot, request id, reader id) of every READ_DATA with max_samples 0 on stream none."""
        found = []
        for boot, data in self.steps:
            if data[0] <= 0x80:
                continue
            for sub_id, _flags, body in _submessages(data, 4):
                if sub_id == C.READ_DATA and len(body) >= 12 and body[4] == 0 and body[7] == 1 \
                        and body[8:10] == b"\x00\x00":
                    found.append((boot, (body[0] << 8) | body[1], (body[2] << 8) | body[3]))
        return found


class UdpChannel:
    """One UDP socket per boot (a reset firmware comes back from a new source port)."""

    def __init__(self, port: int, host: str = "127.0.0.1"):
        self.address = (host, port)
        self.sockets = {}

    def socket(self, boot: int) -> socket.socket:
        sock = self.sockets.get(boot)
        if sock is None:
            sock = self.sockets[boot] = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind(("127.0.0.1", 0))
        return sock

    def send(self, boot: int, data: bytes) -> None:
        self.socket(boot).sendto(data, self.address)

    def receive(self, timeout: float):
        """[(boot, message)] that arrived within ``timeout``."""
        if not self.sockets:
            time.sleep(timeout)
            return []
        by_fd = {sock.fileno(): boot for boot, sock in self.sockets.items()}
        ready, _, _ = select.select(list(self.sockets.values()), [], [], timeout)
        got = []
        for sock in ready:
            try:
                while True:
                    data, _ = sock.recvfrom(65536, socket.MSG_DONTWAIT)
                    got.append((by_fd[sock.fileno()], data))
            except BlockingIOError:
                pass
        return got

    def close(self) -> None:
        for sock in self.sockets.values():
            sock.close()
        self.sockets.clear()


class SerialChannel:
    """The agent's serial line (HDLC-like framing, xrce.transports.framing), one boot at a time."""

    def __init__(self, fd: int, local_address: int = 1, agent_address: int = 0):
        from xrce.transports.framing import FrameDecoder, encode_frame

        self.fd = fd
        self._frame = lambda data: encode_frame(data, local_address, agent_address)
        self._decoder = FrameDecoder(local_address)
        self.boot = 0  # one line: what arrives answers the boot that sent last

    def send(self, boot: int, data: bytes) -> None:
        self.boot = boot
        payload = self._frame(data)
        while payload:
            written = os.write(self.fd, payload)
            payload = payload[written:]

    def receive(self, timeout: float):
        ready, _, _ = select.select([self.fd], [], [], timeout)
        if not ready:
            return []
        try:
            chunk = os.read(self.fd, 65536)
        except BlockingIOError:
            return []
        return [(self.boot, payload) for _src, _dst, payload in self._decoder.feed(chunk)]

    def close(self) -> None:
        pass


class Replayer:
    """Send a capture's firmware side to an agent and collect what it answers (module docstring)."""

    def __init__(self, capture: Capture, channel, status_timeout: float = 30.0,
                 cancel_timeout: float = 3.0, domain_id: int | None = None,
                 answer_requests: bool = False, client_key: bytes | None = None):
        self.capture = capture
        # Another client key for the firmware (4 bytes), so that one capture replayed twice is
        # two boards with the same firmware (a fleet): its CREATE_CLIENT's key, and the header's
        # of a session that carries it (ids below 0x80).
        self.client_key = client_key
        # The firmware's replies echo the sample identity of the request DATA eProsima's agent
        # sent it: with ``answer_requests``, the reply to eProsima's n-th request on a replier waits
        # for this agent's n-th request DATA there and echoes its identity instead (derived from
        # the agent's answers, like the ACKNACKs), so that ROS-side callers get their replies.
        self.answer_requests = answer_requests
        # A ROS test's leased domain for the firmware's participant (it asks for domain 0): the
        # one rewrite besides the README's, so that the test's ROS graph stays its own.
        self.domain_id = domain_id
        self.channel = channel
        self.answers = Answers()
        self.status_timeout = status_timeout
        self.cancel_timeout = cancel_timeout
        self.unacked = {}  # (boot, seq) -> message, our reliable messages in flight
        self.sent_at = {}  # (boot, request id) -> monotonic time of the message that carried it
        self.answered_at = {}  # (boot, request id) -> monotonic time its answer arrived
        self.lock = threading.Lock()

    # -- receiving ---------------------------------------------------------------------------

    def pump(self, timeout: float = 0.0) -> None:
        for boot, message in self.channel.receive(timeout):
            now = time.monotonic()
            if not message:
                continue
            before = set(self.answers.statuses) | set(self.answers.data)
            try:
                decode_message(message)  # the agent must send well-formed messages
            except DecodeError as exc:
                raise AssertionError("malformed message from the agent: %s (%s)"
                                     % (message.hex(), exc))
            answer = self.answers.note(boot, message)
            for key in (set(self.answers.statuses) | set(self.answers.data)) - before:
                self.answered_at.setdefault(key, now)
            if answer:
                self._acknack(boot)
            acked = self.answers.acked.get(boot, 0)
            for key in [k for k in self.unacked if k[0] == boot and k[1] < acked]:
                del self.unacked[key]

    def _acknack(self, boot: int) -> None:
        """Acknowledge what the firmware has of the agent's reliable stream: the first message
        missing, and the gaps after it (what the agent retransmits)."""
        first, bitmap = self.answers.reliable[boot].acknack()
        self.channel.send(boot, encode_message(0x81, 0, 0, None,
                                               [AckNack(first, bitmap, FIRMWARE_STREAM)]))

    def wait(self, predicate, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        resend_at = time.monotonic() + 0.2
        while not predicate():
            now = time.monotonic()
            if now >= deadline:
                return False
            if now >= resend_at:  # what the firmware's client does for unacknowledged messages
                for (boot, _seq), message in sorted(self.unacked.items()):
                    self.channel.send(boot, message)
                resend_at = now + 0.2
            self.pump(min(0.02, max(0.0, deadline - now)))
        return True

    # -- sending -----------------------------------------------------------------------------

    def _in_domain(self, data: bytes) -> bytes:
        """``data`` with each CREATE participant's domain id (its last two bytes) set to ours."""
        if self.domain_id is None or data[0] <= 0x80:
            return data
        out = bytearray(data)
        offset = 4
        while offset + 4 <= len(out):
            sub_id, flags = out[offset], out[offset + 1]
            length = out[offset + 2] | (out[offset + 3] << 8)
            if sub_id == C.CREATE and length >= 8 and out[offset + 8] == C.OBJK_PARTICIPANT:
                end = offset + 4 + length
                out[end - 2:end] = self.domain_id.to_bytes(2, "little" if flags & 1 else "big")
            offset = (offset + 4 + length + 3) & ~3
        return bytes(out)

    def _keyed(self, data: bytes) -> bytes:
        """``data`` with the firmware's client key replaced by ``client_key``."""
        if self.client_key is None:
            return data
        out = bytearray(data)
        header = 4 if data[0] & 0x80 else 8
        if header == 8:
            out[4:8] = self.client_key
        offset = header
        while offset + 4 <= len(out):
            sub_id = out[offset]
            length = out[offset + 2] | (out[offset + 3] << 8)
            if sub_id == C.CREATE_CLIENT and length >= 12:
                # after the cookie "XRCE", the version and the vendor id
                out[offset + 12:offset + 16] = self.client_key
            offset = (offset + 4 + length + 3) & ~3
        return bytes(out)

    def _answering(self, boot: int, data: bytes) -> bytes:
        """``data`` with the identity of each reply it carries rewritten (see ``answer_requests``)."""
        if not self.answer_requests or data[0] <= 0x80:
            return data
        out = None
        offset = 4
        while offset + 4 <= len(data):
            sub_id = data[offset]
            length = data[offset + 2] | (data[offset + 3] << 8)
            body = data[offset + 4:offset + 4 + length]
            if sub_id == C.WRITE_DATA and len(body) >= 28:
                key = (boot, (body[2] << 8) | body[3])
                theirs = [sample[:24] for sample in self.capture.eprosima.samples.get(key, ())]
                if body[4:28] in theirs:
                    index = theirs.index(body[4:28])
                    if not self.wait(lambda: len(self.answers.samples.get(key, ())) > index,
                                     self.status_timeout):
                        raise AssertionError("%s: the agent sent no request %d to replier 0x%04X "
                                             "within %.0f s" % (self.capture.name, index + 1,
                                                                key[1], self.status_timeout))
                    out = out or bytearray(data)
                    out[offset + 8:offset + 32] = self.answers.samples[key][index][:24]
            offset = (offset + 4 + length + 3) & ~3
        return data if out is None else bytes(out)

    def _send(self, boot: int, data: bytes) -> None:
        data = self._answering(boot, self._in_domain(self._keyed(data)))
        session, stream_id = data[0], data[1]
        seq = data[2] | (data[3] << 8)
        if session > 0x80 and stream_id == FIRMWARE_STREAM:
            # The firmware's history: never more than WINDOW of its messages unacknowledged.
            if not self.wait(lambda: seq < self.answers.acked.get(boot, 0) + WINDOW,
                             self.status_timeout):
                raise AssertionError("%s: the agent acknowledged nothing up to %d within %.0f s"
                                     % (self.capture.name, seq - WINDOW, self.status_timeout))
            self.unacked[(boot, seq)] = data
        self.channel.send(boot, data)

    def run(self, until_step: int | None = None, speed: float = 0.0, longest_gap: float = 0.5,
            on_step=None, start_step: int = 0) -> Answers:
        """Send the firmware's messages from ``start_step`` up to ``until_step``. ``speed`` > 0
        keeps the recording's pace (1 = real time; gaps over ``longest_gap`` shortened to it), so
        that the ROS side's data and service calls meet the readers and repliers as they did; 0
        goes as fast as the agent answers. ``on_step(index, boot, data)`` runs before each."""
        end = len(self.capture.steps) if until_step is None else until_step
        cancels = {(boot, rid) for boot, rid, _ in self.capture.cancel_reads()}
        started = time.monotonic()
        offset = 0.0
        for index in range(start_step, end):
            boot, data = self.capture.steps[index]
            if on_step is not None:
                on_step(index, boot, data)
            if speed and index > start_step:
                gap = self.capture.times[index] - self.capture.times[index - 1]
                offset += min(gap, longest_gap) / speed
                due = started + offset
                if due > time.monotonic():
                    self.wait(lambda: time.monotonic() >= due, due - time.monotonic() + 1)
            self.pump()
            session = data[0]
            if session > 0x80 and data[1] == 0 and len(data) > 4 and data[4] == C.ACKNACK:
                self._acknack(boot)  # rewritten: what this agent sent, not what eProsima did
                continue
            waits = []
            if session > 0x80:
                for sub_id, _flags, body in _submessages(data, 4):
                    if len(body) < 2:
                        continue
                    rid = (body[0] << 8) | body[1]
                    if sub_id in (C.CREATE, C.DELETE):
                        waits.append(("status", rid))
                    elif sub_id == C.READ_DATA and (boot, rid) in cancels:
                        waits.append(("cancel", rid))
                    self.sent_at.setdefault((boot, rid), time.monotonic())
            before = (len(self.answers.status_agent), self.answers.infos[boot],
                      self.answers.timestamp_replies[boot])
            self._send(boot, data)
            if session == 0x80 or (session > 0x80 and len(data) > 4 and
                                   data[4] in (C.GET_INFO, C.TIMESTAMP)):
                # Session-less requests and pings: the firmware waits for the answer.
                self.wait(lambda: (len(self.answers.status_agent), self.answers.infos[boot],
                                   self.answers.timestamp_replies[boot]) != before, 5.0)
            for what, rid in waits:
                if what == "status":
                    if not self.wait(lambda: (boot, rid) in self.answers.statuses,
                                     self.status_timeout):
                        raise AssertionError("%s: no STATUS for request 0x%04X within %.0f s"
                                             % (self.capture.name, rid, self.status_timeout))
                else:
                    self.wait(lambda: self.answers.data.get((boot, rid)), self.cancel_timeout)
        self.wait(lambda: not self.unacked, 5.0)
        self.pump(0.05)
        return self.answers


class RosSideFeeder:
    """What the rclpy peers did while the captures were recorded, for an agent without ROS
    (``-m ced``): a second XRCE client, on its own ``channel`` (``UdpChannel``/``SerialChannel``),
    that publishes ``/cmd_vel`` (geometry_msgs/Twist) at 30 Hz and, with ``service=True``, calls
    ``/add_two_ints`` three times a second. Creates on stream none, writes best effort."""

    TWIST = "geometry_msgs::msg::dds_::Twist_"
    ADD_TWO_INTS = "example_interfaces::srv::dds_::AddTwoInts_"

    def __init__(self, channel, service: bool = False, period: float = 1 / 30):
        from xrce.wire.objects import (
            DataWriterBin, EndpointQos, ParticipantBin, PubSubBin, RequesterBin, TopicBin,
        )
        from xrce.wire.submessages import Create, CreateClient

        self.channel = channel
        self.period = period
        self.service = service
        self.written = 0
        self._stop = threading.Event()
        self._seq = 0
        self._send(0x80, CreateClient(b"\x0f\xee\xde\xd0", 0x81, 512))
        self._expect(C.STATUS_AGENT)
        creates = [
            Create(1, 0x0011, C.OBJK_PARTICIPANT, C.REPRESENTATION_IN_BINARY,
                   ParticipantBin("ros_side"), 0),
            Create(2, 0x0012, C.OBJK_TOPIC, C.REPRESENTATION_IN_BINARY,
                   TopicBin("rt/cmd_vel", self.TWIST), 0x0011),
            Create(3, 0x0013, C.OBJK_PUBLISHER, C.REPRESENTATION_IN_BINARY, PubSubBin(), 0x0011),
            Create(4, 0x0015, C.OBJK_DATAWRITER, C.REPRESENTATION_IN_BINARY,
                   DataWriterBin(0x0012, EndpointQos(C.QOS_RELIABLE | C.QOS_KEEP_LAST, 10)),
                   0x0013),
        ]
        if service:
            creates.append(Create(5, 0x0017, C.OBJK_REQUESTER, C.REPRESENTATION_IN_BINARY,
                                  RequesterBin("add_two_ints", self.ADD_TWO_INTS + "Request_",
                                               self.ADD_TWO_INTS + "Response_"), 0x0011))
        for create in creates:
            self._send(0x81, create)
            status = self._expect(C.STATUS)
            if status.status != C.STATUS_OK:
                raise RuntimeError("feeder: CREATE 0x%04X answered %d" % (create.object_id,
                                                                          status.status))
        self._thread = threading.Thread(target=self._run, name="ros-side-feeder", daemon=True)
        self._thread.start()

    def _send(self, session: int, payload, stream_id: int = 0) -> None:
        seq = 0
        if stream_id:
            seq, self._seq = self._seq, (self._seq + 1) & 0xFFFF
        self.channel.send(0, encode_message(session, stream_id, seq, None, [payload]))

    def _expect(self, sub_id: int, timeout: float = 10.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for _boot, data in self.channel.receive(0.1):
                for payload in decode_message(data)[1]:
                    if payload.ID == sub_id:
                        return payload
        raise RuntimeError("feeder: no answer %d from the agent" % sub_id)

    def _run(self) -> None:
        import struct

        from xrce.wire.submessages import WriteData

        count = 0
        while not self._stop.wait(self.period):
            count += 1
            twist = struct.pack("<6d", 0.1 * count, 0, 0, 0, 0, 0.01 * count)
            self._send(0x81, WriteData(count & 0xFFFF, 0x0015, twist), stream_id=0x01)
            if self.service and count % 10 == 0:
                self._send(0x81, WriteData(count & 0xFFFF, 0x0017, struct.pack("<qq", count, 2)),
                           stream_id=0x01)
            self.written = count
            self.channel.receive(0)  # drain what the agent sends this client (nothing it needs)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)


# ------------------------------------------------------------ micro-ROS' graph (graph capture)

GRAPH_ENTITY_KINDS = ("publisher", "subscriber", "service server", "service client")


def decode_graph(body: bytes) -> list:
    """A ``micro_ros_msgs/msg/Graph`` CDR body as [(namespace, name, [(kind, entity name,
    (types...)), ...]), ...], read as rmw_microxrcedds reads it (little endian, as both agents
    send it)."""
    from xrce.wire.cdr import CdrReader

    reader = CdrReader(body)
    nodes = []
    for _ in range(reader.u32()):
        namespace, name = reader.string(), reader.string()
        entities = []
        for _ in range(reader.u32()):
            kind, entity = reader.u8(), reader.string()
            entities.append((GRAPH_ENTITY_KINDS[kind], entity,
                             tuple(reader.string() for _ in range(reader.u32()))))
        nodes.append((namespace, name, entities))
    return nodes


class BoardView:
    """What rmw_microxrcedds answers from one Graph: ``rcl_get_node_names``,
    ``rcl_get_topic_names_and_types`` (publishers' and subscribers' names with their types),
    ``rcl_count_publishers/subscribers`` (entities of that kind and name over all nodes) and the
    service names and types."""

    def __init__(self, graph: list):
        self.nodes = sorted((namespace.rstrip("/") + "/" + name) for namespace, name, _ in graph)
        self.topics = defaultdict(set)
        self.services = defaultdict(set)
        self.counts = defaultdict(int)  # (kind, name) -> entities
        self.by_node = {}
        for namespace, name, entities in graph:
            self.by_node[namespace.rstrip("/") + "/" + name] = entities
            for kind, entity, types in entities:
                self.counts[(kind, entity)] += 1
                target = self.topics if kind in ("publisher", "subscriber") else self.services
                target[entity].update(types)

    def node_topics(self, node: str) -> set:
        """(kind, topic, types) of one node's publishers and subscribers."""
        return {(kind, entity, types) for kind, entity, types in self.by_node.get(node, ())
                if kind in ("publisher", "subscriber")}
