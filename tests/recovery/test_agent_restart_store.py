"""The agent's state store (issue 51), in-process: the SQLite file itself (schema version, mode
0600, size bounded under churn, an unreadable one moved aside), and the engine restarted over it
with boards that never send CREATE_CLIENT again (scripted clients, tests/helpers/engine_peer.py,
with CED behind the engine): their samples flow again, both ways, reliable streams resynchronised
from the board's HEARTBEAT and ACKNACK.
"""

import asyncio
import logging
import os
import sqlite3

import pytest

from engine_peer import Clock, Link, Peer, data_of, talker_and_listener
from xrce.agent.engine.agent import Agent
from xrce.agent.engine.client import ResumingStream
from xrce.agent.middleware.ced import CedMiddleware
from xrce.agent.state import recorder as recorder_module, store as store_module
from xrce.agent.state.recorder import StateRecorder
from xrce.agent.state.store import SCHEMA_VERSION, StateStore
from xrce.wire import constants as C
from xrce.wire.submessages import AckNack, DeliveryControl, Heartbeat, encode_message


def _store(tmp_path):
    return StateStore(str(tmp_path / "state" / "agent.sqlite3"))


def _agent(store, link):
    agent = Agent(CedMiddleware())
    agent.clock = Clock()
    agent.state = StateRecorder(store, agent, [link])
    return agent


def _restart(agent, tmp_path, link):
    """What SIGINT does to the first agent's store (flushed, closed), then a new agent over it."""
    agent.state.close()
    agent.state = None
    store = _store(tmp_path)
    again = _agent(store, link)
    restored = asyncio.run(again.state.restore())
    return again, restored


def _crash(agent, tmp_path, link):
    """SIGKILL: the first agent's store is left as its last commit left it."""
    agent.state.store.commit()
    again = _agent(_store(tmp_path), link)
    restored = asyncio.run(again.state.restore())
    return again, restored


# -- the store file -------------------------------------------------------------------------------

def test_store_is_private_and_versioned(tmp_path):
    store = _store(tmp_path)
    store.put_client(b"\x01\x02\x03\x04", 0x81, b"x", 1, "udp4", ["10.0.0.7", 4000], 1.0)
    store.commit()
    path = store.path
    assert os.stat(path).st_mode & 0o777 == 0o600
    for suffix in ("-wal", "-shm"):
        if os.path.exists(path + suffix):
            assert os.stat(path + suffix).st_mode & 0o777 == 0o600
    store.close()
    db = sqlite3.connect(path)
    assert db.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION
    assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    db.close()
    again = StateStore(path)  # an older-or-equal store is read as it is
    assert [r.key for r in again.clients()] == [b"\x01\x02\x03\x04"]
    again.close()


def test_store_of_a_newer_xrce_is_moved_aside_with_one_line(tmp_path, caplog):
    store = _store(tmp_path)
    store.put_client(b"\x01\x02\x03\x04", 0x81, b"x", 1, "udp4", ["10.0.0.7", 4000], 1.0)
    store.close()
    db = sqlite3.connect(store.path)
    db.execute("PRAGMA user_version=%d" % (SCHEMA_VERSION + 1))
    db.commit()
    db.close()
    with caplog.at_level(logging.WARNING, logger="xrce.agent.state"):
        clean = StateStore(store.path)
    lines = [r.getMessage() for r in caplog.records if r.name == "xrce.agent.state"]
    assert len(lines) == 1 and "newer xrce" in lines[0] and "starting clean" in lines[0], lines
    assert clean.clients() == []
    clean.close()
    assert os.path.exists(store.path + ".unreadable-1")


def test_store_that_is_not_a_database_is_moved_aside(tmp_path, caplog):
    path = tmp_path / "state" / "agent.sqlite3"
    path.parent.mkdir()
    path.write_bytes(b"this is not sqlite" * 100)
    with caplog.at_level(logging.WARNING, logger="xrce.agent.state"):
        clean = StateStore(str(path))
    assert any("cannot be read" in r.getMessage() for r in caplog.records)
    assert clean.clients() == []
    clean.close()


