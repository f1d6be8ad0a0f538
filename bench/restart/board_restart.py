"""A board that never re-creates its session, across a restart of the agent (issue 51): how long
until ROS and the board hear each other again, and what is lost.

    XRCE_EPROSIMA_CLIENT=PREFIX unshare -n sh -c 'ip link set lo up && \\
        .venv/bin/python bench/restart/board_restart.py [--runs 3] [--baseline-checkout DIR]'
    (also: bench/restart/restart_gap.py --board-once ...)

eProsima's client in tests/recovery/programs/board_once.c (best-effort and reliable writers at
10 Hz, a reader of /board_cmd with a standing READ_DATA, a replier) against ``xrce-agent -m dds
--state FILE``, over UDP and over a pty pair; rclpy publishes /board_cmd (reliable, 20 Hz),
subscribes to the board's writers and calls its service. The agent is stopped (SIGINT) or killed
(SIGKILL), started again 1 s later on the same port or device and store, and each run reports,
from the restarted agent's banner: the first board sample in ROS, the first /board_cmd at the
board, the first reliable board sample in ROS, the best-effort samples lost across the gap, and
whether a service call made then is answered within 5 s. Medians of ``--runs`` runs per stop
kind and link. ``--baseline-checkout DIR`` runs the agent of another checkout (e.g. the commit
before a change, exported with ``git archive``; the venv's compiled extensions are used) in the
same run, alternating with this one, as the baseline column.
"""

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import tty
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(REPO / "tests" / "recovery"), str(REPO / "tests" / "helpers"), str(REPO)]

import eprosima_client  # noqa: E402
from agent_process import AgentProcess  # noqa: E402
from board_side import INTERFACES, PROGRAM, Board, RosSide, free_udp_port  # noqa: E402
from ros_helpers import DomainLease, RosPeer, wait_until  # noqa: E402

AWAY_S = 1.0
SETTLE_S = 2.0
WAIT_S = 10.0

# Runs ``xrce.agent`` from another checkout: the venv's editable install (and the interface
# registry its .pth activates) would import this one.
_OTHER = """import sys, runpy
sys.meta_path[:] = [f for f in sys.meta_path if not (type(f).__module__.startswith(("xrce", "__editable")))]
registry = [k for k in sys.modules if k == "xrce" or k.startswith("xrce.")]
for name in registry:
    del sys.modules[name]
sys.path.insert(0, %r)
import glob, xrce, xrce.agent.interfaces as m
for path in glob.glob(sys.prefix + "/lib/python*/site-packages/xrce_interfaces.json"):
    m.activate_registry(path)
assert xrce.__file__.startswith(sys.path[0]), xrce.__file__
runpy.run_module("xrce.agent", run_name="__main__", alter_sys=True)
"""


