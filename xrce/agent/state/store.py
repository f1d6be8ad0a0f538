"""The durable store of what clients told the agent (issue 51): one SQLite database in WAL mode.

What is kept, per client key: its CREATE_CLIENT as received (session id, mtu, properties), the
link and endpoint it spoke from, every object it created as the CREATE submessage that created it
(its representation, XML, reference or binary, and its parent are inside), each standing READ_DATA
as received, the last known sequence number of each stream the agent sends on, and the last one
the agent handled of each reliable stream the board sends on (``inputs``). Nothing here
knows the engine: rows are plain bytes, numbers and text (``xrce.agent.state.recorder`` turns the
engine's objects into them and back).

Writes happen on the control plane only (a session, a creation, a deletion, a standing READ_DATA)
and at a slow checkpoint of stream positions, never per sample. Changes are collected in one
transaction and committed at the end of the event loop's turn (``commit``): the commit is synced
to disk (``synchronous=FULL``), so a SIGKILL or a power cut loses at most the turn's change in
flight.

The schema is versioned (``PRAGMA user_version``): a newer xrce reads an older store through
``MIGRATIONS``; a store it cannot read (written by a newer xrce, or not a database) is moved
aside, said in one line, and a clean one started.
"""

from __future__ import annotations

import json
import logging
import os
import sqlite3
from typing import Dict, Iterable, List, NamedTuple, Optional, Tuple

log = logging.getLogger("xrce.agent.state")

SCHEMA_VERSION = 2
FILE_MODE = 0o600  # it holds client keys

_SCHEMA_V1 = """
CREATE TABLE IF NOT EXISTS clients (
    key BLOB PRIMARY KEY,
    session_id INTEGER NOT NULL,
    create_client BLOB NOT NULL,   -- the CREATE_CLIENT payload as received
    create_flags INTEGER NOT NULL,
    link TEXT NOT NULL,            -- the link's name (udp4, serial, ...)
    endpoint TEXT NOT NULL,        -- where it spoke from, as JSON
    stored_at REAL NOT NULL        -- wall clock of the session's establishment
);
CREATE TABLE IF NOT EXISTS objects (
    key BLOB NOT NULL REFERENCES clients(key) ON DELETE CASCADE,
    object_id INTEGER NOT NULL,
    kind INTEGER NOT NULL,
    parent INTEGER,
    create_payload BLOB NOT NULL,  -- the CREATE submessage payload (its representation inside)
    create_flags INTEGER NOT NULL,
    ordinal INTEGER NOT NULL,      -- creation order: parents before children on restore
    PRIMARY KEY (key, object_id)
);
CREATE TABLE IF NOT EXISTS reads (
    key BLOB NOT NULL REFERENCES clients(key) ON DELETE CASCADE,
    object_id INTEGER NOT NULL,
    request BLOB NOT NULL,         -- the READ_DATA payload as received
    request_flags INTEGER NOT NULL,
    PRIMARY KEY (key, object_id)
);
CREATE TABLE IF NOT EXISTS streams (
    key BLOB NOT NULL REFERENCES clients(key) ON DELETE CASCADE,
    stream_id INTEGER NOT NULL,    -- an output stream of the agent towards this client
    seq INTEGER NOT NULL,          -- reliable: last acknowledged, best effort: last sent
    PRIMARY KEY (key, stream_id)
);
"""

# Version 2: where the board's reliable output streams were. eProsima's client sends a HEARTBEAT
# only after 100 ms without anything to read, so a board fed at 10 Hz or more never says where
# it is, and waits for an ACKNACK that a new process cannot write without knowing (see
# xrce.agent.engine.resync). ``clean`` is 1 when the row was written by a clean stop (SIGINT,
# SIGTERM: nothing was acknowledged after it), 0 for a periodic checkpoint (a lower bound).
_SCHEMA_V2 = """
CREATE TABLE IF NOT EXISTS inputs (
    key BLOB NOT NULL REFERENCES clients(key) ON DELETE CASCADE,
    stream_id INTEGER NOT NULL,    -- a reliable stream the client sends on
    seq INTEGER NOT NULL,          -- the last sequence number the agent handled on it
    clean INTEGER NOT NULL,
    PRIMARY KEY (key, stream_id)
);
"""

# version -> the statements that bring a store of that version to the next one.
MIGRATIONS: Dict[int, str] = {
    0: _SCHEMA_V1,  # an empty database (a new file)
    1: _SCHEMA_V2,
}


class ObjectRecord(NamedTuple):
    object_id: int
    kind: int
    parent: Optional[int]
    payload: bytes
    flags: int


class ReadRecord(NamedTuple):
    object_id: int
    payload: bytes
    flags: int


class ClientRecord(NamedTuple):
    key: bytes
    session_id: int
    create_client: bytes
    create_flags: int
    link: str
    endpoint: object  # JSON-decoded: lists where the link had tuples
    stored_at: float
    objects: List[ObjectRecord]
    reads: List[ReadRecord]
    streams: Dict[int, int]
    inputs: Dict[int, Tuple[int, bool]]  # stream id -> (last handled, written by a clean stop)