def test_store_stays_bounded_under_a_day_of_board_churn(tmp_path):
    """Boards that reset and re-create everything, over and over: the file holds what exists."""
    link = Link()
    store = _store(tmp_path)
    agent = _agent(store, link)
    sizes = []
    for cycle in range(300):
        # A reset board's new session (another id): the old one and its objects go.
        peer = Peer(agent, link, ("h", 1000 + cycle % 7), key=bytes((1, 2, 3, 4 + cycle % 7)),
                    session_id=0x81 + (cycle // 7) % 2)
        link.sent.clear()
        peer.connect()
        peer.build_pubsub()
        peer.read(delivery=DeliveryControl())
        if cycle % 50 == 49:
            agent.state.checkpoint()
            sizes.append(os.path.getsize(store.path) + os.path.getsize(store.path + "-wal"))
    counts = store.counts()
    assert counts["clients"] == 7 and counts["objects"] == 7 * 6 and counts["reads"] == 7, counts
    # The WAL is reused once checkpointed: the last measurements do not keep growing.
    assert sizes[-1] <= max(sizes[:3]) * 1.5, sizes


def test_steady_checkpoints_write_nothing_until_a_stream_moves_a_step(tmp_path):
    """The store is written on the control plane, never per sample: a checkpoint writes a
    stream's row again only once it moved CHECKPOINT_STEP numbers (the restarted agent leaps far
    past its row anyway), and a clean stop writes every stream's exact position."""
    link = Link()
    store = _store(tmp_path)
    agent = _agent(store, link)
    talker, listener = talker_and_listener(agent, link)
    listener.read(delivery=DeliveryControl())
    agent.state.checkpoint()  # the streams' first rows
    statements = []
    store._db.set_trace_callback(statements.append)
    for n in range(40):  # four seconds of a 10 Hz robot, checkpointed every tenth sample
        talker.write(b"s%d" % n)
        listener.ack_all()
        if n % 10 == 9:
            agent.state.checkpoint()
    assert statements == [], statements
    talker_stream = agent.clients[talker.key].in_reliable[0x80]
    for n in range(40, 40 + recorder_module.CHECKPOINT_STEP):
        talker.write(b"s%d" % n)
        listener.take()
        listener.ack_all()
    agent.state.checkpoint()
    writes = [s for s in statements if s.lstrip().upper().startswith(("INSERT", "UPDATE", "REPLACE"))]
    assert writes and any("COMMIT" in s.upper() for s in statements), statements
    store._db.set_trace_callback(None)
    agent.state.close()  # SIGINT: the exact positions, marked clean
    again = _store(tmp_path)
    record = {r.key: r for r in again.clients()}[talker.key]
    assert record.inputs[0x80] == (talker_stream.last_handled, True)
    again.close()


# -- the engine restarted over its store --------------------------------------------------------

def _resync(peer, agent, first_unacked):
    """The board's side of the resynchronisation: the agent's HEARTBEAT on 0x80, answered with
    the ACKNACK the board's input stream computes (first_unacked: what it expects next)."""
    heartbeats = [p for _, ps in peer.take() for p in ps if p.ID == C.HEARTBEAT]
    assert heartbeats, "no HEARTBEAT asking the board where its stream is"
    assert all(h.stream_id == 0x80 for h in heartbeats)
    # Never announced past what the board has had (the stored checkpoint at most).
    assert all(h.last_unacked == (first_unacked - 1) & 0xFFFF or
               (first_unacked - 1 - h.last_unacked) & 0xFFFF < 0x8000 for h in heartbeats)
    peer.send(0, AckNack(first_unacked, 0, 0x80))


@pytest.mark.parametrize("stop", ["sigint", "sigkill"])
def test_boards_carry_on_without_create_client(tmp_path, stop):
    link = Link()
    agent = _agent(_store(tmp_path), link)
    talker, listener = talker_and_listener(agent, link)
    listener.read(delivery=DeliveryControl())  # standing: unlimited, no deadline
    listener.take()
    for n in range(5):
        talker.write(b"before-%d" % n)
    got = data_of(listener.take())
    assert got == [b"before-%d" % n for n in range(5)]
    listener.ack_all()
    board_expects = (agent.clients[listener.key].out_reliable[0x80].last_sent + 1) & 0xFFFF
    if stop == "sigkill":
        # Samples after the last checkpoint: the store's position lags the board's.
        agent.state.checkpoint()
        for n in range(3):
            talker.write(b"late-%d" % n)
        assert len(data_of(listener.take())) == 3
        listener.ack_all()
        board_expects = (agent.clients[listener.key].out_reliable[0x80].last_sent + 1) & 0xFFFF
        link.sent.clear()
        agent2, restored = _crash(agent, tmp_path, link)
    else:
        link.sent.clear()
        agent2, restored = _restart(agent, tmp_path, link)
    assert restored == 2
    assert set(agent2.clients) == {talker.key, listener.key}
    assert all(c.restored and not c.spoken for c in agent2.clients.values())
    # Nothing was sent while restoring (the STATUS of re-created objects went nowhere).
    assert link.sent == []
    # The listener's reliable stream waits for the board to say where it is.
    assert isinstance(agent2.clients[listener.key].out_reliable[0x80], ResumingStream)
    listener.agent = talker.agent = agent2
    agent2.tick()
    for n in range(3):
        talker.write(b"after-%d" % n)  # the talker's numbers go on: no CREATE_CLIENT, no reset
    assert agent2.clients[talker.key].spoken
    assert data_of(listener.take()) == []  # queued until the resynchronisation
    agent2.tick()
    _resync(listener, agent2, board_expects)
    messages = listener.take()
    assert data_of(messages) == [b"after-%d" % n for n in range(3)]
    seqs = [h.seq for h, ps in messages if any(p.ID == C.DATA for p in ps)]
    assert seqs == [(board_expects + i) & 0xFFFF for i in range(3)]  # in order, none repeated
    assert not agent2.clients[listener.key].resuming
    assert agent2.stats.samples_in == 3 and agent2.stats.samples_out == 3


def test_board_heartbeat_first_resynchronises_its_reliable_input(tmp_path):
    """A board whose window is full when the agent comes back sends a HEARTBEAT before anything
    else: the agent's input stream starts at its first unacknowledged number, and the ACKNACK it
    sends never names anything before it."""
    link = Link()
    agent = _agent(_store(tmp_path), link)
    talker, listener = talker_and_listener(agent, link)
    listener.read(delivery=DeliveryControl())
    for n in range(4):
        talker.write(b"x%d" % n)
    agent2, _ = _restart(agent, tmp_path, link)
    talker.agent = listener.agent = agent2
    talker.take()
    first = talker.seqs[0x80]
    talker.send(0, Heartbeat(first, (first + 1) & 0xFFFF, 0x80))
    acknacks = [p for _, ps in talker.take() for p in ps if p.ID == C.ACKNACK]
    assert acknacks and acknacks[-1].first_unacked == first
    assert acknacks[-1].nack_bitmap == 0b11  # the two it still holds: sent again
    talker.write(b"held-0")
    talker.write(b"held-1")
    acknacks = [p for _, ps in talker.take() for p in ps if p.ID == C.ACKNACK]
    assert acknacks[-1].first_unacked == (first + 2) & 0xFFFF


def test_create_client_replaces_stored_state(tmp_path):
    """A board that resets sends CREATE_CLIENT: today's handling, and one stored client."""
    link = Link()
    agent = _agent(_store(tmp_path), link)
    talker, _listener = talker_and_listener(agent, link)
    agent2, _ = _restart(agent, tmp_path, link)
    talker.agent = agent2
    talker.session_id = 0x82  # a reset board's new session: the stored one goes
    link.sent.clear()
    talker.connect()
    talker.build_pubsub(topic="rt/other")
    client = agent2.clients[talker.key]
    assert not client.resume_inputs and not client.resuming
    agent2.state.checkpoint()
    counts = agent2.state.store.counts()
    assert counts["clients"] == 2 and counts["objects"] == 12, counts
    records = {r.key: r for r in agent2.state.store.clients()}
    assert len(records[talker.key].objects) == 6


def test_admission_applies_to_restored_clients(tmp_path):
    from xrce.agent.engine.admission import AdmissionPolicy

    link = Link()
    agent = _agent(_store(tmp_path), link)
    talker, listener = talker_and_listener(agent, link)
    agent.state.close()
    again = _agent(_store(tmp_path), link)
    again.admission = AdmissionPolicy(keys=[listener.key])
    assert asyncio.run(again.state.restore()) == 1
    assert set(again.clients) == {listener.key}
    assert [r.key for r in again.state.store.clients()] == [listener.key]


def test_expiry_removes_stored_clients_that_never_return(tmp_path):
    link = Link()
    agent = _agent(_store(tmp_path), link)
    talker_and_listener(agent, link)
    agent.state.close()
    again = Agent(CedMiddleware(), client_expire_time=5.0)
    again.clock = clock = Clock()
    again.state = StateRecorder(_store(tmp_path), again, [link])
    assert asyncio.run(again.state.restore()) == 2
    clock.now += 6.0
    again.tick()
    assert again.clients == {}
    assert again.state.store.counts()["clients"] == 0


def test_unknown_session_gets_one_line(caplog):
    link = Link()
    agent = Agent(CedMiddleware())
    agent.clock = Clock()
    with caplog.at_level(logging.WARNING, logger="xrce.agent"):
        for seq in range(20):
            agent.receive(link, ("10.1.2.3", 4567), encode_message(
                0x81, 0x01, seq, None, [AckNack(0, 0, 0x80)]))
        agent.receive(link, ("10.1.2.3", 4567), encode_message(
            0x01, 0x01, 0, b"\xaa\xbb\xcc\xdd", [AckNack(0, 0, 0x80)]))
    lines = [r.getMessage() for r in caplog.records if "does not know" in r.getMessage()]
    assert len(lines) == 2, lines
    assert "10.1.2.3:4567" in lines[0] and "Reset the board" in lines[0] and "--state" in lines[0]
    assert "aabbccdd" in lines[1]


def test_default_store_path(monkeypatch, tmp_path):
    """One store per transport and port or device, under $XDG_STATE_HOME/xrce."""
    from xrce.agent.cli.subcommands import build_parser
    from xrce.agent.cli.transports import state_path

    def path(*argv):
        return state_path(build_parser(list(argv)).parse_args(list(argv)))

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path))
    assert path("udp4", "-p", "8888") == str(tmp_path / "xrce" / "udp4-8888.sqlite3")
    assert path("serial", "-D", "/dev/ttyUSB0") == str(tmp_path / "xrce" /
                                                       "serial-dev-ttyUSB0.sqlite3")
    assert path("udp4", "-p", "0") is None  # a free port: nothing to find it again by
    assert path("udp4", "-p", "8888", "--no-state") is None
    assert path("udp4", "-p", "8888", "--state", "/x/y.db") == "/x/y.db"
    monkeypatch.delenv("XDG_STATE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert path("udp6", "-p", "9") == str(tmp_path / "home" / ".local" / "state" / "xrce" /
                                          "udp6-9.sqlite3")


