"""The xrce-agent command line, run as real processes (python -m xrce.agent) on loopback and ptys."""

import os
import re
import selectors
import signal
import socket
import subprocess
import sys
import termios
import time
import tty
from pathlib import Path

import pytest

from agent_process import restore_default_signals
from xrce.wire import constants as C
from xrce.agent.cli.startup import load_refs
from xrce.wire.submessages import GetInfo, Info, Locator, decode_message, encode_message
from xrce.transports.crc import get_crc
from xrce.transports.framing import (
    FrameDecoder,
    LengthPrefixDecoder,
    encode_frame,
    encode_length_prefixed,
)

REPO = Path(__file__).resolve().parents[2]
START_TIMEOUT = 30.0  # the venv's python re-executes itself once at start-up (ROS wheels)
EXIT_TIMEOUT = 15.0
REPLY_TIMEOUT = 5.0



def _env():
    env = dict(os.environ)
    # Never a ROS domain another test leases (ros_helpers uses 40..99): these agents only create
    # ROS entities in the default-middleware start-up test, and that test checks no graph.
    env["ROS_DOMAIN_ID"] = "23"
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["PYTHONUNBUFFERED"] = "1"
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def run_cli(*args, timeout=START_TIMEOUT):
    """Run the CLI to completion; (returncode, stdout, stderr)."""
    done = subprocess.run([sys.executable, "-m", "xrce.agent", *args], cwd=REPO, env=_env(),
                          capture_output=True, text=True, timeout=timeout)
    return done.returncode, done.stdout, done.stderr


