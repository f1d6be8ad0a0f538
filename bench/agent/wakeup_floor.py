"""What waking up costs a process on this machine, the floor under the agent's figures at low rates.

    .venv/bin/python bench/agent/wakeup_floor.py [--seconds S]

A receiver process that does nothing with a datagram but read it, fed single datagrams at a fixed
rate (paced per millisecond, as bench/agent/xrce_flood.py paces its samples), in three forms:

- ``asyncio``: an asyncio loop reading the socket from ``add_reader`` until it is drained, as
  the agent's UDP link does (xrce.agent.links.udp.UdpServer) and nothing else;
- ``uvloop``: the same on uvloop, the agent's loop by default (xrce.agent.cli.event_loop);
- ``python``: a plain Python loop blocked in ``recvfrom``;
- ``c``: the same loop compiled from C, when a C compiler is at hand (skipped otherwise);
- ``bridge`` (``bridge_floor``, run by bench/agent/cost.py next to its subscriber): the asyncio
  reader publishing a Twist with rclpy for each datagram, what a minimal Python bridge pays.

CPU comes from the receiver's ``/proc/<pid>/stat``. At a TurtleBot3's rate of wake-ups (about 150 a
second) and at 5k datagrams a second, the asyncio figure is what any asyncio agent pays before it
does any work; the agent's own figures (bench/agent/cost.py) sit on top of it.
"""

import argparse
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce

from bench.common.figures import record  # noqa: E402
from bench.common.harness import PYTHON, cpu_seconds  # noqa: E402

BURST_PERIOD_S = 0.001

# A receiver that reads every datagram waiting each time asyncio wakes it; {setup} runs first and
# {on_datagram} once per datagram ("pass": the do-nothing asyncio floor).
_ASYNCIO_TEMPLATE = r"""
import asyncio, socket, sys
{setup}
async def main():
    loop = asyncio.get_running_loop()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    def ready():
        while True:
            try:
                sock.recvfrom(2048)
            except BlockingIOError:
                return
            {on_datagram}
    loop.add_reader(sock.fileno(), ready)
    print(sock.getsockname()[1], flush=True)
    await loop.run_in_executor(None, sys.stdin.readline)
{run}(main())
"""

_ASYNCIO_RECEIVER = _ASYNCIO_TEMPLATE.format(setup="", on_datagram="pass", run="asyncio.run")
# The same on uvloop, the loop the agent runs on (xrce.agent.cli.event_loop).
_UVLOOP_RECEIVER = _ASYNCIO_TEMPLATE.format(setup="import uvloop", on_datagram="pass",
                                            run="uvloop.run")

# The least a Python bridge can do per datagram: the asyncio reader above, publishing a Twist's
# CDR bytes with rclpy for each datagram (argv: topic), the agent's job without XRCE.
_BRIDGE_RECEIVER = _ASYNCIO_TEMPLATE.format(on_datagram="publish(sample)", run="asyncio.run", setup=r"""
import rclpy
from geometry_msgs.msg import Twist
from rclpy.context import Context
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rclpy.signals import SignalHandlerOptions
context = Context()
rclpy.init(args=[], context=context, signal_handler_options=SignalHandlerOptions.NO)
node = Node("xrce_bridge_floor", context=context, start_parameter_services=False,
            enable_rosout=False)
publisher = node.create_publisher(Twist, sys.argv[1],
                                  QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT))
publish = publisher.publish
sample = serialize_message(Twist())""")

_PYTHON_RECEIVER = r"""
import socket, sys, threading
sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
sock.bind(("127.0.0.1", 0))
print(sock.getsockname()[1], flush=True)
def read():
    while True:
        sock.recvfrom(2048)
threading.Thread(target=read, daemon=True).start()
sys.stdin.readline()
"""

