"""Between the engine and the store: what a client tells the agent goes into the store as it
happens (``StateRecorder``'s hooks, called by ``xrce.agent.engine``), and a restarted agent
rebuilds its clients from it (``StateRecorder.restore``) before it opens its links.

The engine calls ``agent.state`` (this object, or None without a store) at each control-plane
change: a session established or deleted, a CREATE or DELETE handled, a READ_DATA that stands
(no sample count, no deadline). The store is committed at the end of the loop's turn, and the
positions of the streams the agent sends on are checked every ``CHECKPOINT_S`` and written when
they moved ``CHECKPOINT_STEP`` numbers past their row (a row per stream is a lower bound, and the
restarted agent leaps far past it anyway, so a row per 10 s of a 30 Hz stream bought nothing but
a write): what a restored stream needs to resume (see ``ResumingStream`` in
xrce.agent.engine.client for the reliable ones; a best-effort one resumes ``BEST_EFFORT_LEAP``
numbers past its checkpoint, which the board takes as newer while its own count is less than
that many past the checkpoint); so are the positions the agent handled on the board's reliable
streams, and at a clean stop all of them as final (``xrce.agent.engine.resync`` says why and how
a restarted agent uses them).

A restored client is a session as the board left it: its objects re-created from the CREATEs
that made them (the ROS entities with them, domains joined as usual), its standing READ_DATAs
in force, the same session id, key and endpoint. It is marked ``restored``; the board, which
never learnt that the agent went away, carries on without a CREATE_CLIENT
(docs/RECOVERY.md).
"""

from __future__ import annotations

import asyncio
import logging
import time
from typing import Dict, Optional, Tuple

from xrce import DecodeError
from xrce.agent.engine.objects import Parked
from xrce.agent.engine.resync import InputResync
from xrce.agent.engine.client import (
    ClientProxy, ObjectEntry, ResumingStream, _hard_liveliness, client_host,
)
from xrce.agent.engine.limits import STREAM_WINDOW
from xrce.agent.state.store import ClientRecord, ObjectRecord, ReadRecord, StateStore
from xrce.wire import constants as C
from xrce.wire.objects import with_kind
from xrce.wire.streams import OutputBestEffortStream, is_reliable, seq_sub
from xrce.wire.submessages import decode_payload

log = logging.getLogger("xrce.agent.state")

CHECKPOINT_S = 10.0
# How far a stream moves before its row is written again: far below the leaps a restored stream
# takes past its row (BEST_EFFORT_LEAP, resync.LEAP), which bound what a crash may lose; a board
# at 30 Hz writes a row every half minute, a 100 Hz one every checkpoint, as before.
CHECKPOINT_STEP = 1024
BEST_EFFORT_LEAP = 0x4000
RESTORE_CREATE_TIMEOUT_S = 30.0


class _Silent:
    """The link of a client being restored: the STATUS its re-created objects would get goes
    nowhere (the board asked for them long ago, from the previous process)."""

    name = "restore"
    sends_from_any_thread = True
    fastpath = None
    info_locators = ()

    def send(self, endpoint, data) -> None:
        pass


def endpoint_json(endpoint):
    """The endpoint as JSON (a UDP address, a serial device and address), None when it has no
    lasting form (a TCP connection: the board has to connect again anyway)."""
    if isinstance(endpoint, (str, int)):
        return endpoint
    if isinstance(endpoint, tuple) and all(isinstance(part, (str, int)) for part in endpoint):
        return list(endpoint)
    return None


def endpoint_from_json(value):
    return tuple(value) if isinstance(value, list) else value


def _padded(data, start: int, end: int) -> Tuple[bytes, int]:
    """A submessage payload kept with the alignment it had in its message (CDR aligns from the
    message start): the pad goes into the flags' high byte."""
    pad = start % 8
    return bytes(pad) + bytes(data[start:end]), pad


def _decode(sub_id: int, flags: int, blob: bytes):
    pad = flags >> 8
    return decode_payload(sub_id, flags & 0xFF, blob, pad, len(blob))


def standing(request) -> bool:
    """A READ_DATA that stays in force until replaced: no count, no deadline (rmw's)."""
    delivery = request.delivery
    return delivery is not None and delivery.max_samples == C.MAX_SAMPLES_UNLIMITED and \
        not delivery.max_elapsed_time and request.stream_id != C.STREAM_NONE