class AgentProcess:
    """A running agent; ``banner`` is its first stdout line, ``port`` the port it names."""

    def __init__(self, *args, tmp_path):
        self.stderr_path = tmp_path / ("agent-stderr-%d.txt" % time.monotonic_ns())
        self._stderr = open(self.stderr_path, "wb")
        self.proc = subprocess.Popen([sys.executable, "-m", "xrce.agent", *args], cwd=REPO,
                                     env=_env(), stdout=subprocess.PIPE, stderr=self._stderr,
                                     preexec_fn=restore_default_signals)
        self.banner = None

    def wait_banner(self):
        selector = selectors.DefaultSelector()
        selector.register(self.proc.stdout, selectors.EVENT_READ)
        try:
            line = b""
            deadline = time.monotonic() + START_TIMEOUT
            while not line.endswith(b"\n"):
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not selector.select(remaining):
                    raise AssertionError("no banner; stderr: %s" % self.stderr_text())
                chunk = os.read(self.proc.stdout.fileno(), 1)
                if not chunk:
                    raise AssertionError("agent exited (%s) before its banner; stderr: %s"
                                         % (self.proc.poll(), self.stderr_text()))
                line += chunk
        finally:
            selector.close()
        self.banner = line.decode().strip()
        return self.banner

    def port(self, what="agent"):
        match = re.search(r"%s on port (\d+)" % what, self.banner)
        assert match, self.banner
        return int(match.group(1))

    def stderr_text(self):
        self._stderr.flush()
        return self.stderr_path.read_text(errors="replace")

    def stop(self, signum=signal.SIGINT):
        self.proc.send_signal(signum)
        return self.proc.wait(EXIT_TIMEOUT)

    def cleanup(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(EXIT_TIMEOUT)
        self.proc.stdout.close()
        self._stderr.close()


@pytest.fixture
def agent(tmp_path):
    started = []

    def start(*args):
        process = AgentProcess(*args, tmp_path=tmp_path)
        started.append(process)
        process.wait_banner()
        return process

    yield start
    for process in started:
        process.cleanup()


def ipv6_loopback():
    try:
        with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as probe:
            probe.bind(("::1", 0))
        return True
    except OSError:
        return False


# ------------------------------------------------------------------------------ argument errors

@pytest.mark.parametrize("args, mentions", [
    (["bogus"], "invalid choice: 'bogus'"),
    ([], "required: SUBCOMMAND"),
    (["udp4"], "-p/--port"),
    (["udp4", "-p", "x"], "-p/--port"),
    (["tcp4", "-p", "70000"], "-p/--port"),
    (["udp4", "-p", "8888", "-v", "9"], "-v/--verbose"),
    (["serial", "-D", "/dev/null", "--crc", "crc32"], "--crc"),
    (["serial"], "-D/--dev"),
    (["multiserial", "-b", "fast", "--devs", "a b"], "-b/--baudrate"),
    (["udp4", "-p", "8888", "-m", "zenoh"], "-m/--middleware"),
    (["udp4", "-p", "8888", "-r", "/nonexistent/refs.xml"], "refs"),
    # issue 23: each names the flag and what to do, before anything starts
    (["udp4", "-p", "0", "-m", "ced", "--capture", "/nonexistent/dir/f"], "--capture"),
    (["udp4", "-p", "0", "-m", "ced", "--capture", "/"], "--capture"),
    (["udp4", "-p", "0", "-m", "ced", "--interfaces", "/nonexistent"], "--interfaces"),
    (["udp4", "-p", "0", "-m", "ced", "--interfaces", "/etc/passwd"], "--interfaces"),
    (["udp4", "-p", "0", "-m", "ced", "--stats-port", "70000"], "--stats-port"),
    (["demo", "--duration", "-1"], "--duration"),
    (["demo", "--duration", "soon"], "--duration"),
    (["demo", "--domain", "300"], "--domain"),
    (["demo", "--domain", "1", "--lan"], "--lan"),
    (["stats", "-p", "70000"], "-p/--port"),
    (["stats", "-p", "1", "-i", "0"], "--interval"),
])
def test_bad_arguments_give_one_line_and_exit_2(args, mentions):
    code, out, err = run_cli(*args)
    assert code == 2
    assert out == ""
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("xrce-agent: error: ") and mentions in lines[0]
    assert "Traceback" not in err


def test_demo_reports_a_bad_ros_domain_id_in_one_line():
    env = dict(_env(), ROS_DOMAIN_ID="abc")
    done = subprocess.run([sys.executable, "-m", "xrce.agent", "demo", "--lan"], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=START_TIMEOUT)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.splitlines() == [
        "xrce-agent demo: error: ROS_DOMAIN_ID=abc is not a domain id in 0..232 (unset it, or pass "
        "--domain N)"]


def test_help_shows_defaults_and_what_each_option_is_for():
    def help_text(*args):
        code, out, err = run_cli(*args, "-h")
        assert code == 0 and err == ""
        return " ".join(out.split())  # argparse wraps at the terminal width

    assert "-b BAUD, --baudrate BAUD line speed" in help_text("serial")
    assert "(default 115200, as eProsima)" in help_text("multiserial")
    stats = help_text("stats")
    assert "--host HOST where that agent runs (default 127.0.0.1" in stats
    assert "--json print one raw JSON snapshot and exit" in stats
    demo = help_text("demo")
    assert "a private domain on this machine only" in demo and "--lan" in demo


def test_help_lists_every_subcommand():
    code, out, err = run_cli("-h")
    assert code == 0 and err == ""
    for name in ("udp4", "udp6", "tcp4", "tcp6", "serial", "multiserial", "pseudoterminal"):
        assert name in out
    code, out, _ = run_cli("serial", "-h")
    assert code == 0 and "--baudrate" in out and "--crc" in out


_MODULES_AFTER_THE_COMMAND = r"""
import sys
from xrce.agent.launcher import main
try:
    main(sys.argv[1:])
finally:
    sys.stderr.write("MODULES " + " ".join(sorted(sys.modules)) + "\n")
"""


def _modules_after(*args):
    """The modules a command that exits at once (--version, -h) imported, and its stdout."""
    done = subprocess.run([sys.executable, "-c", _MODULES_AFTER_THE_COMMAND, *args], cwd=REPO,
                          env=_env(), capture_output=True, text=True, timeout=START_TIMEOUT)
    line = [text for text in done.stderr.splitlines() if text.startswith("MODULES ")]
    assert done.returncode == 0 and line, done.stdout + done.stderr
    return set(line[0].split()[1:]), done.stdout


# The parser holds only the named subcommand's options (xrce/agent/cli/subcommands.py): what the
# others' options and defaults need stays unloaded.
# (xrce.agent.interfaces itself is no tool's alone: once a build has run, the registry's .pth
# hook imports it in every interpreter of the venv.)
_AGENT = {"xrce.agent.engine.limits", "xrce.agent.observe.observability", "xrce.agent.links.udp"}
_TOOLS = {"xrce.tools.ros_cli.arguments", "xrce.agent.demo", "xrce.agent.interfaces.builder",
          "xrce.agent.observe.stats_view"}


def test_version_and_help_load_no_agent_and_no_tool():
    modules, out = _modules_after("--version")
    assert out.startswith("xrce-agent ") and not modules & (_AGENT | _TOOLS)
    modules, out = _modules_after("-h")
    assert "pseudoterminal" in out and not modules & (_AGENT | _TOOLS)


def test_a_transport_help_loads_only_what_its_options_name():
    modules, out = _modules_after("udp4", "-h")
    assert "--max-clients" in out and _AGENT <= modules and not modules & _TOOLS
    modules, out = _modules_after("serial", "-h")
    assert "--baudrate" in out and "xrce.agent.links.udp" not in modules
    modules, out = _modules_after("demo", "-h")
    assert "--lan" in out and "xrce.agent.engine.limits" not in modules


def test_refs_file_gives_one_xml_per_profile(tmp_path):
    refs_file = tmp_path / "refs.xml"
    refs_file.write_text(
        '<?xml version="1.0"?>\n'
        '<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">\n'
        '  <profiles>\n'
        '    <participant profile_name="my_participant">\n'
        '      <rtps><name>xrce_participant</name></rtps>\n'
        '    </participant>\n'
        '    <data_writer profile_name="my_writer">\n'
        '      <topic><kind>NO_KEY</kind><name>rt/chatter</name>\n'
        '        <dataType>std_msgs::msg::dds_::String_</dataType></topic>\n'
        '    </data_writer>\n'
        '  </profiles>\n'
        '</dds>\n')
    refs = load_refs(str(refs_file))
    assert sorted(refs) == ["my_participant", "my_writer"]
    assert refs["my_participant"].startswith('<participant profile_name="my_participant">')
    assert "<name>xrce_participant</name>" in refs["my_participant"]
    assert "ns0" not in refs["my_writer"] and "<dataType>std_msgs::msg::dds_::String_" in refs["my_writer"]

    broken = tmp_path / "broken.xml"
    broken.write_text("<dds><profiles>")
    code, _, err = run_cli("udp4", "-p", "0", "-m", "ced", "-r", str(broken))
    assert code == 2 and len(err.splitlines()) == 1 and "not valid XML" in err


# ------------------------------------------------------------------------------ start and stop

@pytest.mark.parametrize("transport", ["udp4", "udp6", "tcp4", "tcp6"])
def test_ip_subcommands_start_and_exit_0_on_sigint(agent, transport):
    if transport.endswith("6") and not ipv6_loopback():
        pytest.skip("no IPv6 loopback")
    process = agent(transport, "-p", "0", "-m", "ced")
    assert process.banner.startswith("xrce-agent: %s agent on port " % transport)
    assert process.port() > 0
    assert process.stop() == 0
    assert "Traceback" not in process.stderr_text()


def test_serial_and_multiserial_start_and_exit_0_on_sigint(agent, pty_pair):
    _, slave = pty_pair()
    process = agent("serial", "-D", slave, "-b", "57600", "-m", "ced")
    assert slave in process.banner and "57600 baud" in process.banner
    assert process.stop() == 0

    (_, slave_a), (_, slave_b) = pty_pair(), pty_pair()
    process = agent("multiserial", "--devs", "%s %s" % (slave_a, slave_b), "-m", "ced")
    assert slave_a in process.banner and slave_b in process.banner
    assert process.stop(signal.SIGTERM) == 0
    assert "Traceback" not in process.stderr_text()


def test_pseudoterminal_prints_its_slave_and_links_dev(agent, tmp_path):
    link = tmp_path / "xrce_pty"
    process = agent("pseudoterminal", "-D", str(link), "-m", "ced")
    match = re.search(r"pseudoterminal at (/dev/\S+)", process.banner)
    assert match, process.banner
    assert os.readlink(link) == match.group(1)
    assert process.stop() == 0
    assert not os.path.lexists(link)


@pytest.mark.parametrize("transport, kind", [("tcp4", socket.SOCK_STREAM), ("udp4", socket.SOCK_DGRAM)])
def test_a_port_in_use_is_one_line_naming_it_and_exit_1(transport, kind):
    with socket.socket(socket.AF_INET, kind) as busy:
        busy.bind(("0.0.0.0", 0))
        if kind == socket.SOCK_STREAM:
            busy.listen()
        port = busy.getsockname()[1]
        code, out, err = run_cli(transport, "-p", str(port), "-m", "ced", "-v", "0")
    assert code == 1 and out == ""
    assert err.splitlines() == ["xrce-agent: error: cannot open %s port %d (-p): Address already in "
                                "use (another agent there? choose another -p)" % (transport, port)]


def test_a_stats_port_in_use_names_the_flag():
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code, out, err = run_cli("udp4", "-p", "0", "-m", "ced", "-v", "0", "--stats-port", str(port))
    assert code == 1 and out == ""
    assert err.splitlines() == ["xrce-agent: error: cannot open stats port %d (--stats-port): "
                                "Address already in use" % port]


def test_a_serial_device_that_exists_but_is_no_tty_is_one_line_and_exit_1(tmp_path):
    not_a_tty = tmp_path / "ttyFILE"
    not_a_tty.write_bytes(b"")
    code, out, err = run_cli("serial", "-D", str(not_a_tty), "-m", "ced", "-v", "0")
    assert code == 1 and out == ""
    assert len(err.splitlines()) == 1 and "ttyFILE" in err


def test_serial_waits_for_a_device_that_is_not_there_yet_saying_so_once(agent, tmp_path):
    """As eProsima's agent: ``serial --dev`` before the board is plugged in starts and waits; the
    device is served as soon as it appears (here a symlink to a pty, made after the start)."""
    later = tmp_path / "ttyLATER"
    process = agent("serial", "-D", str(later), "-m", "ced")
    assert process.banner.startswith("xrce-agent: serial agent on %s" % later)
    time.sleep(1.0)  # several re-open attempts: still one line
    waiting = [l for l in process.stderr_text().splitlines() if "ttyLATER" in l]
    assert len(waiting) == 1 and "not there yet; waiting for it" in waiting[0], waiting
    master, slave = os.openpty()
    try:
        tty.setraw(master, termios.TCSANOW)
        os.symlink(os.ttyname(slave), later)
        deadline = time.monotonic() + REPLY_TIMEOUT
        while "appeared" not in process.stderr_text() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert "appeared" in process.stderr_text(), process.stderr_text()
        _framed_conversation(master).run_section_13()
    finally:
        os.close(master)
        os.close(slave)
    assert process.stop() == 0


def test_undecodable_datagrams_give_one_hint_at_the_default_verbosity(agent):
    process = agent("udp4", "-p", "0", "-m", "ced")  # -v 4, the default
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as junk:
        for i in range(50):
            junk.sendto(b"not XRCE at all %d" % i, ("127.0.0.1", process.port()))
        probe = encode_message(0x80, 0, 0, None, [GetInfo(0xAA, C.OBJECTID_AGENT, 1)])
        junk.settimeout(REPLY_TIMEOUT)
        junk.sendto(probe, ("127.0.0.1", process.port()))
        junk.recv(65536)  # answered: every junk datagram before it was read
    assert process.stop() == 0
    hints = [l for l in process.stderr_text().splitlines() if "nothing decodable" in l]
    assert len(hints) == 1, process.stderr_text()
    assert "WARNING" in hints[0] and "not XRCE" in hints[0] and "port %d" % process.port() in hints[0]


def test_frames_with_the_wrong_crc_give_one_hint_naming_baud_rate_and_crc(agent):
    process = agent("pseudoterminal", "-m", "ced")  # CRC-16/ARC, the default
    slave_path = re.search(r"pseudoterminal at (/dev/\S+)", process.banner).group(1)
    fd = os.open(slave_path, os.O_RDWR | os.O_NOCTTY)
    try:
        tty.setraw(fd, termios.TCSANOW)
        request = encode_message(0x80, 0, 0, None, [GetInfo(0xAA, C.OBJECTID_AGENT, 1)])
        for _ in range(20):  # a client framing with X.25 instead
            os.write(fd, encode_frame(request, 1, 0, crc=get_crc("ccitt")))
        deadline = time.monotonic() + REPLY_TIMEOUT
        while "nothing decodable" not in process.stderr_text() and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        os.close(fd)
    assert process.stop() == 0
    hints = [l for l in process.stderr_text().splitlines() if "nothing decodable" in l]
    assert len(hints) == 1, process.stderr_text()
    assert "bad CRC" in hints[0] and "--crc arc" in hints[0]


# ------------------------------------------------------------------ end to end (XRCE-WIRE.md §13)

def h(text):
    return bytes.fromhex(text.replace("xx", "00"))


PARTICIPANT_XML = b"<dds><participant><rtps><name>default_xrce_participant</name></rtps></participant></dds>\x00"
M1_CREATE_CLIENT = h("80000000 00011000 58524345 0100010F AABBCCDD 8100FC01")
M2_STATUS_AGENT = h("81000000 04010B00 0000 58524345 0100010F 00")
M3_CREATE_PARTICIPANT = (h("81800000 01056800 000A 0011 01 02 0000 59000000") + PARTICIPANT_XML
                         + h("00 0000"))
M4_STATUS = h("81800000 05010600 000A 0011 0000")
M6_FIVE_CREATES = h(
    "81800100"
    "01054300 000B0012 02030000 35000000"
    "0B000000 72742F63 68617474 65720000 01xxxxxx"
    "1D000000" + b"std_msgs::msg::dds_::String_\x00".hex() + "0011 00"
    "01051000 000C0013 03030000 02000000 00000011"
    "01051C00 000D0015 05030000 0E000000 001201xx 030001xx 05000000 00000013"
    "01051000 000E0014 04030000 02000000 00000011"
    "01051D00 000F0016 06030000 0F000000 001201xx 030001xx 05000000 000000 0014 000000")
M6_STATUSES = [h("8180%02X00 05010600 %s 0000" % (seq, ids)) for seq, ids in
               ((1, "000B0012"), (2, "000C0013"), (3, "000D0015"), (4, "000E0014"),
                (5, "000F0016"))]
M7_READ_DATA = h("81800200 08011000 00100016 80000001 FFFF0000 00000000")
M8_WRITE_DATA = h("81800300 07010B00 00110015 03000000 686900 00")
M9_DATA = h("81800600 09010B00 00100016 03000000 686900")


def test_section_13_bytes_are_consistent():
    assert len(M1_CREATE_CLIENT) == 24 and len(M2_STATUS_AGENT) == 19
    assert len(M3_CREATE_PARTICIPANT) == 112 and len(M6_FIVE_CREATES) == 184
    assert len(M7_READ_DATA) == 24 and len(M8_WRITE_DATA) == 20 and len(M9_DATA) == 19
    for message in (M1_CREATE_CLIENT, M3_CREATE_PARTICIPANT, M6_FIVE_CREATES, M7_READ_DATA,
                    M8_WRITE_DATA):
        decode_message(message)


class Conversation:
    """Sends client messages and collects agent messages until the wanted ones have arrived."""

    def __init__(self, send, receive):
        self.send = send
        self.receive = receive  # receive(timeout) -> list of messages
        self.seen = []

    def expect(self, wanted):
        missing = list(wanted)
        deadline = time.monotonic() + REPLY_TIMEOUT
        while missing:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError("missing %s; got %s" % (
                    [m.hex() for m in missing], [m.hex() for m in self.seen]))
            for message in self.receive(remaining):
                self.seen.append(message)
                if message in missing:
                    missing.remove(message)

    def run_section_13(self):
        self.send(M1_CREATE_CLIENT)
        self.expect([M2_STATUS_AGENT])
        self.send(M3_CREATE_PARTICIPANT)
        self.expect([M4_STATUS])
        self.send(M6_FIVE_CREATES)
        self.expect(M6_STATUSES)
        self.send(M7_READ_DATA)
        self.send(M8_WRITE_DATA)
        self.expect([M9_DATA])


def _wait_readable(fd, timeout):
    with selectors.DefaultSelector() as selector:
        selector.register(fd, selectors.EVENT_READ)
        return bool(selector.select(timeout))


def test_end_to_end_over_udp(agent):
    process = agent("udp4", "-p", "0", "-m", "ced")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as client:
        client.connect(("127.0.0.1", process.port()))

        def receive(timeout):
            client.settimeout(timeout)
            try:
                return [client.recv(65536)]
            except socket.timeout:
                return []

        Conversation(client.send, receive).run_section_13()
    assert process.stop() == 0


def test_end_to_end_over_tcp(agent):
    process = agent("tcp4", "-p", "0", "-m", "ced")
    with socket.create_connection(("127.0.0.1", process.port()), timeout=REPLY_TIMEOUT) as client:
        decoder = LengthPrefixDecoder()

        def receive(timeout):
            client.settimeout(timeout)
            try:
                data = client.recv(65536)
            except socket.timeout:
                return []
            assert data, "agent closed the connection"
            return decoder.feed(data)

        Conversation(lambda m: client.sendall(encode_length_prefixed(m)), receive).run_section_13()
    assert process.stop() == 0


def _framed_conversation(fd):
    decoder = FrameDecoder(local_addr=1)

    def receive(timeout):
        if not _wait_readable(fd, timeout):
            return []
        frames = decoder.feed(os.read(fd, 65536))
        assert all(src == 0 for src, _, _ in frames)
        return [payload for _, _, payload in frames]

    return Conversation(lambda m: os.write(fd, encode_frame(m, 1, 0)), receive)


def test_end_to_end_over_serial_on_a_pty(agent, pty_pair):
    master, slave = pty_pair()
    process = agent("serial", "-D", slave, "-m", "ced")
    # XRCE-WIRE.md §11 worked example 1, byte for byte in both directions.
    os.write(master, h("7E 01 00 18 00 80 00 00 00 00 01 10 00 58 52 43 45 01 00 01 0F "
                       "AA BB CC DD 81 00 FC 01 3E 8F"))
    expected = h("7E 00 01 13 00 81 00 00 00 04 01 0B 00 00 00 58 52 43 45 01 00 01 0F 00 00 EC")
    received = b""
    deadline = time.monotonic() + REPLY_TIMEOUT
    while len(received) < len(expected) and _wait_readable(master, deadline - time.monotonic()):
        received += os.read(master, 65536)
    assert received[:len(expected)] == expected
    conversation = _framed_conversation(master)
    conversation.send(M3_CREATE_PARTICIPANT)
    conversation.expect([M4_STATUS])
    conversation.send(M6_FIVE_CREATES)
    conversation.expect(M6_STATUSES)
    conversation.send(M7_READ_DATA)
    conversation.send(M8_WRITE_DATA)
    conversation.expect([M9_DATA])
    assert process.stop() == 0


def test_end_to_end_over_the_agents_pseudoterminal(agent):
    process = agent("pseudoterminal", "-m", "ced")
    slave_path = re.search(r"pseudoterminal at (/dev/\S+)", process.banner).group(1)
    fd = os.open(slave_path, os.O_RDWR | os.O_NOCTTY)
    try:
        tty.setraw(fd, termios.TCSANOW)
        _framed_conversation(fd).run_section_13()
    finally:
        os.close(fd)
    assert process.stop() == 0


def _free_udp_port():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("0.0.0.0", 0))
        return probe.getsockname()[1]