_C_RECEIVER = r"""
#include <arpa/inet.h>
#include <stdio.h>
#include <sys/socket.h>
#include <unistd.h>
int main(void) {
    int s = socket(AF_INET, SOCK_DGRAM, 0);
    struct sockaddr_in a = {0};
    socklen_t n = sizeof a;
    char buf[2048];
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (bind(s, (struct sockaddr *)&a, sizeof a) || getsockname(s, (struct sockaddr *)&a, &n))
        return 1;
    printf("%d\n", ntohs(a.sin_port));
    fflush(stdout);
    for (;;)
        recv(s, buf, sizeof buf, 0);
}
"""


def _offer(port, rate, seconds):
    """Send ``rate`` datagrams a second for ``seconds``, one sendto each; returns the count."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.connect(("127.0.0.1", port))
    payload = bytes(40)
    sent = 0
    start = time.monotonic()
    next_burst = start
    try:
        while True:
            now = time.monotonic()
            if now >= start + seconds:
                return sent
            if now < next_burst:
                time.sleep(next_burst - now)
                continue
            for _ in range(int((now - start) * rate) - sent):
                try:
                    sock.send(payload)
                except OSError:
                    pass
                sent += 1
            next_burst += BURST_PERIOD_S
    finally:
        sock.close()


def receiver_cost(command, rate, seconds, env=None, ready=None):
    """(CPU fraction of a core, CPU µs per datagram) of the receiver ``command`` at ``rate``;
    ``ready()`` (optional) returns once the receiver's peers are in place."""
    proc = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                            env=env)
    try:
        port = int(proc.stdout.readline())
        if ready is not None:
            ready()
        _offer(port, rate, 0.5)  # warm up
        before = cpu_seconds(proc.pid)
        sent = _offer(port, rate, seconds)
        time.sleep(0.2)
        cpu = cpu_seconds(proc.pid) - before
    finally:
        proc.kill()
        proc.wait()
        proc.stdin.close()
        proc.stdout.close()
    return cpu / seconds, 1e6 * cpu / max(sent, 1)


def wakeup_floors(seconds=5.0, rates=(150, 5000)):
    """{(kind, rate): (CPU fraction, µs per datagram)} for the receivers available here."""
    receivers = {"asyncio": [PYTHON, "-c", _ASYNCIO_RECEIVER],
                 "uvloop": [PYTHON, "-c", _UVLOOP_RECEIVER],
                 "python": [PYTHON, "-c", _PYTHON_RECEIVER]}
    build = None
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler:
        build = tempfile.mkdtemp(prefix="xrce-floor-")
        source = os.path.join(build, "receiver.c")
        with open(source, "w") as f:
            f.write(_C_RECEIVER)
        binary = os.path.join(build, "receiver")
        if subprocess.run([compiler, "-O2", "-o", binary, source]).returncode == 0:
            receivers["c"] = [binary]
    try:
        return {(kind, rate): receiver_cost(command, rate, seconds)
                for kind, command in receivers.items() for rate in rates}
    finally:
        if build:
            shutil.rmtree(build, ignore_errors=True)


def bridge_floor(env, topic, rates=(5000, 20000), seconds=5.0, ready=None):
    """{rate: (CPU fraction, µs per datagram)} of ``_BRIDGE_RECEIVER`` publishing on ``topic``
    in the ROS domain of ``env`` (a subscriber there makes the publish cost what it costs the
    agent)."""
    return {rate: receiver_cost([PYTHON, "-c", _BRIDGE_RECEIVER, topic], rate, seconds, env,
                                ready)
            for rate in rates}


def record_floors(floors):
    for (kind, rate), (fraction, per_datagram) in sorted(floors.items()):
        record("wake-up floor: %s receiver, %d datagrams/s" % (kind, rate), 100 * fraction,
               "% core", None, "-", "",
               "%.1f us per datagram; single datagrams paced per ms, nothing done with them"
               % per_datagram)


def main(argv=None):
    from bench.common.figures import print_table

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    args = parser.parse_args(argv)
    record_floors(wakeup_floors(args.seconds))
    print_table()
    return 0


if __name__ == "__main__":
    sys.exit(main())