class StoreError(Exception):
    """The store cannot be opened at all (its directory cannot be created or written)."""


def _open_file(path: str) -> None:
    """Create the file (and its directory) readable by its owner only, before SQLite opens it:
    SQLite gives its -wal and -shm files the database file's mode."""
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, mode=0o700, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, FILE_MODE)
    try:
        os.fchmod(fd, FILE_MODE)
    finally:
        os.close(fd)


class StateStore:
    """The store at ``path``. Every method runs on the agent's loop thread."""

    def __init__(self, path: str):
        self.path = path
        self.commits = 0
        self._dirty = False
        try:
            self._db = self._connect()
        except (sqlite3.DatabaseError, _Unreadable) as exc:
            aside = _aside_name(path)
            log.warning("state store %s cannot be read (%s): moved to %s, starting clean",
                        path, exc, aside)
            for suffix in ("-wal", "-shm"):
                try:
                    os.unlink(path + suffix)
                except FileNotFoundError:
                    pass
            os.replace(path, aside)
            self._db = self._connect()
        except OSError as exc:
            raise StoreError("cannot open state store %s: %s" % (path, exc.strerror or exc))

    def _connect(self) -> sqlite3.Connection:
        _open_file(self.path)
        db = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False)
        try:
            mode = db.execute("PRAGMA journal_mode=WAL").fetchone()[0]
            if mode.lower() != "wal":
                raise _Unreadable("journal mode %s, not WAL" % mode)
            db.execute("PRAGMA synchronous=FULL")
            db.execute("PRAGMA foreign_keys=ON")
            version = db.execute("PRAGMA user_version").fetchone()[0]
            if version > SCHEMA_VERSION:
                raise _Unreadable("written by a newer xrce: schema %d, this one reads up to %d"
                                  % (version, SCHEMA_VERSION))
            if version < SCHEMA_VERSION:
                db.execute("BEGIN IMMEDIATE")
                for step in range(version, SCHEMA_VERSION):
                    for statement in _statements(MIGRATIONS[step]):
                        db.execute(statement)
                db.execute("PRAGMA user_version=%d" % SCHEMA_VERSION)
                db.execute("COMMIT")
                if version:
                    log.info("state store %s: schema %d upgraded to %d", self.path, version,
                             SCHEMA_VERSION)
            # Fails here, not at the first write, on a file that is not a database.
            db.execute("SELECT count(*) FROM clients").fetchone()
        except BaseException:
            db.close()
            raise
        return db

    # -- writes (one transaction per loop turn: see ``commit``) ------------------------------

    def _begin(self) -> sqlite3.Connection:
        if not self._dirty:
            self._db.execute("BEGIN")
            self._dirty = True
        return self._db

    def put_client(self, key: bytes, session_id: int, create_client: bytes, create_flags: int,
                   link: str, endpoint, stored_at: float) -> None:
        """A session established. Its objects and READ_DATAs stay (a session restarted keeps
        its objects for REUSE; a new session of the key was preceded by ``delete_client``); its
        stream positions go: the streams start over."""
        db = self._begin()
        db.execute("INSERT INTO clients VALUES (?, ?, ?, ?, ?, ?, ?) ON CONFLICT(key) DO UPDATE "
                   "SET session_id = excluded.session_id, create_client = excluded.create_client, "
                   "create_flags = excluded.create_flags, link = excluded.link, "
                   "endpoint = excluded.endpoint, stored_at = excluded.stored_at",
                   (key, session_id, create_client, create_flags, link,
                    json.dumps(endpoint), stored_at))
        db.execute("DELETE FROM streams WHERE key = ?", (key,))
        db.execute("DELETE FROM inputs WHERE key = ?", (key,))

    def put_endpoint(self, key: bytes, link: str, endpoint) -> None:
        self._begin().execute("UPDATE clients SET link = ?, endpoint = ? WHERE key = ?",
                              (link, json.dumps(endpoint), key))

    def delete_client(self, key: bytes) -> None:
        self._begin().execute("DELETE FROM clients WHERE key = ?", (key,))

    def put_object(self, key: bytes, record: ObjectRecord) -> None:
        db = self._begin()
        db.execute("DELETE FROM objects WHERE key = ? AND object_id = ?", (key, record.object_id))
        db.execute("INSERT INTO objects SELECT ?, ?, ?, ?, ?, ?, "
                   "coalesce(max(ordinal), 0) + 1 FROM objects WHERE key = ?",
                   (key, record.object_id, record.kind, record.parent, record.payload,
                    record.flags, key))

    def delete_object(self, key: bytes, object_id: int) -> None:
        db = self._begin()
        db.execute("DELETE FROM objects WHERE key = ? AND object_id = ?", (key, object_id))
        db.execute("DELETE FROM reads WHERE key = ? AND object_id = ?", (key, object_id))

    def put_read(self, key: bytes, record: ReadRecord) -> None:
        self._begin().execute("INSERT OR REPLACE INTO reads VALUES (?, ?, ?, ?)",
                              (key, record.object_id, record.payload, record.flags))

    def delete_read(self, key: bytes, object_id: int) -> None:
        self._begin().execute("DELETE FROM reads WHERE key = ? AND object_id = ?",
                              (key, object_id))

    def put_streams(self, key: bytes, streams: Iterable[Tuple[int, int]]) -> None:
        self._begin().executemany("INSERT OR REPLACE INTO streams VALUES (?, ?, ?)",
                                  [(key, stream_id, seq) for stream_id, seq in streams])

    def put_inputs(self, key: bytes, inputs: Iterable[Tuple[int, int, bool]]) -> None:
        self._begin().executemany("INSERT OR REPLACE INTO inputs VALUES (?, ?, ?, ?)",
                                  [(key, stream_id, seq, int(clean))
                                   for stream_id, seq, clean in inputs])

    def inputs_unclean(self) -> None:
        """What a clean stop wrote holds no more once a new process runs: from now on a crash
        leaves lower bounds only."""
        self._begin().execute("UPDATE inputs SET clean = 0 WHERE clean != 0")

    def pending(self) -> bool:
        return self._dirty

    def commit(self) -> None:
        if self._dirty:
            self._dirty = False
            self._db.execute("COMMIT")
            self.commits += 1

    def close(self) -> None:
        self.commit()
        try:
            # What the WAL holds goes into the database file: one file to copy or inspect.
            self._db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        except sqlite3.DatabaseError:
            pass
        self._db.close()

    # -- reads --------------------------------------------------------------------------------

    def clients(self) -> List[ClientRecord]:
        db = self._db
        objects: Dict[bytes, List[ObjectRecord]] = {}
        for row in db.execute("SELECT key, object_id, kind, parent, create_payload, create_flags "
                              "FROM objects ORDER BY key, ordinal"):
            objects.setdefault(bytes(row[0]), []).append(ObjectRecord(*row[1:4], bytes(row[4]),
                                                                      row[5]))
        reads: Dict[bytes, List[ReadRecord]] = {}
        for row in db.execute("SELECT key, object_id, request, request_flags FROM reads"):
            reads.setdefault(bytes(row[0]), []).append(ReadRecord(row[1], bytes(row[2]), row[3]))
        streams: Dict[bytes, Dict[int, int]] = {}
        for key, stream_id, seq in db.execute("SELECT key, stream_id, seq FROM streams"):
            streams.setdefault(bytes(key), {})[stream_id] = seq
        inputs: Dict[bytes, Dict[int, Tuple[int, bool]]] = {}
        for key, stream_id, seq, clean in db.execute("SELECT key, stream_id, seq, clean "
                                                     "FROM inputs"):
            inputs.setdefault(bytes(key), {})[stream_id] = (seq, bool(clean))
        records = []
        for row in db.execute("SELECT key, session_id, create_client, create_flags, link, "
                              "endpoint, stored_at FROM clients ORDER BY stored_at"):
            key = bytes(row[0])
            try:
                endpoint = json.loads(row[5])
            except ValueError:
                endpoint = None
            records.append(ClientRecord(key, row[1], bytes(row[2]), row[3], row[4], endpoint,
                                        row[6], objects.get(key, []), reads.get(key, []),
                                        streams.get(key, {}), inputs.get(key, {})))
        return records

    def counts(self) -> Dict[str, int]:
        return {table: self._db.execute("SELECT count(*) FROM %s" % table).fetchone()[0]
                for table in ("clients", "objects", "reads", "streams", "inputs")}


class _Unreadable(Exception):
    pass


def _statements(script: str) -> List[str]:
    return [s.strip() for s in script.split(";") if s.strip()]


def _aside_name(path: str) -> str:
    for index in range(1, 1000):
        candidate = "%s.unreadable-%d" % (path, index)
        if not os.path.exists(candidate):
            return candidate
    return path + ".unreadable"


def default_directory(environ=None) -> str:
    """``$XDG_STATE_HOME/xrce``, or ``~/.local/state/xrce`` (the XDG base directory rule)."""
    environ = os.environ if environ is None else environ
    base = environ.get("XDG_STATE_HOME")
    if not base or not os.path.isabs(base):
        base = os.path.join(os.path.expanduser("~"), ".local", "state")
    return os.path.join(base, "xrce")


def default_name(transport: str, where: str) -> str:
    """One store per transport and port or device: ``udp4-8888.sqlite3``,
    ``serial-dev-ttyUSB0.sqlite3``."""
    safe = "".join(c if c.isalnum() or c in "._" else "-" for c in where.strip("/"))
    return "%s-%s.sqlite3" % (transport, safe or "default")