def test_discovery_answers_with_the_agents_port(agent):
    discovery_port = _free_udp_port()
    process = agent("udp4", "-p", "0", "-d", str(discovery_port), "-m", "ced")
    assert process.port("discovery") == discovery_port
    agent_port = process.port()
    request = encode_message(0x80, 0, 0, None, [GetInfo(C.REQUEST_ID_DISCOVERY, C.OBJECTID_AGENT, 3)])
    assert request == h("80000000 02010800 0009FFFD 03000000")  # the captured discovery request
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as client:
        client.settimeout(REPLY_TIMEOUT)
        client.sendto(request, ("127.0.0.1", discovery_port))
        reply, source = client.recvfrom(65536)
    assert source == ("127.0.0.1", discovery_port)
    _, (info,) = decode_message(reply)
    assert isinstance(info, Info) and info.request_id == C.REQUEST_ID_DISCOVERY
    assert Locator(C.LOCATOR_MEDIUM, socket.inet_aton("127.0.0.1"), agent_port) in info.locators
    assert process.stop() == 0


@pytest.mark.parametrize("transport", ["udp6", "tcp6", "udp4"])
def test_discovery_answers_locators_of_the_agents_family(agent, transport):
    """eProsima's agent answers discovery with its own transport's family: `[::1]:PORT` style LARGE
    locators for udp6/tcp6 (an IPv4 one would be of no use to that agent's clients), MEDIUM for
    udp4; asked over IPv4 as eProsima's clients ask, and over IPv6 where the agent is IPv6."""
    from xrce.agent.links.udp import local_ipv6_addresses

    loopback6 = socket.inet_pton(socket.AF_INET6, "::1")
    if transport.endswith("6") and loopback6 not in local_ipv6_addresses():
        pytest.skip("this host has no IPv6 loopback address")
    discovery_port = _free_udp_port()
    process = agent(transport, "-p", "0", "-d", str(discovery_port), "-m", "ced")
    agent_port = process.port()
    request = encode_message(0x80, 0, 0, None, [GetInfo(C.REQUEST_ID_DISCOVERY, C.OBJECTID_AGENT, 3)])
    askers = [(socket.AF_INET, "127.0.0.1")]
    if transport.endswith("6"):
        askers.append((socket.AF_INET6, "::1"))
    for family, host in askers:
        with socket.socket(family, socket.SOCK_DGRAM) as client:
            client.settimeout(REPLY_TIMEOUT)
            client.sendto(request, (host, discovery_port))
            reply, _ = client.recvfrom(65536)
        _, (info,) = decode_message(reply)
        if transport.endswith("6"):
            assert Locator(C.LOCATOR_LARGE, loopback6, agent_port) in info.locators
            assert {loc.fmt for loc in info.locators} == {C.LOCATOR_LARGE}
        else:
            assert Locator(C.LOCATOR_MEDIUM, socket.inet_aton("127.0.0.1"), agent_port) in info.locators
            assert {loc.fmt for loc in info.locators} == {C.LOCATOR_MEDIUM}
    assert process.stop() == 0