class Agent(AgentProcess):
    def __init__(self, *args, checkout=None):
        super().__init__(*args)
        self.checkout = checkout

    def __enter__(self):
        if self.checkout is None:
            return super().__enter__()
        from procs import read_until
        self.proc = subprocess.Popen([sys.executable, "-c", _OTHER % str(self.checkout),
                                      *self.args], cwd=str(self.checkout), env=self.env,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        line, output = read_until(self.proc, lambda l: l.startswith("xrce-agent:") and (
            "agent on port" in l or "serial" in l), self.start_timeout)
        self.output.append(output)
        if line is None:
            self.stop()
            raise RuntimeError("agent did not start: %s" % output)
        self.banner = line.strip()
        return self


def one_run(exe, ros, link, stop, checkout, work):
    state = os.path.join(work, "state-%d.sqlite3" % time.monotonic_ns())
    fds = ()
    if link == "udp":
        port = free_udp_port()
        agent_args = ("udp4", "-p", str(port))
        board_args = ("udp", "127.0.0.1", str(port), "120")
    else:
        master, slave = os.openpty()
        tty.setraw(master)
        tty.setraw(slave)
        fds = (master, slave)
        agent_args = ("serial", "-D", os.ttyname(slave))
        board_args = ("serial-fd", str(master), "120")
    agent_args += ("-m", "dds", "-v", "4", "--state", state, "--interfaces", INTERFACES)
    agent = Agent(*agent_args, checkout=checkout).__enter__()
    board = Board(exe, board_args, fds[:1])
    result = {}
    try:
        if not (wait_until(lambda: board.has("READY"), 30) and
                wait_until(lambda: ros.sensor and board.commands(), 30)):
            agent.drain()
            raise RuntimeError("the board did not start talking: %s ... %s\n%s" % (
                board.lines[:3], board.lines[-3:], "".join(agent.output)[-3000:]))
        time.sleep(SETTLE_S)
        if stop == "SIGINT":
            agent.stop()
        else:
            agent.proc.send_signal(signal.SIGKILL)
            agent.proc.wait(10)
        last_sensor = ros.sensor[-1][1]
        time.sleep(AWAY_S)
        agent = Agent(*agent_args, checkout=checkout).__enter__()
        banner = time.monotonic()
        wait_until(lambda: ros.sensor[-1][0] > banner, WAIT_S)
        wait_until(lambda: board.commands(since=banner), WAIT_S)
        wait_until(lambda: any(t > banner for t, _ in ros.reliable), WAIT_S)
        sensor = [(t, v) for t, v in ros.sensor if t > banner]
        cmds = board.commands(since=banner)
        reliable = [t for t, _ in ros.reliable if t > banner]
        result["sensor_s"] = sensor[0][0] - banner if sensor else None
        result["cmd_s"] = cmds[0][0] - banner if cmds else None
        result["reliable_s"] = reliable[0] - banner if reliable else None
        result["lost"] = sensor[0][1] - last_sensor - 1 if sensor else None
        result["answered"] = ros.call(4, 5, timeout=5.0) == 9
    finally:
        board.stop()
        agent.stop()
        for fd in fds:
            os.close(fd)
        for suffix in ("", "-wal", "-shm"):
            try:
                os.unlink(state + suffix)
            except FileNotFoundError:
                pass
    return result


def _median(values):
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def _fmt(value, unit=" s"):
    return "never" if value is None else ("%.2f%s" % (value, unit) if unit else "%d" % value)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--links", default="udp,serial")
    parser.add_argument("--stops", default="SIGINT,SIGKILL")
    parser.add_argument("--baseline-checkout", type=Path, default=None,
                        help="another checkout whose agent is measured in the same run")
    args = parser.parse_args(argv)
    reason = eprosima_client.missing_reason()
    if reason:
        print(reason)
        return 2
    lease = DomainLease()
    os.environ["ROS_DOMAIN_ID"] = str(lease.domain_id)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    work = tempfile.mkdtemp(prefix="xrce-bench-restart-")
    exe = eprosima_client.build(PROGRAM, Path(work) / "build")
    peer = RosPeer(lease.domain_id)
    ros = RosSide(peer)
    agents = [("this checkout", None)]
    if args.baseline_checkout is not None:
        agents.insert(0, ("baseline %s" % args.baseline_checkout, args.baseline_checkout))
    figures = {}
    failed = []  # runs whose board never started talking (before any restart)
    try:
        for link in args.links.split(","):
            for stop in args.stops.split(","):
                for index in range(args.runs):
                    for name, checkout in agents:  # alternating: the same load for both
                        try:
                            got = one_run(exe, ros, link, stop, checkout, work)
                        except RuntimeError as exc:  # said and counted, not measured
                            failed.append("%s %s %s run %d: %s" % (link, stop, name, index + 1,
                                                                   str(exc)[:600]))
                            print(failed[-1], flush=True)
                            continue
                        figures.setdefault((link, stop, name), []).append(got)
                        print("%s %s %s run %d: %s" % (link, stop, name, index + 1, got),
                              flush=True)
    finally:
        ros.stop()
        peer.close()
        lease.release()
        import shutil
        shutil.rmtree(work, ignore_errors=True)
    print("\nmedians of %d runs, from the restarted agent's banner:" % args.runs)
    print("%-7s %-8s %-40s %12s %12s %12s %6s %9s" % ("link", "stop", "agent", "ROS sample",
                                                     "/board_cmd", "reliable", "lost",
                                                     "answered"))
    for (link, stop, name), runs in figures.items():
        print("%-7s %-8s %-40s %12s %12s %12s %6s %6d/%d" % (
            link, stop, name, _fmt(_median([r["sensor_s"] for r in runs])),
            _fmt(_median([r["cmd_s"] for r in runs])),
            _fmt(_median([r["reliable_s"] for r in runs])),
            _fmt(_median([r["lost"] for r in runs]), ""),
            sum(1 for r in runs if r["answered"]), len(runs)))
    if failed:
        print("%d runs left out, their board never started talking before the restart:" %
              len(failed))
    return 0


if __name__ == "__main__":
    sys.exit(main())
