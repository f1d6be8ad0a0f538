"""Another agent for side-by-side figures: a command line such as eProsima's MicroXRCEAgent
(built outside this repository, e.g. ``--agent-cmd $PEERS/agent.sh``), started the way
its users start it, ``<command> udp4 -p <port>`` (its defaults otherwise, ``-m dds`` among them).

Such an agent says nothing we could wait for, so it is ready when it answers a session-less
GET_INFO. eProsima's agent does not exit on SIGINT while a session is open: it is stopped with
SIGTERM, then killed if it hangs.
"""

import shlex
import signal
import socket
import subprocess
import time

from xrce.wire import constants as C
from xrce.wire.submessages import GetInfo, encode_message


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def answers_ping(port: int, timeout_s: float = 0.2) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(timeout_s)
        sock.sendto(encode_message(C.SESSION_ID_NONE_WITHOUT_KEY, C.STREAM_NONE, 0, None,
                                   [GetInfo()]), ("127.0.0.1", port))
        try:
            sock.recv(2048)
        except OSError:
            return False
        return True


class CommandAgent:
    """``CommandAgent("$PEERS/agent.sh", env)``: ``port``, ``pid``, ``stop()``."""

    def __init__(self, command, env: dict, start_timeout_s: float = 30.0, options=(), cwd=None):
        """``command``: a command line, or its argv; ``options`` come after ``udp4 -p PORT``."""
        self.port = free_udp_port()
        argv = shlex.split(command) if isinstance(command, str) else list(command)
        self.proc = subprocess.Popen(argv + ["udp4", "-p", str(self.port), *options], cwd=cwd,
                                     env=env, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL)
        self.pid = self.proc.pid  # the wrapper execs the agent: this is the agent's pid
        deadline = time.monotonic() + start_timeout_s
        while not answers_ping(self.port):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise RuntimeError("%r did not answer on port %d" % (command, self.port))

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()