def test_the_ros_middleware_runs_section_13_and_exits_0(agent):
    pytest.importorskip("rclpy")
    process = agent("udp4", "-p", "0")  # -m dds is the default
    assert "(middleware dds)" in process.banner
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as client:
        client.connect(("127.0.0.1", process.port()))

        def receive(timeout):
            client.settimeout(timeout)
            try:
                return [client.recv(65536)]
            except socket.timeout:
                return []

        conversation = Conversation(client.send, receive)
        conversation.send(M1_CREATE_CLIENT)
        conversation.expect([M2_STATUS_AGENT])
        conversation.send(M3_CREATE_PARTICIPANT)
        conversation.expect([M4_STATUS])
        conversation.send(M6_FIVE_CREATES)
        conversation.expect(M6_STATUSES)
    # Shutting down with live ROS entities: the engine destroys them, then the process exits 0.
    assert process.stop() == 0
    assert "Traceback" not in process.stderr_text()


@pytest.mark.parametrize("verbosity, traced", [("6", True), ("0", False)])
def test_verbosity_6_traces_every_message_and_0_is_silent(agent, verbosity, traced):
    process = agent("udp4", "-p", "0", "-m", "ced", "-v", verbosity)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as client:
        client.settimeout(REPLY_TIMEOUT)
        client.sendto(M1_CREATE_CLIENT, ("127.0.0.1", process.port()))
        assert client.recv(65536) == M2_STATUS_AGENT
    assert process.stop() == 0
    log_text = process.stderr_text()
    if traced:
        assert "TRACE" in log_text and "CREATE_CLIENT" in log_text and "STATUS_AGENT" in log_text
    else:
        assert log_text == ""


