"""What the compiled receive path's C knows of one client (``CompiledClient``, a client's
``ClientProxy.fast`` while C serves it): its handle in C, the streams and writers registered
there, and how they come back to Python when C lets the client go."""

from __future__ import annotations

import logging

from xrce.agent.engine.compiled.streams import CompiledOutputBestEffort, CompiledOutputStream, \
    CompiledReliableStream, CompiledStream
from xrce.wire.streams import InputBestEffortStream, OutputBestEffortStream

log = logging.getLogger("xrce.agent")


class CompiledClient:
    """What C knows of one client: its handle, streams and writers."""

    __slots__ = ("path", "handle", "streams", "writers", "enabled", "reliable", "out_streams")

    def __init__(self, path: "FastPath", handle: int):
        self.path = path
        self.handle = handle
        self.streams: set = set()
        self.writers: set = set()
        self.enabled = True
        self.reliable = False  # a reliable stream is registered: C needs the budget's room
        self.out_streams: set = set()  # the agent's reliable output streams whose ACKNACKs C takes

    def compile_output(self, client) -> None:
        """Hand the acknowledged point of every reliable output stream not yet compiled to C
        (under the engine's lock: ``StreamOutput.send_on_stream`` uses the streams on other
        threads)."""
        for stream_id, stream in list(client.out_reliable.items()):
            if stream_id not in self.out_streams:
                client.out_reliable[stream_id] = CompiledOutputStream(
                    self.path.receiver, self.handle, stream, client.heartbeat_sent_at is not None)
                self.out_streams.add(stream_id)
                log.debug("client %s: reliable output stream 0x%02X: plain ACKNACKs take the "
                          "compiled path", client.key.hex(), stream_id)

    def probing(self, probing: bool) -> None:
        """Python sends a HEARTBEAT and times the ACKNACK answering it: every ACKNACK is
        Python's meanwhile."""
        if self.out_streams:
            self.path.receiver.set_probing(self.handle, probing)

    def forget_writer(self, client, object_id: int) -> None:
        """Before the writer's publisher is destroyed: C holds no pointer to it afterwards."""
        if object_id in self.writers:
            self.writers.discard(object_id)
            samples, size = self.path.receiver.remove_writer(self.handle, object_id)
            entry = client.objects.get(object_id)
            if entry is not None:
                entry.samples += samples
                entry.sample_bytes += size

    def drop(self, client) -> None:
        """The client is deleted or its streams reset: C forgets it (counters folded first)."""
        path = self.path
        path.fold()
        for object_id in list(self.writers):
            self.forget_writer(client, object_id)
        for stream_id in self.streams:  # the sequence numbers come back to Python
            reliable = client.in_reliable.get(stream_id)
            if isinstance(reliable, CompiledReliableStream):
                partial = reliable.take_partial()  # so does a reassembly under way
                if partial is not None:
                    client.reassembly[stream_id] = bytearray(partial)
                client.in_reliable[stream_id] = reliable.detached()
            elif isinstance(client.in_best_effort.get(stream_id), CompiledStream):
                stream = client.in_best_effort[stream_id] = InputBestEffortStream(stream_id)
                seq = path.receiver.stream_seq(self.handle, stream_id)
                if seq is not None:
                    stream.last_handled = seq
        for stream_id in self.out_streams:  # the acknowledged points come back to Python
            stream = client.out_reliable.get(stream_id)
            if isinstance(stream, CompiledOutputStream):
                path.budget.charge(client, -stream.release())
                client.out_reliable[stream_id] = stream.detached()
        for stream_id, stream in list(client.out_best_effort.items()):
            if isinstance(stream, CompiledOutputBestEffort):
                plain = client.out_best_effort[stream_id] = OutputBestEffortStream(stream_id)
                plain.last_sent = stream.last_sent
        for token, (owner, _object_id) in path.readers.items():
            if owner is client:  # C keeps the subscription and hands every sample over
                path.direct[token] = None
        path.receiver.remove_client(self.handle)
        path.clients.pop(self.handle, None)
        client.fast = None
