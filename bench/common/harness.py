"""What the bench groups share: line-protocol child processes (ros_peer.py, session_swarm.py,
serial_flood.py), a process's CPU time, polling, an agent's --stats-port, and the raw UDP echo that
is the baseline of every ping figure.
"""

import os
import re
import subprocess
import sys
import threading
import time

from bench.common import REPO

PYTHON = sys.executable


def stats_port(agent):
    return int(re.search(r"stats on 127\.0\.0\.1:(\d+)", agent.banner).group(1))


def cpu_seconds(pid):
    """User + system CPU time of a process and its threads, from /proc."""
    with open("/proc/%d/stat" % pid) as stat:
        fields = stat.read().rsplit(")", 1)[1].split()
    ticks = os.sysconf("SC_CLK_TCK")
    return (int(fields[11]) + int(fields[12])) / ticks


class Child:
    """A line-protocol child process (ros_peer.py, session_swarm.py, serial_flood.py)."""

    def __init__(self, args, env=None, ready=None, timeout=60):
        self.proc = subprocess.Popen([PYTHON, *args], cwd=REPO, env=env, stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                     bufsize=1)
        if ready is not None:
            line = self.readline(timeout)
            if not line.startswith(ready):
                self.close()
                raise RuntimeError("%s did not start: %r" % (args[0], line))
            self.first_line = line

    def readline(self, timeout=120):
        result = []
        reader = threading.Thread(target=lambda: result.append(self.proc.stdout.readline()),
                                  daemon=True)
        reader.start()
        reader.join(timeout)
        if not result:
            raise RuntimeError("no answer within %.0f s" % timeout)
        return result[0].strip()

    def ask(self, line, timeout=120):
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        return self.readline(timeout)

    def close(self):
        if self.proc.poll() is None:
            try:
                self.proc.stdin.write("quit\n")
                self.proc.stdin.flush()
                self.proc.stdin.close()
            except (BrokenPipeError, OSError):
                pass
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for stream in (self.proc.stdin, self.proc.stdout):
            try:
                stream.close()
            except (BrokenPipeError, OSError):
                pass


def wait_for(predicate, timeout_s=10.0, interval_s=0.05):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() >= deadline:
            return False
        time.sleep(interval_s)
    return True


UDP_ECHO = r"""
import socket, sys
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind(("127.0.0.1", 0))
print(s.getsockname()[1], flush=True)
while True:
    data, addr = s.recvfrom(2048)
    if data == b"quit":
        break
    s.sendto(data, addr)
"""


def udp_echo_rtts(count):
    """Round trips of a 16-byte datagram to a Python echo process, in microseconds."""
    import socket

    echo = subprocess.Popen([PYTHON, "-c", UDP_ECHO], stdout=subprocess.PIPE, text=True)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        address = ("127.0.0.1", int(echo.stdout.readline()))
        sock.settimeout(1.0)
        rtts = []
        for _ in range(count):
            start = time.perf_counter_ns()
            sock.sendto(b"0123456789abcdef", address)
            sock.recvfrom(2048)
            rtts.append((time.perf_counter_ns() - start) / 1000.0)
        sock.sendto(b"quit", address)
        echo.wait(5)
        return rtts
    finally:
        sock.close()
        if echo.poll() is None:
            echo.kill()
            echo.wait()
        echo.stdout.close()