class StateRecorder:
    def __init__(self, store: StateStore, agent, links=()):
        self.store = store
        self.agent = agent
        self.links = list(links)
        # key -> {object id: (the engine's entry, its record)}: what the store holds of each
        # live client, to tell what a CREATE or DELETE changed.
        self._objects: Dict[bytes, Dict[int, Tuple[ObjectEntry, ObjectRecord]]] = {}
        self._reads: Dict[bytes, Dict[int, ReadRecord]] = {}
        self._streams: Dict[bytes, Dict[int, int]] = {}
        # key -> {stream id: (last handled, clean)}: the board's reliable streams as stored.
        self._inputs: Dict[bytes, Dict[int, Tuple[int, bool]]] = {}
        self._commit_handle = None
        self._checkpoint_handle = None
        self.restored = 0
        self.loop: Optional[asyncio.AbstractEventLoop] = None

    # -- engine hooks ------------------------------------------------------------------------

    def client_established(self, client: ClientProxy, flags: int, data, start: int, end: int,
                           restarted: bool) -> None:
        where = endpoint_json(client.endpoint)
        if where is None:
            self.client_deleted(client)
            return
        blob, pad = _padded(data, start, end)
        self.store.put_client(client.key, client.session_id, blob, flags | (pad << 8),
                              client.link.name, where, time.time())
        self._streams.pop(client.key, None)  # (put_client dropped them: the streams start over)
        self._inputs.pop(client.key, None)
        if not restarted:
            self._objects[client.key] = {}
            self._reads[client.key] = {}
        self._commit_soon()

    def client_moved(self, client: ClientProxy) -> None:
        where = endpoint_json(client.endpoint)
        if where is not None and client.key in self._objects:
            self.store.put_endpoint(client.key, client.link.name, where)
            self._commit_soon()

    def client_deleted(self, client: ClientProxy) -> None:
        self._objects.pop(client.key, None)
        self._inputs.pop(client.key, None)
        self._reads.pop(client.key, None)
        self._streams.pop(client.key, None)
        self.store.delete_client(client.key)
        self._commit_soon()

    def objects_changed(self, client: ClientProxy, sub_id: int, flags: int, data, start: int,
                        end: int, request) -> None:
        """After a CREATE or DELETE was handled: the store follows the client's objects (a
        REPLACE or a DELETE takes children with it)."""
        stored = self._objects.get(client.key)
        if stored is None:
            return  # a client the store does not keep (its endpoint has no lasting form)
        current = client.objects
        store = self.store
        changed = False
        for object_id in [oid for oid, (entry, _) in stored.items()
                          if current.get(oid) is not entry]:
            del stored[object_id]
            self._reads.get(client.key, {}).pop(object_id, None)
            store.delete_object(client.key, object_id)
            changed = True
        if sub_id == C.CREATE:
            object_id = with_kind(request.object_id, request.kind)
            entry = current.get(object_id)
            if entry is not None and object_id not in stored:
                blob, pad = _padded(data, start, end)
                record = ObjectRecord(object_id, entry.kind, entry.parent, blob, flags | (pad << 8))
                stored[object_id] = (entry, record)
                store.put_object(client.key, record)
                changed = True
        if self._note_inputs(client):
            changed = True
        if changed:
            self._commit_soon()

    def _note_inputs(self, client: ClientProxy) -> bool:
        """A reliable stream of the board the store has no row for yet gets one now (its
        position as a lower bound): a crash before the next checkpoint still leaves the
        restarted agent knowing which streams to resynchronise and roughly where. Called with
        CREATEs and READ_DATAs, which come on those streams: never per sample."""
        known = self._inputs.setdefault(client.key, {})
        new = [(stream_id, stream.last_handled, False)
               for stream_id, stream in list(client.in_reliable.items()) if stream_id not in known]
        if not new:
            return False
        for stream_id, seq, clean in new:
            known[stream_id] = (seq, clean)
        self.store.put_inputs(client.key, new)
        return True

    def read_data(self, client: ClientProxy, flags: int, data, start: int, end: int,
                  request) -> None:
        reads = self._reads.get(client.key)
        if reads is None or request.object_id not in client.objects:
            return
        if self._note_inputs(client):
            self._commit_soon()
        if standing(request):
            blob, pad = _padded(data, start, end)
            record = ReadRecord(request.object_id, blob, flags | (pad << 8))
            if reads.get(request.object_id) != record:
                reads[request.object_id] = record
                self.store.put_read(client.key, record)
                self._commit_soon()
        elif reads.pop(request.object_id, None) is not None:
            self.store.delete_read(client.key, request.object_id)
            self._commit_soon()

    # -- commits and checkpoints -------------------------------------------------------------

    def _commit_soon(self) -> None:
        loop = self.loop
        if loop is None or loop.is_closed():
            self.store.commit()
        elif self._commit_handle is None:
            self._commit_handle = loop.call_soon(self._commit)

    def _commit(self) -> None:
        self._commit_handle = None
        try:
            self.store.commit()
        except Exception:
            log.warning("state store %s: commit failed", self.store.path, exc_info=True)

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop
        self._checkpoint_handle = loop.call_later(CHECKPOINT_S, self._periodic)

    def _periodic(self) -> None:
        self._checkpoint_handle = self.loop.call_later(CHECKPOINT_S, self._periodic)
        self.checkpoint()

    def checkpoint(self, clean: bool = False) -> None:
        """The stream positions that moved ``CHECKPOINT_STEP`` past their rows (one row each),
        all that moved when ``clean``: the agent is stopping and takes no more input
        (``Agent.close`` paused the compiled paths first), so what it handled on the board's
        streams is at least what the board has had acknowledged: rows marked clean say so."""
        step = 1 if clean else CHECKPOINT_STEP

        def moved_on(stored, seq) -> bool:
            return stored is None or seq_sub(seq, stored) >= step
        written = False
        with self.agent.lock:
            for key, client in list(self.agent.clients.items()):
                if key not in self._objects:
                    continue
                known = self._streams.setdefault(key, {})
                moved = []
                for stream_id, stream in list(client.out_reliable.items()):
                    seq = stream.last_acknowledged
                    if moved_on(known.get(stream_id), seq):
                        moved.append((stream_id, seq))
                for stream_id, stream in list(client.out_best_effort.items()):
                    seq = stream.last_sent
                    if moved_on(known.get(stream_id), seq):
                        moved.append((stream_id, seq))
                if moved:
                    known.update(moved)
                    self.store.put_streams(key, moved)
                inputs = self._inputs.setdefault(key, {})
                handled = []
                for stream_id, stream in list(client.in_reliable.items()):
                    stored = inputs.get(stream_id)
                    seq = stream.last_handled
                    if stored is None or (clean and stored != (seq, True)) or \
                            moved_on(stored[0], seq):
                        inputs[stream_id] = (seq, clean)
                        handled.append((stream_id, seq, clean))
                if handled:
                    self.store.put_inputs(key, handled)
                written = written or bool(moved or handled)
        if written or clean:
            self.store.commit()

    def close(self) -> None:
        """SIGINT/SIGTERM: the stream positions as they are now, then everything to disk."""
        for handle in (self._commit_handle, self._checkpoint_handle):
            if handle is not None:
                handle.cancel()
        self._commit_handle = self._checkpoint_handle = None
        try:
            self.checkpoint(clean=True)
        finally:
            self.store.close()
        log.info("state store %s flushed (%d clients)", self.store.path, len(self._objects))

    # -- restore -----------------------------------------------------------------------------

    def _link_for(self, record: ClientRecord):
        for link in self.links:
            if link.name == record.link:
                return link
        return None

    async def restore(self) -> int:
        """Rebuild every stored client; the number restored. Runs before the links open."""
        records = self.store.clients()
        for record in records:
            try:
                ok = await self._restore_client(record)
            except Exception:
                log.warning("client %s: could not be restored from the store; forgotten",
                            record.key.hex(), exc_info=True)
                ok = False
                partial = self.agent.clients.get(record.key)
                if partial is not None and partial.restored:
                    with self.agent.lock:
                        self.agent.sessions.delete_client(partial)
            if not ok:
                self.store.delete_client(record.key)
        # A clean stop's positions hold for this process's first messages only.
        self.store.inputs_unclean()
        self.store.commit()
        if records:
            log.info("state store %s: %d of %d stored clients restored", self.store.path,
                     self.restored, len(records))
        return self.restored

    async def _restore_client(self, record: ClientRecord) -> bool:
        agent = self.agent
        key = record.key
        link = self._link_for(record)
        endpoint = endpoint_from_json(record.endpoint)
        if link is None or endpoint is None:
            log.info("client %s: stored for link %s, which this agent does not serve; forgotten",
                     key.hex(), record.link)
            return False
        if agent.admission is not None and not agent.admission.admits(key, link, endpoint):
            log.info("client %s: stored, but refused by this agent's admission; forgotten",
                     key.hex())
            return False
        if key in agent.clients or len(agent.clients) >= agent.max_clients:
            log.info("client %s: stored, but no room under --max-clients; forgotten", key.hex())
            return False
        request = _decode(C.CREATE_CLIENT, record.create_flags, record.create_client)
        if request.session_id != record.session_id or bytes(request.client_key) != key:
            raise DecodeError("stored CREATE_CLIENT does not match its row")
        sessions = agent.sessions
        now = agent.clock()
        mtu = request.mtu if request.mtu is not None else 508
        client = ClientProxy(key, request.session_id, mtu, _Silent(), endpoint, now,
                             _hard_liveliness(request.properties))
        client.restored = True
        agent.clients[key] = client
        if request.session_id >= C.SESSION_ID_WITHOUT_KEY_MASK:
            agent.endpoints[(link, endpoint)] = key
        sessions._join_host(client, client_host(link, endpoint), None)
        stored: Dict[int, Tuple[ObjectEntry, ObjectRecord]] = {}
        for obj in record.objects:
            if obj.parent is not None and obj.parent not in client.objects:
                continue  # its parent could not be re-created: neither can it
            entry = await self._recreate(client, obj)
            if entry is not None:
                stored[obj.object_id] = (entry, obj)
        reads: Dict[int, ReadRecord] = {}
        for read in record.reads:
            if read.object_id not in client.objects:
                continue
            agent.datapath.read_data(client, _decode(C.READ_DATA, read.flags, read.payload))
            reads[read.object_id] = read
        # What the re-creation sent went nowhere; from here on the streams are the board's.
        sessions.reset_streams(client)
        client.link = link
        client.resume_inputs = True
        for stream_id, seq in record.streams.items():
            if not is_reliable(stream_id):
                stream = client.out_best_effort[stream_id] = OutputBestEffortStream(stream_id)
                stream.last_sent = (seq + BEST_EFFORT_LEAP) & 0xFFFF
        reliable = {sid: seq for sid, seq in record.streams.items() if is_reliable(sid)}
        for entry in client.objects.values():
            active = entry.reader.active if entry.reader is not None else None
            if active is not None and is_reliable(active.stream_id):
                reliable.setdefault(active.stream_id, 0xFFFF)
            elif active is not None and active.stream_id not in client.out_best_effort:
                stream = client.out_best_effort[active.stream_id] = \
                    OutputBestEffortStream(active.stream_id)
                stream.last_sent = (0xFFFF + BEST_EFFORT_LEAP) & 0xFFFF
        for stream_id, seq in reliable.items():
            client.out_reliable[stream_id] = ResumingStream(stream_id, STREAM_WINDOW, seq)
        client.resuming = bool(reliable)
        # The board's own reliable streams: where to resynchronise them when it speaks.
        client.input_resync = InputResync(record.inputs) if record.inputs else None
        self._inputs[key] = {sid: (seq, False) for sid, (seq, _clean) in record.inputs.items()}
        self._objects[key] = stored
        self._reads[key] = reads
        self._streams[key] = dict(record.streams)
        # Entities the store held that could not be re-created are gone from it too.
        for obj in record.objects:
            if obj.object_id not in stored:
                self.store.delete_object(key, obj.object_id)
        agent.scheduler.wake_at(now)  # its resynchronising HEARTBEATs
        agent.scheduler.wake_at(now + sessions.quiet_limit(client))
        self.restored += 1
        log.info("client %s session 0x%02X restored from the store on %s %r: %d of %d objects, "
                 "%d standing READ_DATAs; carrying on when it speaks", key.hex(),
                 client.session_id, link.name, endpoint, len(stored), len(record.objects),
                 len(reads))
        return True

    async def _recreate(self, client: ClientProxy, obj: ObjectRecord) -> Optional[ObjectEntry]:
        agent = self.agent
        request = _decode(C.CREATE, obj.flags, obj.payload)
        deadline = time.monotonic() + RESTORE_CREATE_TIMEOUT_S
        while True:
            try:
                with agent.lock:
                    agent.objects.create(client, request, C.BUILTIN_RELIABLE)
                break
            except Parked as parked:
                future = parked.future
                if not isinstance(future, asyncio.Future):
                    future = asyncio.wrap_future(future)
                await asyncio.wait_for(future, max(0.1, deadline - time.monotonic()))
        entry = client.objects.get(obj.object_id)
        if entry is None:
            log.warning("client %s: stored object 0x%04X could not be re-created; forgotten",
                        client.key.hex(), obj.object_id)
        return entry