def test_stats_show_restored_clients_and_whether_they_have_spoken(tmp_path):
    """``xrce-agent stats`` (the observer's snapshot, drawn by stats_view) names the clients that
    came back from the store: silent until the board's first message after the restart."""
    from xrce.agent.observe.observability import Observer
    from xrce.agent.observe.stats_view import format_snapshot

    link = Link()
    agent = _agent(_store(tmp_path), link)
    talker, listener = talker_and_listener(agent, link)
    assert [c["restored"] for c in Observer(agent).snapshot()["clients"]] == [None, None]
    agent2, restored = _restart(agent, tmp_path, link)
    assert restored == 2
    assert [c["restored"] for c in Observer(agent2).snapshot()["clients"]] == ["silent", "silent"]
    talker.agent = agent2
    talker.write(b"after")
    snapshot = Observer(agent2).snapshot(show_keys=True)
    spoke = [c["key"] for c in snapshot["clients"] if c["restored"] == "spoke"]
    assert spoke == [talker.key.hex()]
    assert sorted(c["restored"] for c in snapshot["clients"]) == ["silent", "spoke"]
    view = format_snapshot(snapshot)
    assert "restored" in view and "yes, spoke" in view and "yes, silent" in view, view


def test_version_1_store_is_upgraded_keeping_its_clients(tmp_path):
    """Schema 2 added the board's reliable stream positions: a store of version 1 is read, its
    clients kept, the new table added."""
    path = str(tmp_path / "old.sqlite3")
    db = sqlite3.connect(path)
    for statement in store_module._statements(store_module.MIGRATIONS[0]):
        db.execute(statement)
    db.execute("INSERT INTO clients VALUES (?, 129, x'00', 1, 'udp4', '[\"10.0.0.7\", 4000]', 1.0)",
               (b"\x01\x02\x03\x04",))
    db.execute("PRAGMA user_version=1")
    db.commit()
    db.close()
    store = StateStore(path)
    [record] = store.clients()
    assert record.key == b"\x01\x02\x03\x04" and record.inputs == {}
    assert store.counts()["inputs"] == 0
    store.close()
    db = sqlite3.connect(path)
    assert db.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION == 2
    db.close()