# ------------------------------------------------------------------ xrce-agent stats (issue 23)

def test_the_banner_says_where_boards_connect(agent):
    """Bound to every interface, the banner lists the host's addresses with the port, as a
    board's AGENT = ("192.168.1.10", 8888) needs them; a serial agent has nothing to add."""
    from xrce.agent.cli.addresses import MAX_LISTED, host_addresses

    process = agent("udp4", "-p", "0", "-m", "ced")
    port = int(re.search(r"on port (\d+)", process.banner).group(1))
    listed = re.search(r"; boards reach it at udp4 (.*) \(all interfaces\)$", process.banner)
    assert listed, process.banner
    addresses = host_addresses(False)
    assert "127.0.0.1" in addresses and addresses[-1] == "127.0.0.1"  # loopback last
    expected = ["%s:%d" % (a, port) for a in addresses[:MAX_LISTED]]
    assert listed.group(1).split(", ") == expected + (["..."] if len(addresses) > MAX_LISTED
                                                      else [])
    assert process.stop() == 0
    process = agent("pseudoterminal", "-m", "ced")
    assert "boards reach it" not in process.banner
    assert process.stop() == 0


def test_stats_json_is_one_snapshot_and_a_closed_reader_ends_it_quietly(agent):
    import json

    process = agent("udp4", "-p", "0", "-m", "ced", "--stats-port", "0")
    stats_port = int(re.search(r"stats on 127\.0\.0\.1:(\d+)", process.banner).group(1))
    code, out, err = run_cli("stats", "-p", str(stats_port), "--json")
    assert code == 0 and err == ""
    snapshot = json.loads(out)  # one document, then exit: no loop
    assert snapshot["links"][0]["name"] == "udp4"
    # `xrce-agent stats | head -n 1`: the reader goes away while the view keeps refreshing.
    view = subprocess.Popen([sys.executable, "-m", "xrce.agent", "stats", "-p", str(stats_port),
                             "-i", "0.05"], cwd=REPO, env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, preexec_fn=restore_default_signals)
    try:
        assert view.stdout.readline().startswith(b"xrce-agent up ")
        view.stdout.close()
        assert view.wait(EXIT_TIMEOUT) == 0
        assert view.stderr.read() == b""  # no BrokenPipeError traceback
    finally:
        if view.poll() is None:
            view.kill()
            view.wait()
        view.stderr.close()
    assert process.stop() == 0


