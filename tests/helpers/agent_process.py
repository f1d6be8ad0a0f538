"""Start ``python -m xrce.agent`` as a real process for a test and stop it cleanly afterwards."""

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "bench" / "common"))

from procs import read_until  # noqa: E402


# The signals tests send their children. A process started with them ignored (a background job of
# a script, ``nohup sh -c '...' &``) passes SIG_IGN on to every child it starts: an agent or client
# a test stops with Ctrl-C would then go on running. Every test child that gets a signal starts with
# these at their defaults, as it would from a terminal.
SIGNALS_TESTS_SEND = (signal.SIGINT, signal.SIGTERM)


def restore_default_signals():
    """``preexec_fn`` for a test's child process: the signals tests send at their defaults."""
    for signum in SIGNALS_TESTS_SEND:
        signal.signal(signum, signal.SIG_DFL)


_TRANSPORTS = ("udp4", "udp6", "tcp4", "tcp6", "serial", "multiserial", "pseudoterminal")


def _is_banner(line):
    return line.startswith("xrce-agent:") and ("agent on port" in line or "pseudoterminal at" in line
                                               or "serial" in line)


class AgentProcess:
    """``with AgentProcess("udp4", "-m", "ced") as agent: agent.port`` — the agent listens on a free
    port (``-p 0``) unless the arguments name one; the banner line tells which."""

    def __init__(self, *args, env=None, start_timeout=60, cwd=REPO):
        self.args = list(args)
        if self.args and self.args[0] in ("udp4", "udp6", "tcp4", "tcp6") and "-p" not in self.args:
            self.args += ["-p", "0"]
        if self.args and self.args[0] in _TRANSPORTS and "--state" not in self.args and \
                "--no-state" not in self.args:
            # A test's agent keeps no state unless the test gives it a file of its own: nothing
            # of one test's sessions may be restored into another's agent.
            self.args.append("--no-state")
        self.env = dict(os.environ, **(env or {}))
        self.start_timeout = start_timeout
        self.cwd = cwd  # the checkout's xrce is importable from there; an installed one elsewhere
        self.proc = None
        self.port = None
        self.device = None
        self.banner = None
        self.output = []

    def __enter__(self):
        self.proc = subprocess.Popen([sys.executable, "-m", "xrce.agent", *self.args], cwd=self.cwd,
                                     env=self.env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, preexec_fn=restore_default_signals)
        line, output = read_until(self.proc, _is_banner, self.start_timeout)
        self.output.append(output)
        if line is not None:
            self.banner = line.strip()
            port = re.search(r"on port (\d+)", line)
            self.port = int(port.group(1)) if port else None
            device = re.search(r"pseudoterminal at ([^\s;]+)", line)
            self.device = device.group(1) if device else None
            return self
        self.stop()
        raise RuntimeError("agent did not start: %s" % "".join(self.output))

    def stop(self, timeout=20):
        """SIGINT, as a user's Ctrl-C; returns the exit code (killing it if it hangs)."""
        if self.proc is None or self.proc.poll() is not None:
            return None if self.proc is None else self.proc.returncode
        self.proc.send_signal(signal.SIGINT)
        try:
            rest, _ = self.proc.communicate(timeout=timeout)
            self.output.append(rest or "")
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.communicate()
        return self.proc.returncode

    def drain(self):
        """Keep what the agent has logged so far (in ``output``) without waiting for more. At -v 4
        (the default) the agent logs a line per object; a test that makes many objects without
        reading its log must call this now and then, or the agent blocks on a full pipe (64 KiB)."""
        line, output = read_until(self.proc, lambda text: False, 0.01)
        self.output.append(output)

    def __exit__(self, *exc):
        self.stop()


def child_pids(pid: int) -> list:
    """PIDs whose parent is ``pid`` (read from /proc: no psutil in the test venv)."""
    children = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open("/proc/%s/stat" % entry) as f:
                    fields = f.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                children.append(int(entry))
    return children
