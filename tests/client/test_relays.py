"""xrce.tools.relays between real ``xrce-agent -m ced`` processes and client Sessions: a writer
client publishes through the agent to a reader client, so every sample crosses the damaged link
client → agent and again agent → client.

- UDP relay dropping 20 %, duplicating and reordering: reliable streams deliver everything in order
  (fragmented samples included); best-effort delivers only whole samples, each newer than the last.
- Serial relay flipping bits at a 1e-3 bit error rate: reliable delivers everything in order, the
  CRC drops are counted; best-effort loses only what corrupted frames explain.
- Serial pacing: a relay at 9600 baud moves about 960 bytes per second, not a pty's megabytes.
"""

import os
import time

import pytest

from agent_process import AgentProcess
from xrce.client.session import Session
from xrce.msgs.std_msgs import String
from xrce.tools.relays import SerialRelay, UdpRelay
from xrce.transports.serial import SerialTransport
from xrce.transports.udp import UdpTransport


def _until(predicate, seconds, *sessions):
    deadline = time.monotonic() + seconds
    while not predicate() and time.monotonic() < deadline:
        for session in sessions:
            session.spin_once(2)
    return predicate()


def _connect(transport, name):
    # auto_recover off: these tests are about the streams surviving the link, and a ping lost to
    # the noise must not restart the session under them.
    session = Session(transport, history=8, heartbeat_ms=50, auto_recover=False)
    assert session.create(attempts=30, timeout_ms=300), name
    return session


def _wait_statuses(session, seconds=30):
    # One call: run_until_all_status forgets the requests it reported, even unanswered ones.
    assert session.run_until_all_status(int(seconds * 1000)), session.last_statuses


def _pair(writer, reader, topic, reliable):
    received = []
    writer_id = writer.create_writer(writer.create_participant(name="w"), topic, String,
                                     reliable=reliable, depth=500)
    reader.create_reader(reader.create_participant(name="r"), topic, String, received.append,
                         reliable=reliable, depth=500)
    for session in (writer, reader):
        _wait_statuses(session)
    return writer_id, received


def _write_when_room(writer, reader, writer_id, sample, seconds):
    # write() waits up to 1 s for window room and then drops the sample (returns 0). Through a
    # 1e-3 bit error rate a 300-byte message survives one try in ten, so the retransmissions that
    # free the window can take longer than that on a loaded machine: the test is about everything
    # arriving in order, so it offers the sample again, with the reader kept running meanwhile.
    deadline = time.monotonic() + seconds
    while not writer.write(writer_id, sample):
        if time.monotonic() > deadline:
            return False
        reader.spin_once(1)
    return True


def _reliable_round(writer, reader, topic, count, big_every=None, text_size=300):
    writer_id, received = _pair(writer, reader, topic, reliable=True)
    sent = []
    for i in range(count):
        if big_every and i % big_every == 3:
            text = ("big %d " % i) * text_size  # fragmented both ways
        else:
            text = "sample %d" % i
        sent.append(text)
        assert _write_when_room(writer, reader, writer_id, String(data=text), 30), \
            "window stayed full for 30 s"
        writer.flush()
        reader.spin_once(1)
    assert _until(lambda: len(received) >= len(sent), 60, writer, reader), \
        "%d of %d arrived" % (len(received), len(sent))
    return sent, [m.data for m in received]


def _best_effort_round(writer, reader, topic, count):
    writer_id, received = _pair(writer, reader, topic, reliable=False)
    sent = ["sample %d" % i for i in range(count)]
    for text in sent:
        writer.write(writer_id, String(data=text), stream_id=writer.best_effort)
        writer.flush()
        _until(lambda: False, 0.005, writer, reader)
    _until(lambda: False, 1.0, writer, reader)
    got = [m.data for m in received]
    assert got, "nothing arrived"
    assert all(text in sent for text in got)  # whole, uncorrupted samples only
    indices = [sent.index(text) for text in got]
    assert indices == sorted(set(indices))  # each newer than the last: no duplicate, no going back
    return sent, got


@pytest.fixture
def ced_udp_agent():
    with AgentProcess("udp4", "-m", "ced", "-v", "3") as agent:
        yield agent


@pytest.fixture
def lossy_udp(ced_udp_agent):
    with UdpRelay(("127.0.0.1", ced_udp_agent.port), drop=0.2, duplicate=0.1, reorder=0.2,
                  seed=5) as relay:
        writer = _connect(UdpTransport("127.0.0.1", relay.port), "writer")
        reader = _connect(UdpTransport("127.0.0.1", relay.port), "reader")
        yield relay, writer, reader
        for session in (writer, reader):
            session.close()