# ------------------------------------------------------------------ names given to boards (issue 53)

@pytest.mark.parametrize("args, mentions", [
    (["--ros-args", "-r", "foo"], "'foo' is not FROM:=TO"),
    (["--ros-args", "-r", "__ns:=robot3"], "must be absolute (/robot3)"),
    (["--ros-args", "-r", "__node:=x"], "only __ns:="),
    (["--ros-args", "-p", "x:=1"], "only -r/--remap"),
    (["--ros-args", "-r"], "needs FROM:=TO"),
    (["--ros-args", "-r", "cmd vel:=x", "--"], "not a valid ROS name"),
    (["--ros-args", "-r", "a:=2b", "--"], "not a valid ROS name"),
    (["--namespace", "/bad//ns"], "not a valid ROS name"),
    (["--namespace", "/a", "--ros-args", "-r", "__ns:=/b"], "disagree"),
    (["--domain", "300"], "--domain"),
    (["--global-topics", "tf"], "not an absolute name"),
    (["-m", "ced", "--domain", "3"], "need -m dds"),
])
def test_bad_naming_arguments_give_one_line_and_exit_2(args, mentions):
    code, out, err = run_cli("udp4", "-p", "0", *args)
    assert code == 2 and out == ""
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("xrce-agent: error: ") and mentions in lines[0], lines[0]


def test_ros_args_are_refused_by_the_tools():
    code, out, err = run_cli("stats", "-p", "1", "--ros-args", "-r", "__ns:=/robot3")
    assert code == 2 and len(err.splitlines()) == 1 and "--ros-args" in err