def _board_acknacks(peer):
    return [p for _, ps in peer.take() for p in ps if p.ID == C.ACKNACK and p.stream_id == 0x80]


@pytest.mark.parametrize("stop", ["sigint", "sigkill"])
def test_agent_sets_going_a_board_that_never_sends_heartbeat(tmp_path, stop):
    """eProsima's client sends no HEARTBEAT while it keeps reading: after a restart its reliable
    output waits for an ACKNACK. After a clean stop the agent sends it at once, exactly after
    what it handled, with a NACK bit (the board sends again what went into the outage); after a
    crash, once the board has had GRACE_S to speak for itself, far past the stored checkpoint,
    and the board's next message, whatever its number, starts the stream."""
    from xrce.agent.engine import resync

    link = Link()
    agent = _agent(_store(tmp_path), link)
    talker, listener = talker_and_listener(agent, link)
    for n in range(3):
        talker.write(b"before-%d" % n)
    handled = agent.clients[talker.key].in_reliable[0x80].last_handled
    if stop == "sigkill":
        agent.state.checkpoint()
        # The row as stored: a lower bound of what was handled (rows move in steps).
        checkpoint = {r.key: r for r in agent.state.store.clients()}[talker.key].inputs[0x80][0]
        assert (handled - checkpoint) & 0xFFFF < recorder_module.CHECKPOINT_STEP
        for n in range(4):
            talker.write(b"late-%d" % n)
        agent2, _ = _crash(agent, tmp_path, link)
    else:
        agent2, _ = _restart(agent, tmp_path, link)
    talker.agent = listener.agent = agent2
    talker.take()
    # The board speaks (an ACKNACK of the agent's stream, as eProsima's answers a HEARTBEAT),
    # nothing on its own reliable stream.
    talker.send(0, AckNack(0, 0, 0x80))
    acknacks = _board_acknacks(talker)
    if stop == "sigint":
        assert [(a.first_unacked, a.nack_bitmap) for a in acknacks] == [((handled + 1) & 0xFFFF, 1)]
        # The board sends again what it holds from the outage: taken in order, once.
        talker.seqs[0x80] = (handled + 1) & 0xFFFF
        talker.write(b"outage-0")
        talker.write(b"outage-1")
        assert agent2.clients[talker.key].in_reliable[0x80].last_handled == (handled + 2) & 0xFFFF
        talker.take()
        agent2.clock.now += 0.2
        agent2.tick()  # settled by the board's messages: no ACKNACK of the resync again
        assert agent2.clients[talker.key].input_resync is None
        assert [a.first_unacked for a in _board_acknacks(talker)] == []
        return
    assert acknacks == []  # the board may still say where it is itself
    agent2.clock.now += resync.GRACE_S
    agent2.tick()
    acknacks = _board_acknacks(talker)
    assert [(a.first_unacked, a.nack_bitmap) for a in acknacks] == \
        [((checkpoint + resync.LEAP + 1) & 0xFFFF, 0)]
    # Far past anything the board sent: never behind its acknowledged point.
    assert 0x3000 < (acknacks[0].first_unacked - talker.seqs[0x80]) & 0xFFFF < 0x8000
    agent2.clock.now += 0.2
    agent2.tick()
    assert len(_board_acknacks(talker)) == 1  # again until the board answers (at most TRIES)
    talker.write(b"after-0")  # its next number, whatever it is, starts the stream
    stream = agent2.clients[talker.key].in_reliable[0x80]
    assert stream.last_handled == (talker.seqs[0x80] - 1) & 0xFFFF
    assert [a.first_unacked for a in _board_acknacks(talker)] == [talker.seqs[0x80]]
    agent2.clock.now += 0.2
    agent2.tick()
    assert _board_acknacks(talker) == []  # settled: no more guesses
