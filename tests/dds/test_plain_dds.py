"""Plain DDS topics in ``-m dds`` (issue 50, item 1): a topic whose type is not a ROS one is made on
the DDS domain under exactly the client's names and carries its CDR both ways.

The DDS peer is neither the agent nor ROS: Cyclone DDS's Python binding (tests/dds/cyclone_peer.py,
a child process with a ``HelloWorld`` type of its own). The board is xrce.client on CPython, creating
its entities in binary, by XML and by reference; the agent is the real process with its Fast DDS
bridge built on first use (into a cache of the test run's own). Run under ``unshare -n``.
"""

from __future__ import annotations

import importlib.util
import os
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from agent_process import AgentProcess
from ros_helpers import ros_domain  # noqa: F401
from xrce.client.entities import endpoint_qos
from xrce.client.session import Session
from xrce.transports.udp import UdpTransport
from xrce.wire import constants as C

PEER = Path(__file__).resolve().parent / "cyclone_peer.py"
UP, DOWN = "HelloWorldTopic", "HelloWorldDown"
TYPE = "HelloWorld"

needs_cyclone = pytest.mark.skipif(importlib.util.find_spec("cyclonedds") is None,
                                   reason="CYCLONE DDS PEER TESTS NOT RUN: the cyclonedds package "
                                          "(a test requirement) is not installed")


def hello(index: int, message: str) -> bytes:
    text = message.encode() + b"\0"
    return struct.pack("<II", index, len(text)) + text


def decode_hello(cdr: bytes) -> tuple[int, str]:
    index, length = struct.unpack_from("<II", cdr)
    return index, cdr[8:8 + length - 1].decode()


@pytest.fixture(scope="module")
def bridge_cache(tmp_path_factory):
    """XDG_CACHE_HOME for the agents of this module: the bridge is built once, in the run's own
    temporary directory, and nothing is left in ~/.cache."""
    return {"XDG_CACHE_HOME": str(tmp_path_factory.mktemp("xdg-cache"))}


class Lines:
    """A child's stdout lines, read on a thread."""

    def __init__(self, proc):
        self.lines: list[str] = []
        self._thread = threading.Thread(target=self._read, args=(proc,), daemon=True)
        self._thread.start()

    def _read(self, proc):
        for line in proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def starting(self, word: str) -> list[str]:
        return [line for line in list(self.lines) if line.split(" ", 1)[0] == word]


# The tests' ROS domains are localhost-only (ros_helpers: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST),
# where rmw_fastrtps announces itself by unicast to 127.0.0.1 alone: the Cyclone program does the
# same, as a DDS application configured for one host would.
CYCLONE_LOCALHOST = ("<CycloneDDS><Domain><General><Interfaces><NetworkInterface address=\"127.0.0.1\"/>"
                     "</Interfaces><AllowMulticast>false</AllowMulticast></General><Discovery>"
                     "<ParticipantIndex>auto</ParticipantIndex><Peers><Peer address=\"127.0.0.1\"/>"
                     "</Peers></Discovery></Domain></CycloneDDS>")


class CyclonePeer:
    def __init__(self, domain: int):
        self.proc = subprocess.Popen([sys.executable, str(PEER), str(domain), UP, DOWN],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True,
                                     env=dict(os.environ, CYCLONEDDS_URI=CYCLONE_LOCALHOST))
        self.out = Lines(self.proc)

    def ups(self) -> list[tuple[int, str]]:
        return [(int(i), text) for _, i, text in (line.split(" ", 2) for line in self.out.starting("up"))]

    def downs(self) -> dict[int, bytes]:
        return {int(i): bytes.fromhex(body)
                for _, i, body in (line.split(" ", 2) for line in self.out.starting("down"))}

    def close(self):
        if self.proc.poll() is None:
            self.proc.stdin.close()
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


PARTICIPANT_XML = "<dds><participant><rtps><name>hello_board</name></rtps></participant></dds>"