def test_udp_relay_reliable_delivers_everything_in_order(lossy_udp):
    relay, writer, reader = lossy_udp
    sent, got = _reliable_round(writer, reader, "/lossy_reliable", 60, big_every=10)
    assert got == sent
    # ... and the other way round on the same sessions.
    sent_back, got_back = _reliable_round(reader, writer, "/lossy_back", 20)
    assert got_back == sent_back
    for direction in relay.stats.values():
        assert direction["dropped"] > 10 and direction["duplicated"] > 3 and direction["reordered"] > 10


def test_udp_relay_best_effort_delivers_whole_newer_samples(lossy_udp):
    relay, writer, reader = lossy_udp
    sent, got = _best_effort_round(writer, reader, "/lossy_best_effort", 200)
    assert len(got) < len(sent)  # two lossy hops lose some
    assert relay.stats["to_client"]["dropped"] > 0


def _serial_clients(relays):
    sessions = []
    for relay, name in zip(relays, ("writer", "reader")):
        sessions.append(_connect(SerialTransport(relay.client_path, 115200), name))
    return sessions


@pytest.fixture
def noisy_serial():
    relays = [SerialRelay(bit_error_rate=1e-3, seed=seed) for seed in (11, 12)]
    try:
        devices = " ".join(relay.agent_path for relay in relays)
        with AgentProcess("multiserial", "--devs", devices, "-m", "ced", "-v", "3") as agent:
            writer, reader = _serial_clients(relays)
            yield agent, relays, writer, reader
            for session in (writer, reader):
                session.close()
    finally:
        for relay in relays:
            relay.close()


def _crc_drops(session):
    decoder = session.transport.decoder
    return decoder.crc_errors + decoder.resyncs + decoder.oversize


def test_serial_relay_bit_errors_reliable_delivers_everything_in_order(noisy_serial):
    agent, relays, writer, reader = noisy_serial
    sent, got = _reliable_round(writer, reader, "/noisy_reliable", 60, big_every=20, text_size=40)
    assert got == sent
    flipped = sum(relay.totals()["flipped_bits"] for relay in relays)
    assert flipped > 20
    assert _crc_drops(writer) + _crc_drops(reader) > 0  # corrupted replies were caught, not used


def test_serial_relay_bit_errors_best_effort_loses_only_corrupted_frames(noisy_serial):
    agent, relays, writer, reader = noisy_serial
    before_reader = _crc_drops(reader)
    corrupted_before = relays[0].stats["to_agent"]["corrupted_bytes"] + \
        relays[1].stats["to_client"]["corrupted_bytes"]
    sent, got = _best_effort_round(writer, reader, "/noisy_best_effort", 150)
    lost = len(sent) - len(got)
    corrupted = relays[0].stats["to_agent"]["corrupted_bytes"] + \
        relays[1].stats["to_client"]["corrupted_bytes"] - corrupted_before
    # Every lost sample crossed a corrupted byte on its way (a flipped flag byte may take the
    # neighbouring frame along, hence up to two per corruption); nothing else loses frames here.
    assert lost <= 2 * corrupted, (lost, corrupted)
    assert _crc_drops(reader) - before_reader <= relays[1].stats["to_client"]["corrupted_bytes"]


def test_serial_relay_paces_at_a_tenth_of_the_baud_rate():
    with SerialRelay(baudrate=9600) as relay:
        client = os.open(relay.client_path, os.O_RDWR | os.O_NOCTTY)
        agent = os.open(relay.agent_path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            import termios
            import tty
            for fd in (client, agent):
                tty.setraw(fd, termios.TCSANOW)
            payload = bytes(range(256)) * 6  # 1536 bytes: 1.6 s of line time at 960 B/s
            start = time.monotonic()
            os.write(client, payload)
            got = bytearray()
            deadline = start + 10
            while len(got) < len(payload) and time.monotonic() < deadline:
                try:
                    got += os.read(agent, 4096)
                except BlockingIOError:
                    time.sleep(0.005)
            elapsed = time.monotonic() - start
        finally:
            os.close(client)
            os.close(agent)
    assert bytes(got) == payload
    rate = len(payload) / elapsed
    assert 800 < rate < 1100, rate
    assert relay.stats["to_agent"]["bytes_out"] == len(payload)
