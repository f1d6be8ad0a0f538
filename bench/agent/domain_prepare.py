"""What the default domain prepared at start costs an agent at rest (issue 51 item 6): CPU over a
window after a start-up pause, resident memory and threads, for this checkout and, taking turns in
each round, another checkout (``--reference``, e.g. main before the change); optionally both under
a Fast DDS Discovery Server of the ROS wheels (``--discovery-server``), where the default domain's
DDS participant is made at start.

    .venv/bin/python bench/agent/domain_prepare.py [--rounds 3] [--start 20] [--window 60]
        [--reference DIR] [--discovery-server]

CPU is the sum of every thread's time on a CPU (``/proc/<pid>/task/*/schedstat``, nanoseconds),
so a few milliseconds over a minute show, where clock ticks would round them to 0.
"""

import os
import signal
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from agent_process import AgentProcess  # noqa: E402

from bench.common.figures import print_table, record  # noqa: E402
from bench.common.peer_agent import CommandAgent  # noqa: E402
from bench.microros.entity_creation import _TREE_BOOTSTRAP  # noqa: E402


def cpu_ns(pid: int) -> int:
    total = 0
    for tid in os.listdir("/proc/%d/task" % pid):
        try:
            with open("/proc/%d/task/%s/schedstat" % (pid, tid)) as schedstat:
                total += int(schedstat.read().split()[0])
        except OSError:  # the thread has just ended
            pass
    return total


def resident_mb(pid: int) -> float:
    with open("/proc/%d/status" % pid) as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def threads(pid: int) -> int:
    return len(os.listdir("/proc/%d/task" % pid))


def at_rest(agent, start_s: float, window_s: float) -> tuple:
    """(% of a core over ``window_s`` after ``start_s``, resident MB, threads) of ``agent``."""
    time.sleep(start_s)
    before, started = cpu_ns(agent.pid), time.monotonic()
    time.sleep(window_s)
    cpu = (cpu_ns(agent.pid) - before) / 1e9 / (time.monotonic() - started)
    return 100 * cpu, resident_mb(agent.pid), threads(agent.pid)


class _Ours:
    """This checkout's agent, with ``pid``."""

    def __init__(self, env):
        self.agent = AgentProcess("udp4", "-m", "dds", "--no-state", env=env)

    def __enter__(self):
        self.agent.__enter__()
        self.pid = self.agent.proc.pid
        return self

    def __exit__(self, *exc):
        return self.agent.__exit__(*exc)


def discovery_server():
    """(the server's process, ROS_DISCOVERY_SERVER for it) on a free port of 127.0.0.1."""
    sys.path.insert(0, str(REPO / "tests" / "ros"))
    from test_discovery_server import _free_udp_port, _server_command

    port = _free_udp_port()
    server = subprocess.Popen(_server_command(port), stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    time.sleep(1.0)  # it says nothing we wait for here; a client retries its server anyway
    return server, "127.0.0.1:%d" % port


def main(argv=None):
    import argparse

    from ros_helpers import DomainLease

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--start", type=float, default=20.0, help="seconds before the window")
    parser.add_argument("--window", type=float, default=60.0)
    parser.add_argument("--reference", metavar="DIR")
    parser.add_argument("--discovery-server", action="store_true")
    args = parser.parse_args(argv)
    lease = DomainLease()
    env = dict(os.environ, ROS_DOMAIN_ID=str(lease.domain_id),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    server = None
    if args.discovery_server:
        server, address = discovery_server()
        env["ROS_DISCOVERY_SERVER"] = address
    starts = [("xrce", lambda: _Ours(env))]
    if args.reference:
        tree = str(Path(args.reference).resolve())
        starts.append(("reference", lambda: CommandAgent(
            [sys.executable, "-c", _TREE_BOOTSTRAP % tree], env,
            options=("-m", "dds", "--no-state"), cwd=tree)))
    results = {name: [] for name, _ in starts}
    try:
        for number in range(args.rounds):
            for name, start in starts:
                agent = start()
                try:
                    if isinstance(agent, _Ours):
                        with agent:
                            figures = at_rest(agent, args.start, args.window)
                    else:
                        figures = at_rest(agent, args.start, args.window)
                finally:
                    if not isinstance(agent, _Ours):
                        agent.stop()
                results[name].append(figures)
                print("round %d %-9s %.4f %% of a core, %.1f MB, %d threads (load average %.1f)"
                      % (number + 1, name, *figures, os.getloadavg()[0]), flush=True)
    finally:
        if server is not None:
            server.send_signal(signal.SIGINT)
            try:
                server.wait(10)
            except subprocess.TimeoutExpired:
                server.kill()
                server.wait()
        lease.release()
    where = " under a discovery server" if args.discovery_server else ""
    ours = results["xrce"]
    others = results.get("reference")
    for index, (label, unit) in enumerate((("CPU", "% of a core"), ("resident", "MB"),
                                           ("threads", ""))):
        value = statistics.median(r[index] for r in ours)
        baseline = statistics.median(r[index] for r in others) if others else None
        record("at rest%s, %.0f s after a %.0f s start: %s (median of %d)"
               % (where, args.window, args.start, label, args.rounds), value, unit, baseline,
               "reference %s" % args.reference if others else "", "",
               "runs: %s%s" % (", ".join("%.4g" % r[index] for r in ours),
                               "; reference: " + ", ".join("%.4g" % r[index] for r in others)
                               if others else ""))
    print_table()
    return 0


if __name__ == "__main__":
    sys.exit(main())