def topic_xml(name: str) -> str:
    return "<dds><topic><name>%s</name><dataType>%s</dataType></topic></dds>" % (name, TYPE)


def endpoint_xml(kind: str, name: str) -> str:
    return ("<dds><%s><topic><kind>NO_KEY</kind><name>%s</name><dataType>%s</dataType>"
            "<historyQos><kind>KEEP_LAST</kind><depth>16</depth></historyQos></topic>"
            "<qos><reliability><kind>RELIABLE</kind></reliability>"
            "<durability><kind>VOLATILE</kind></durability></qos></%s></dds>"
            % (kind, name, TYPE, kind))


PROFILES = """<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"><profiles>
  <participant profile_name="hello_participant"><rtps><name>hello_board</name></rtps></participant>
  <topic profile_name="up_topic"><name>%(up)s</name><dataType>%(type)s</dataType></topic>
  <topic profile_name="down_topic"><name>%(down)s</name><dataType>%(type)s</dataType></topic>
  <data_writer profile_name="up_writer"><topic><kind>NO_KEY</kind><name>%(up)s</name>
    <dataType>%(type)s</dataType><historyQos><kind>KEEP_LAST</kind><depth>16</depth></historyQos>
    </topic><qos><reliability><kind>RELIABLE</kind></reliability></qos></data_writer>
  <data_reader profile_name="down_reader"><topic><kind>NO_KEY</kind><name>%(down)s</name>
    <dataType>%(type)s</dataType><historyQos><kind>KEEP_LAST</kind><depth>16</depth></historyQos>
    </topic><qos><reliability><kind>RELIABLE</kind></reliability></qos></data_reader>
</profiles></dds>
""" % {"up": UP, "down": DOWN, "type": TYPE}


class Board:
    """xrce.client with a writer of UP and a reader of DOWN, made in ``representation``."""

    def __init__(self, port: int, domain: int, representation: str):
        self.session = s = Session(UdpTransport("127.0.0.1", port), history=8)
        assert s.create(attempts=5, timeout_ms=1000)
        if representation == "binary":
            node = s.create_participant(domain_id=domain, name="hello_board")
            up = s.create_topic(node, UP, TYPE)
            down = s.create_topic(node, DOWN, TYPE)
            qos = endpoint_qos(reliable=True, depth=16)
            publisher, subscriber = s.create_publisher(node), s.create_subscriber(node)
            self.writer = s.create_datawriter(publisher, up, qos)
            self.reader = s.create_datareader(subscriber, down, qos)
        elif representation == "xml":
            node = s.create_participant(domain_id=domain, xml=PARTICIPANT_XML)
            s.create_topic(node, xml=topic_xml(UP))
            s.create_topic(node, xml=topic_xml(DOWN))
            publisher, subscriber = s.create_publisher(node), s.create_subscriber(node)
            self.writer = s.create_datawriter(publisher, xml=endpoint_xml("data_writer", UP))
            self.reader = s.create_datareader(subscriber, xml=endpoint_xml("data_reader", DOWN))
        else:
            node = s.create_participant(domain_id=domain, ref="hello_participant")
            s.create_topic(node, ref="up_topic")
            s.create_topic(node, ref="down_topic")
            publisher, subscriber = s.create_publisher(node), s.create_subscriber(node)
            self.writer = s.create_datawriter(publisher, ref="up_writer")
            self.reader = s.create_datareader(subscriber, ref="down_reader")
        self.downs: list[bytes] = []
        s.set_reader_callback(self.reader, lambda cdr: self.downs.append(bytes(cdr)))
        s.read_data(self.reader, s.reliable)
        assert s.run_until_all_status(30000), s.last_statuses
        assert all(status == C.STATUS_OK for status in s.last_statuses.values()), s.last_statuses

    def close(self):
        self.session.delete(attempts=2, timeout_ms=500)
        self.session.close()


