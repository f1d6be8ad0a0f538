"""The README's MicroPython example runs as written (only AGENT and DOMAIN changed) under real
MicroPython 1.27, through its UDP transport, against a real ``xrce-agent -m dds`` and rclpy."""

import re
import threading
import time
from pathlib import Path

from geometry_msgs.msg import Twist
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from agent_process import AgentProcess, restore_default_signals
from procs import read_until
from mp_harness import ensure_installed, run_micropython
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401

README = Path(__file__).resolve().parents[2] / "README.md"


def readme_example():
    text = README.read_text()
    section = text[text.index("## The client on MicroPython"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_readme_micropython_example_runs_as_written(ros_peer, ros_domain):  # noqa: F811
    source = readme_example()
    assert len(source.strip().splitlines()) <= 20
    with AgentProcess("udp4", "-m", "dds") as agent:
        source = re.sub(r"^AGENT = .*$", "AGENT = (%r, %d)" % ("127.0.0.1", agent.port), source, flags=re.M)
        source = re.sub(r"^DOMAIN = .*$", "DOMAIN = %d" % ros_domain, source, flags=re.M)
        chatter = []
        best_effort = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
        ros_peer.node.create_subscription(String, "/chatter", chatter.append, best_effort)
        cmd_vel = ros_peer.node.create_publisher(Twist, "/cmd_vel", 10)
        stop = threading.Event()

        def drive():
            while not stop.is_set():
                message = Twist()
                message.linear.x, message.angular.z = 0.5, -0.25
                cmd_vel.publish(message)
                time.sleep(0.1)

        driver = threading.Thread(target=drive, daemon=True)
        driver.start()
        try:
            result = run_micropython(source, timeout=120)
        finally:
            stop.set()
            driver.join(5)
        # The block ends by deleting its session: the board's node leaves the ROS graph now, while
        # the agent runs on (it stayed there for the agent's lifetime before).
        assert wait_until(lambda: ("board", "/") not in ros_peer.node_names(), 30), ros_peer.node_names()
    assert result.returncode == 0, result.stdout + result.stderr
    assert "cmd_vel 0.5 -0.25" in result.stdout
    assert len(chatter) >= 50 and chatter[-1].data.startswith("hello ")


def _no_board_commands():
    """The commands of README's "No board?" paragraph, as written."""
    text = README.read_text()
    paragraph = text[text.index("**No board?**"):]
    paragraph = " ".join(paragraph[:paragraph.index("\n\n")].split())
    install = re.search(r"`(npm ci --prefix tests/micropython[^`]*)`", paragraph)
    run = re.search(r"`(node tests/micropython/run\.mjs board\.py)`", paragraph)
    assert install and run, paragraph
    return install.group(1), run.group(1)


def test_no_board_runs_the_block_under_node_as_written_and_says_when_it_waits(ros_peer, ros_domain, tmp_path):  # noqa: F811
    """README's "No board?": the block as board.py (AGENT on this machine), run by the README's
    command from the checkout, says each second that no agent answers yet, then runs once an
    agent is there, and leaves the ROS graph when it ends."""
    import socket

    _, command = _no_board_commands()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:  # a port no agent has yet
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    source = re.sub(r"^AGENT = .*$", "AGENT = (%r, %d)" % ("127.0.0.1", port), readme_example(), flags=re.M)
    source = re.sub(r"^DOMAIN = .*$", "DOMAIN = %d" % ros_domain, source, flags=re.M)
    board = tmp_path / "board.py"
    board.write_text(source)
    ensure_installed()
    process = subprocess.Popen(command.replace("board.py", str(board)).split(), cwd=README.parent, text=True,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, preexec_fn=restore_default_signals)
    try:
        waiting = process.stdout.readline()
        assert waiting == "no agent at 127.0.0.1:%d yet\n" % port, (waiting, process.stderr.read())
        with AgentProcess("udp4", "-m", "dds", "-p", str(port)):
            assert wait_until(lambda: ("board", "/") in ros_peer.node_names(), 60), ros_peer.node_names()
            out, err = process.communicate(timeout=120)
            assert process.returncode == 0, out + err
            assert wait_until(lambda: ("board", "/") not in ros_peer.node_names(), 30)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()


def test_run_mjs_without_npm_ci_says_what_to_run_in_one_line(tmp_path):
    """A fresh clone has no tests/micropython/node_modules: run.mjs says in one line to run the
    README's `npm ci` (exit 3), where Node printed its module-resolution stack."""
    install, command = _no_board_commands()
    fresh = tmp_path / "tests" / "micropython"
    fresh.mkdir(parents=True)
    for name in ("run.mjs", "ring.mjs", "udp_worker.mjs"):
        shutil.copy(README.parent / "tests" / "micropython" / name, fresh / name)
    (tmp_path / "board.py").write_text("print('never')\n")
    done = subprocess.run(command.split(), cwd=tmp_path, text=True, capture_output=True, timeout=60)
    assert done.returncode == 3 and done.stdout == "", done
    assert done.stderr.count("\n") == 1 and "`%s`" % install in done.stderr, done.stderr


# ------------------------------------------------------------------ every shell block (issue 23)
#
# Each line of README's ```sh blocks runs as written, from the checkout, with the venv's paths
# (.venv/bin/...), in a network namespace of its own (unshare -n): port 8888, discovery on 7400 and
# the ROS graph are the test's alone, and nothing it starts can reach another machine. A line
# that needs hardware, root or a second install is not run; each such line has its reason below,
# and a line no rule knows fails the test, so a new README line must be thought about.

import os  # noqa: E402
import shutil  # noqa: E402
import signal  # noqa: E402
import subprocess  # noqa: E402

import pytest  # noqa: E402

VENV_BIN = README.parent / ".venv" / "bin"
SERVER_START_S = 120.0
LINE_TIMEOUT_S = 180.0

NOT_RUN = [  # (substring of the line, why this test does not run it)
    ("sudo ", "needs root and apt"),
    ("source /opt/ros/jazzy/setup.bash", "needs ROS 2 Jazzy from apt"),
    ("mpremote", "needs a MicroPython board on USB"),
    ("pip install -e '.[test]'", "the suite's own install: this run is it"),
    ("pip wheel", "a second install: tests/repo/test_install_paths.py builds and runs the wheel"),
    ("xrce-client ping serial --dev /dev/ttyACM0", "needs a board on /dev/ttyACM0"),
]
INSTALL_PREFIX = "python3.11 -m venv .venv && .venv/bin/pip install -e . && "  # this venv's own install


def readme_shell_lines():
    """(section, line) for every command line of every ```sh block."""
    text = README.read_text()
    lines = []
    section = "(top)"
    for block in re.finditer(r"^(## [^\n]*)$|```sh\n(.*?)```", text, re.S | re.M):
        if block.group(1):
            section = block.group(1)[3:]
            continue
        for line in block.group(2).splitlines():
            if line.strip() and not line.lstrip().startswith("#"):
                lines.append((section, line.strip()))
    return lines


class Namespace:
    """A network namespace with only an up loopback, held by a sleeping process."""

    def __init__(self):
        self.holder = subprocess.Popen(["unshare", "-n", "sh", "-c", "ip link set lo up && exec sleep 600"],
                                       stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            if os.readlink("/proc/%d/ns/net" % self.holder.pid) != os.readlink("/proc/self/ns/net") \
                    and b"lo" in subprocess.run(["nsenter", "--net=/proc/%d/ns/net" % self.holder.pid,
                                                  "ip", "-o", "link", "show", "up"],
                                                 capture_output=True).stdout:
                return
            if self.holder.poll() is not None:
                break
            time.sleep(0.05)
        raise RuntimeError("no network namespace: %s" % self.holder.stderr.read())

    def popen(self, line, **kwargs):
        # A session of its own: whatever the line starts can be killed with it (_kill).
        return subprocess.Popen(["nsenter", "--net=/proc/%d/ns/net" % self.holder.pid, "bash", "-c", line],
                                cwd=README.parent, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True, start_new_session=True, preexec_fn=restore_default_signals, **kwargs)

    def close(self):
        self.holder.kill()
        self.holder.wait()
        self.holder.stderr.close()


def _kill(process):
    """End ``process`` and everything it started (its session), whatever state the test is in."""
    try:
        os.killpg(process.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    process.communicate()


def _finish(process, line):
    """The output of a line that must end by itself; killed (with its children) if it hangs."""
    try:
        out, _ = process.communicate(timeout=LINE_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        _kill(process)
        raise AssertionError("%r did not end within %d s" % (line, LINE_TIMEOUT_S))
    return out


def _start_server(namespace, line, banner):
    """``line`` (exec'd, so signals reach it) until its output shows ``banner``."""
    process = namespace.popen("exec " + line)
    found, output = read_until(process, lambda text: re.search(banner, text), SERVER_START_S)
    if found is not None:
        return process, [output]
    _kill(process)
    raise AssertionError("%r did not start:\n%s" % (line, output))


def _stop_server(process, output, expected):
    process.send_signal(signal.SIGINT)
    try:
        rest, _ = process.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        _kill(process)
        raise
    text = "".join(output) + rest
    assert process.returncode == expected, text
    assert "Traceback" not in text, text
    return text


SERVERS = [  # (how a long-running line starts, its banner, its exit code after Ctrl-C)
    (".venv/bin/xrce-agent demo", r"driving a 0\.5 m square", 130),
    (".venv/bin/xrce-agent ", r"^xrce-agent: .*\(middleware (dds|ced)\)", 0),  # its banner
]


@pytest.fixture
def namespace(ros_domain):  # noqa: F811
    if shutil.which("unshare") is None or shutil.which("nsenter") is None:
        pytest.fail("unshare/nsenter (util-linux) missing: README's lines need a namespace of their own")
    if not (VENV_BIN / "xrce-agent").exists():
        pytest.skip("LOUD SKIP: no .venv in the checkout (%s): README's commands name .venv/bin, "
                    "create it as README's first line does" % VENV_BIN)
    made = Namespace()
    try:
        yield made
    finally:
        made.close()


def test_every_readme_shell_line_runs_as_written(namespace):
    lines = readme_shell_lines()
    assert len(lines) >= 15, lines
    ran, not_run = [], []
    agent = None  # the README's first agent line, kept running for the xrce-client section
    background = []  # lines ending in "&": started, then awaited after the next line
    try:
        for section, line in lines:
            if section.startswith("`xrce-client`") and agent is None:
                agent = _start_server(namespace, ".venv/bin/xrce-agent udp4 -p 8888", r"agent on port 8888")
            if re.search(r"&\s*(#.*)?$", line):
                # As a person types it: the next line comes once this one has said something
                # (sub's "subscribed to ..."), not within the same millisecond.
                command = re.sub(r"&\s*(#.*)?$", "", line)
                assert command.startswith(".venv/bin/"), "README line without the venv's path: %r" % line
                process, output = _start_server(namespace, command, r".")
                background.append((line, process, output))
                continue
            reason = next((why for key, why in NOT_RUN if key in line), None)
            if reason is not None:
                not_run.append((line, reason))
                continue
            if line.startswith(INSTALL_PREFIX):
                # The venv this test runs in is that install; what it installed must be there.
                assert (VENV_BIN / "xrce-agent").exists() and (VENV_BIN / "xrce-client").exists()
                line = line[len(INSTALL_PREFIX):]
            assert line.startswith(".venv/bin/"), "README line without the venv's path: %r" % line
            server = next((s for s in SERVERS if line.startswith(s[0])), None)
            if server is not None and "xrce-client" not in line:
                process, output = _start_server(namespace, line, server[1])
                _stop_server(process, output, server[2])
            else:
                process = namespace.popen(line)
                out = _finish(process, line)
                assert process.returncode == 0, "%r exited %s:\n%s" % (line, process.returncode, out)
                assert "Traceback" not in out, out
            ran.append(line)
            while background:
                started_line, process, output = background.pop(0)
                out = "".join(output) + _finish(process, started_line)
                assert process.returncode == 0, "%r exited %s:\n%s" % (started_line, process.returncode, out)
                ran.append(started_line)
    finally:
        for _, process, _ in background:
            _kill(process)
        if agent is not None:
            _stop_server(agent[0], agent[1], 0)
    print("ran %d README lines; not run: %s" % (len(ran), not_run))
    assert any("xrce-client sub" in line for line in ran) and any("demo" in line for line in ran)
    assert len(not_run) <= 8, not_run


def test_readme_cpython_example_runs_and_says_why_without_an_agent(namespace, tmp_path):
    text = README.read_text()
    section = text[text.index("## The client on CPython"):]
    script = tmp_path / "talker.py"
    script.write_text(re.search(r"```python\n(.*?)```", section, re.S).group(1))
    alone = namespace.popen(".venv/bin/python %s" % script)
    out = _finish(alone, "the CPython example")
    assert alone.returncode == 1 and out.strip().splitlines() == [
        "no agent at 127.0.0.1:8888: start .venv/bin/xrce-agent udp4 -p 8888"], out
    agent = _start_server(namespace, ".venv/bin/xrce-agent udp4 -p 8888", r"agent on port 8888")
    try:
        with_agent = namespace.popen(".venv/bin/python %s" % script)
        out = _finish(with_agent, "the CPython example")
        assert with_agent.returncode == 0 and out == "", out
    finally:
        _stop_server(agent[0], agent[1], 0)


def test_readme_bench_command_runs_with_the_venvs_python():
    """README's `.venv/bin/python bench/run.py`: its imports and options as written (the run itself
    takes minutes, bench/ is not the suite), and `bench/run.py --smoke`: every bench script starts
    from its path (its --help or shortest run, every module imported; no agent, ~10 s)."""
    assert "`.venv/bin/python bench/run.py`" in README.read_text()
    done = subprocess.run([str(VENV_BIN / "python"), "bench/run.py", "--help"], cwd=README.parent,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "--quick" in done.stdout and "--smoke" in done.stdout, done.stderr
    smoke = subprocess.run([str(VENV_BIN / "python"), "bench/run.py", "--smoke"], cwd=README.parent,
                           capture_output=True, text=True, timeout=600)
    assert smoke.returncode == 0 and "every bench file runs" in smoke.stdout, smoke.stdout + smoke.stderr
    assert smoke.stdout.count("ok ") >= 30, smoke.stdout  # the scripts of bench/'s folders, not none


# ------------------------------------------------------------------ docs/*.md shell blocks
#
# What moved out of README (issue 24) keeps its commands runnable too. The docs' shell lines are
# benchmark commands, which take minutes each and are not the suite: each line's script runs with
# --help and must list every option the line uses. A line of any other kind fails this test: run
# it from README's test above (move it there) or give it a rule here.

DOCS = sorted((README.parent / "docs").glob("*.md"))
BENCH_LINE = re.compile(r"\.venv/bin/python (bench/(?:\w+/)*\w+\.py)((?: \S+)*)")


def docs_shell_lines():
    """(page, line) for every command line of every ```sh block of docs/*.md."""
    lines = []
    for page in DOCS:
        for block in re.finditer(r"```sh\n(.*?)```", page.read_text(), re.S):
            lines += [(page.name, line.strip()) for line in block.group(1).splitlines()
                      if line.strip() and not line.lstrip().startswith("#")]
    return lines


def test_docs_shell_lines_name_real_scripts_and_options():
    if not (VENV_BIN / "python").exists():
        pytest.skip("LOUD SKIP: no .venv in the checkout (%s): the docs' commands name .venv/bin, "
                    "create it as README's first line does" % VENV_BIN)
    lines = docs_shell_lines()
    assert len(lines) >= 10, lines  # docs/PERFORMANCE.md's list of benchmark commands
    helps = {}
    for page, line in lines:
        if any(key in line for key, _ in NOT_RUN):
            continue
        match = BENCH_LINE.fullmatch(line)
        assert match, "%s: %r is neither a benchmark command nor a line README's test runs" % (page, line)
        script, options = match.group(1), re.findall(r"(?<!\S)(--[\w-]+)", match.group(2))
        assert (README.parent / script).is_file(), "%s names a missing script: %r" % (page, line)
        if script not in helps:
            done = subprocess.run([str(VENV_BIN / "python"), script, "--help"], cwd=README.parent,
                                  capture_output=True, text=True, timeout=120)
            assert done.returncode == 0 and "usage:" in done.stdout, "%s --help: %s" % (script, done.stderr)
            helps[script] = done.stdout
        for option in options:
            assert option in helps[script], "%s: %s has no %s (%r)" % (page, script, option, line)
    assert "bench/run.py" in helps


def test_readme_stays_a_five_minute_read():
    """Issue 24: README at most 250 lines with these sections in this order (issue 53 asked for
    the fleet's); the rest is in docs/."""
    text = README.read_text()
    assert len(text.splitlines()) <= 250, "README has %d lines: move detail to docs/" % len(text.splitlines())
    sections = re.findall(r"^## (.*)$", text, re.M)
    assert sections == ["What it is", "Install", "First look: a simulated TurtleBot3", "The agent",
                        "A fleet of robots", "`xrce-client`: poke an agent from a shell", "The client on CPython",
                        "The client on MicroPython", "Figures against eProsima's agent"], sections
    assert text.index("```sh\npython3.11 -m venv .venv && .venv/bin/pip install -e . && ") < text.index("## ")