@needs_cyclone
@pytest.mark.parametrize("representation", ["binary", "xml", "ref"])
def test_a_board_and_a_cyclone_dds_program_exchange_hello_world(representation, ros_domain,  # noqa: F811
                                                                 bridge_cache, tmp_path):
    args = ["udp4", "-m", "dds"]
    if representation == "ref":
        profiles = tmp_path / "profiles.xml"
        profiles.write_text(PROFILES)
        args += ["-r", str(profiles)]
    with AgentProcess(*args, env=bridge_cache) as agent:
        peer = CyclonePeer(ros_domain)
        board = None
        try:
            board = Board(agent.port, ros_domain, representation)
            deadline = time.monotonic() + 90
            index = 0
            while time.monotonic() < deadline and (len(peer.ups()) < 5 or len(board.downs) < 5):
                index += 1
                assert board.session.write(board.writer, hello(index, "board says %d" % index))
                board.session.run_until_timeout(100)
        finally:
            if board is not None:
                board.close()
            peer.close()
        assert agent.stop() == 0
    log = "".join(agent.output)
    output = "\n".join(peer.out.lines)
    ups = peer.ups()
    assert len(ups) >= 5, output + log
    # What the Cyclone program read is what the board wrote, in order (reliable both ends).
    assert all(text == "board says %d" % i for i, text in ups), output
    assert [i for i, _ in ups] == sorted(i for i, _ in ups), output
    # What the board read is the Cyclone program's serialized sample, byte for byte, with the
    # padding to 4 bytes Cyclone puts on the wire (its encapsulation options count it): what
    # eProsima's agent hands a board too, everything after the 4-byte header.
    written = peer.downs()
    assert len(board.downs) >= 5, log
    for body in board.downs:
        index, text = decode_hello(body)
        assert text == "cyclone says %d" % index
        assert body == written[index] + bytes(-len(written[index]) % 4)
    assert "DDS writer %s of type %s in domain %d" % (UP, TYPE, ros_domain) in log, log
    assert "Traceback" not in log and "failed" not in log, log


@needs_cyclone
def test_a_remap_names_a_plain_topic_and_a_namespace_leaves_it(ros_domain, bridge_cache):  # noqa: F811
    """Issue 53: plain-DDS topics keep their names under --ros-args __ns:= (a namespace is a ROS
    idea), and a remap naming one moves it: the board's 'board_hello' is the Cyclone program's
    HelloWorldTopic; its ROS topic goes under the namespace."""
    with AgentProcess("udp4", "-m", "dds", "--ros-args", "-r", "__ns:=/robot1",
                      "-r", "board_hello:=%s" % UP, "--", env=bridge_cache) as agent:
        peer = CyclonePeer(ros_domain)
        try:
            s = Session(UdpTransport("127.0.0.1", agent.port), history=8)
            assert s.create(attempts=5, timeout_ms=1000)
            node = s.create_participant(domain_id=ros_domain, name="renamed_board")
            writer = s.create_datawriter(s.create_publisher(node),
                                         s.create_topic(node, "board_hello", TYPE))
            chatter = s.create_topic(node, "rt/chatter", "std_msgs::msg::dds_::String_")
            s.create_datawriter(s.create_publisher(node), chatter)
            assert s.run_until_all_status(30000), s.last_statuses
            assert all(v == C.STATUS_OK for v in s.last_statuses.values()), s.last_statuses
            deadline = time.monotonic() + 60
            index = 0
            while time.monotonic() < deadline and len(peer.ups()) < 3:
                index += 1
                s.write(writer, hello(index, "renamed"))
                s.run_until_timeout(50)
            s.delete(attempts=2, timeout_ms=500)
            s.close()
        finally:
            peer.close()
        assert agent.stop() == 0
    log = "".join(agent.output)
    assert len(peer.ups()) >= 3, "\n".join(peer.out.lines) + log
    assert all(text == "renamed" for _, text in peer.ups())
    assert "DDS writer %s of type %s in domain %d" % (UP, TYPE, ros_domain) in log, log
    assert "publisher /robot1/chatter of node /robot1/renamed_board" in log, log


@needs_cyclone
def test_two_boards_share_a_plain_topic_beside_ros_ones(ros_domain, bridge_cache):  # noqa: F811
    """Two clients' topics of one name share the DDS topic: one board's samples reach the other
    through the agent and the Cyclone program alike. Another type under that name is refused;
    a ROS type name in the same session still becomes a ROS publisher."""
    with AgentProcess("udp4", "-m", "dds", env=bridge_cache) as agent:
        peer = CyclonePeer(ros_domain)
        boards = []
        try:
            writer_board = Board(agent.port, ros_domain, "binary")
            boards.append(writer_board)
            s = Session(UdpTransport("127.0.0.1", agent.port), history=8)
            assert s.create(attempts=5, timeout_ms=1000)
            node = s.create_participant(domain_id=ros_domain, name="listener_board")
            topic = s.create_topic(node, UP, TYPE)
            reader = s.create_datareader(s.create_subscriber(node), topic)
            got = []
            s.set_reader_callback(reader, lambda cdr: got.append(bytes(cdr)))
            s.read_data(reader, s.reliable)
            chatter = s.create_topic(node, "rt/chatter", "std_msgs::msg::dds_::String_")
            s.create_datawriter(s.create_publisher(node), chatter)
            assert s.run_until_all_status(30000), s.last_statuses
            assert all(v == C.STATUS_OK for v in s.last_statuses.values()), s.last_statuses
            s.create_topic(node, UP, "OtherType")
            assert not s.run_until_all_status(10000)
            assert list(s.last_statuses.values()) == [C.STATUS_ERR_DDS_ERROR]
            deadline = time.monotonic() + 60
            index = 0
            while time.monotonic() < deadline and (len(got) < 3 or len(peer.ups()) < 3):
                index += 1
                writer_board.session.write(writer_board.writer, hello(index, "to both"))
                writer_board.session.run_until_timeout(50)
                s.run_until_timeout(50)
            s.delete(attempts=2, timeout_ms=500)
            s.close()
        finally:
            for board in boards:
                board.close()
            peer.close()
        assert agent.stop() == 0
    log = "".join(agent.output)
    assert len(got) >= 3, log
    assert all(decode_hello(body)[1] == "to both" for body in got)
    assert len(peer.ups()) >= 3, "\n".join(peer.out.lines)
    assert "topic '%s' is already of type '%s'" % (UP, TYPE) in log, log
    assert "-> publisher /chatter of node /listener_board" in log, log


def test_m_rtps_is_served_as_dds():
    with AgentProcess("udp4", "-m", "rtps") as agent:
        banner = agent.banner
        assert agent.stop() == 0
    assert "(middleware dds)" in banner
    assert "-m rtps is served as -m dds" in "".join(agent.output)


def fake_fastdds(root: Path, library: str) -> str:
    """A ROS prefix with only what _plan looks at: the library's file and the headers' marker."""
    (root / "lib").mkdir(parents=True)
    (root / "lib" / library).write_bytes(b"")
    header = root / "include" / "fastdds" / "dds" / "domain" / "DomainParticipant.hpp"
    header.parent.mkdir(parents=True)
    header.write_text("")
    return str(root / "lib" / library)


@pytest.mark.parametrize("library, version, link", [("libfastrtps.so.2.14.5", "2.14.5", "-lfastrtps"),
                                                    ("libfastdds.so.3.2.2", "3.2.2", "-lfastdds")])
def test_the_bridge_is_planned_against_the_loaded_fast_dds_2_or_3(library, version, link,
                                                                  monkeypatch, tmp_path):
    """Jazzy's Fast DDS 2 is libfastrtps, Kilted's 3 libfastdds: the bridge compiles against the
    headers beside the one loaded and links that one, cached apart from the other's build."""
    from xrce.agent.middleware.dds import build

    path = fake_fastdds(tmp_path / "ros", library)
    maps = tmp_path / "maps"
    maps.write_text("7f00-7f01 r-xp 0 08:01 1 %s\n7f01-7f02 r-xp 0 08:01 2 /usr/lib/libc.so.6\n" % path)
    assert build.loaded_fastdds(str(maps)) == (path, version)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setattr(build, "loaded_fastdds", lambda: (path, version))
    output, command = build._plan()
    assert "-I" + str(tmp_path / "ros" / "include") in command
    assert command[-2:] == [link, "-lfastcdr"]
    assert output.startswith(str(tmp_path / "cache" / "xrce" / "plaindds") + os.sep)
    other = "libfastdds.so.3.2.2" if version.startswith("2") else "libfastrtps.so.2.14.5"
    monkeypatch.setattr(build, "loaded_fastdds", lambda: (str(tmp_path / "ros" / "lib" / other),
                                                          other.split(".so.")[1]))
    assert build._plan()[0] != output


def test_the_bridge_refuses_other_fast_dds_versions_and_a_process_without_fast_dds(monkeypatch,
                                                                                   tmp_path):
    from xrce.agent.middleware.dds import build

    for library, version in [("libfastdds.so.4.0.0", "4.0.0"), ("libfastrtps.so.1.10.0", "1.10.0"),
                             ("libfastrtps.so.3.0.0", "3.0.0")]:
        path = fake_fastdds(tmp_path / version, library)
        monkeypatch.setattr(build, "loaded_fastdds", lambda: (path, version))
        with pytest.raises(build.BridgeUnavailable, match="Fast DDS 2 .ROS 2 Jazzy. and 3 .ROS 2 "
                                                          "Kilted.; this agent runs Fast DDS "
                                                          + version.replace(".", "[.]")):
            build._plan()
    path = str(tmp_path / "bare" / "lib" / "libfastdds.so.3.2.2")
    monkeypatch.setattr(build, "loaded_fastdds", lambda: (path, "3.2.2"))
    with pytest.raises(build.BridgeUnavailable, match="need Fast DDS's headers"):
        build._plan()
    monkeypatch.setattr(build, "loaded_fastdds", lambda: None)
    with pytest.raises(build.BridgeUnavailable, match="need Fast DDS"):
        build._plan()


@needs_cyclone
@pytest.mark.parametrize("representation", ["xml", "bin"])
def test_eprosimas_client_and_a_cyclone_dds_program_exchange_hello_world(  # noqa: F811
        representation, ros_domain, bridge_cache, tmp_path):
    """eProsima's C client (tests/dds/programs/hello_dds.c against XRCE_EPROSIMA_CLIENT), its
    entities by XML and in binary as its HelloWorld examples make them."""
    import eprosima_client

    eprosima_client.require_library()
    program = eprosima_client.build(Path(__file__).resolve().parent / "programs" / "hello_dds.c",
                                    tmp_path / "programs")
    with AgentProcess("udp4", "-m", "dds", env=bridge_cache) as agent:
        peer = CyclonePeer(ros_domain)
        try:
            board = subprocess.run([str(program), representation, "127.0.0.1", str(agent.port),
                                    str(ros_domain), "50"], capture_output=True, text=True,
                                   timeout=120)
        finally:
            peer.close()
        assert agent.stop() == 0
    log = "".join(agent.output)
    lines = board.stdout.splitlines()
    assert board.returncode == 0, board.stdout + board.stderr + log
    assert lines[0] == "status 1 0 0 0 0 0 0 0", board.stdout
    assert "wrote 50" in lines, board.stdout
    ups = peer.ups()
    assert len(ups) >= 5, "\n".join(peer.out.lines) + log
    assert all(text == "eprosima says %d" % i for i, text in ups)
    downs = [line.split(" ", 2) for line in lines if line.startswith("down ")]
    assert len(downs) >= 3, board.stdout + log
    assert all(text == "cyclone says %s" % i for _, i, text in downs), board.stdout
