"""Boards that reboot, reconnect and vanish, against one agent: what stays behind (issue 39).

    .venv/bin/python bench/churn/churn.py [--minutes M] [--same-key] [--agent-cmd CMD]
        [--agent-args "ARGS"] [--serial] [--soak] [--warmup S] [--json FILE]

churn (default): every second a "board" (xrce.client over UDP, in this process) pings the agent,
creates a session under a new client key (``--same-key``: always the same one), a participant,
a reliable ``/odom`` and a best-effort ``/imu`` writer and a reliable ``/cmd_vel`` reader, waiting
up to 2 s for each STATUS, publishes 5 samples on each writer, then vanishes without DELETE (its
socket closed). A board whose session or any entity is not confirmed within that time counts as
a failed creation. ``--serial``: the same over a pseudo-terminal pair, the agent serving
``serial --dev LINK``; each life makes a new pair and points LINK at it, and closes its end when
it vanishes, as a USB board re-enumerates (the agent sees its device fail and reopens it).

soak (``--soak``): the simulated TurtleBot3 (xrce/examples/turtlebot3.py, its own process)
publishes steadily while 10 boards beside it each live 10 s (a sample a second on
``/board/odom`` and ``/board/imu``) and vanish, staggered by 1 s; an rclpy subscriber counts the
robot's ``/odom`` samples against those it published (lost should be 0).

Measured from the agent's /proc every 10 s: resident memory (VmRSS) at start, after ``--warmup``
seconds (default 300) and at the end, and its slope in MB/h by least squares over the samples
after the warm-up; CPU (utime + stime) per 5-minute window; ``/odom`` publishers in the ROS graph
(an rclpy node's ``count_publishers``, bench/common/ros_peer.py) over time and at the end.

The agent is this tree's ``xrce-agent`` (``--agent-args`` appended to ``udp4 -p 0``) or another
agent's command line (``--agent-cmd $PEERS/agent.sh``: eProsima's MicroXRCEAgent, run as
``udp4 -p PORT -m dds``; bench/common/peer_agent.py). Run every mode in a private network namespace and
/dev/shm, one agent per namespace, e.g.
``unshare -nm sh -c 'mount -t tmpfs tmpfs /dev/shm && ip link set lo up && exec CMD'``.

``CHURN_DUMP=FILE`` in the environment (this tree's agent only): the agent process appends, every
60 s, its live Python objects counted by type (the 25 that grew most since the first count),
glibc's malloc figures and, under PYTHONTRACEMALLOC=1, the source lines whose allocations grew
most, to FILE: where the memory goes when RSS grows.
"""

import argparse
import json
import os
import random
import re
import select
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from bench.agent.cost import rss_mb  # noqa: E402
from bench.common.harness import PYTHON, Child, cpu_seconds, wait_for  # noqa: E402
from bench.common.peer_agent import CommandAgent  # noqa: E402
from bench.common.procs import interrupt, read_until  # noqa: E402

from xrce.client.ping import ping_agent  # noqa: E402
from xrce.client.session import Session  # noqa: E402
from xrce.msgs.geometry_msgs import Twist  # noqa: E402
from xrce.msgs.nav_msgs import Odometry  # noqa: E402
from xrce.msgs.sensor_msgs import Imu  # noqa: E402
from xrce.transports.custom import CustomTransport  # noqa: E402
from xrce.transports.udp import UdpTransport  # noqa: E402

SAMPLE_PERIOD_S = 10.0
CPU_WINDOW_S = 300.0
STATUS_WAIT_MS = 2000  # a board waits this long for each STATUS
SAMPLES_PER_LIFE = 5
LARGEST_SAMPLE = 720  # /odom with frame ids: fragmented, as the TurtleBot3's
SAME_KEY = 0x0C0FFEE5

# Started with ``python -c``: counts the agent's live objects by type every 60 s when CHURN_DUMP
# names a file, then runs the agent as ``xrce-agent`` would.
AGENT_BOOT = r"""
import os, runpy, sys
dump = os.environ.get("CHURN_DUMP")
if dump:
    import collections, ctypes, gc, threading, time, tracemalloc
    class MallInfo2(ctypes.Structure):
        _fields_ = [(name, ctypes.c_size_t) for name in (
            "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks",
            "fordblks", "keepcost")]
    mallinfo2 = ctypes.CDLL(None).mallinfo2
    mallinfo2.restype = MallInfo2
    def count():
        return collections.Counter(type(o).__qualname__ for o in gc.get_objects())
    def objs(name):
        return [o for o in gc.get_objects() if type(o).__qualname__ == name]
    def describe(obj):
        if isinstance(obj, dict):
            return "dict(%s)" % ",".join(sorted(str(k) for k in list(obj)[:6]))
        name = getattr(obj, "__qualname__", None) or getattr(getattr(obj, "__func__", None),
                                                              "__qualname__", "")
        return "%s %s" % (type(obj).__qualname__, name)
    def referrers(name):
        everything = gc.get_objects()
        found = [o for o in everything if type(o).__qualname__ == name][:3]
        skip = {id(everything), id(found)}
        out = []
        for obj in found:
            paths, level = [], [(obj, "")]
            for _ in range(5):
                nxt = []
                for item, path in level:
                    for ref in gc.get_referrers(item):
                        if id(ref) in skip or type(ref).__name__ == "frame" or ref is level:
                            continue
                        nxt.append((ref, path + " <- " + describe(ref)))
                level = nxt[:6]
            out.append("    %s: %s" % (name, " || ".join(p for _, p in level)))
        del everything
        return "\n".join(out)
    def dumper():
        first = snapshot = None
        start = time.monotonic()
        while True:
            time.sleep(60)
            if os.environ.get("CHURN_COLLECT"):
                gc.collect()
            now = count()
            if first is None:
                first = now
                snapshot = tracemalloc.take_snapshot() if tracemalloc.is_tracing() else None
            grown = sorted(((now[k] - first.get(k, 0), k) for k in now), reverse=True)[:25]
            info = mallinfo2()
            lines = ["t=%.0f objects=%d blocks=%d malloc in use %.2f MB, free %.2f MB, mmapped "
                     "%.2f MB; %s" % (time.monotonic() - start, sum(now.values()),
                     sys.getallocatedblocks(), info.uordblks / 1e6, info.fordblks / 1e6,
                     info.hblkhd / 1e6,
                     " ".join("%s:+%d(%d)" % (k, d, now[k]) for d, k in grown if d))]
            for expression in filter(None, os.environ.get("CHURN_EVAL", "").split(";")):
                try:
                    value = eval(expression, {"objs": objs})
                except Exception as exc:
                    value = repr(exc)
                lines.append("    %s = %s" % (expression, value))
            for name in filter(None, os.environ.get("CHURN_REFS", "").split(",")):
                lines.append(referrers(name))
            if snapshot is not None:
                for stat in tracemalloc.take_snapshot().compare_to(snapshot, "lineno")[:12]:
                    lines.append("    %s" % stat)
            with open(dump, "a") as out:
                out.write("\n".join(lines) + "\n")
    threading.Thread(target=dumper, daemon=True).start()
sys.argv[0] = "xrce-agent"
runpy.run_module("xrce.agent", run_name="__main__", alter_sys=True)
"""


class XrceAgent:
    """This tree's agent: ``xrce-agent udp4 -p 0 ARGS`` or ``xrce-agent serial --dev LINK ARGS``."""

    def __init__(self, env, args=(), serial_link=None):
        if serial_link is None:
            argv = ["udp4", "-p", "0"]
        else:
            argv = ["serial", "--dev", serial_link, "-b", "115200"]
        self.proc = subprocess.Popen([PYTHON, "-c", AGENT_BOOT, *argv, *args], cwd=REPO, env=env,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        line, output = read_until(self.proc, lambda text: "(middleware" in text, 90)
        if line is None:
            self.stop()
            raise RuntimeError("the agent did not start:\n%s" % output)
        match = re.search(r"on port (\d+)", line)
        self.port = int(match.group(1)) if match else None
        self.pid = self.proc.pid
        self.log = []
        threading.Thread(target=self._drain, daemon=True).start()

    def _drain(self):
        for line in self.proc.stdout:
            if len(self.log) < 2000:
                self.log.append(line.rstrip())

    def stop(self):
        interrupt(self.proc, 20)


# ---------------------------------------------------------------------- boards


class PtyBoardLink:
    """The board's end of a fresh pseudo-terminal pair; ``link`` (a symlink the agent serves) is
    pointed at the other end, as a re-enumerated USB board comes back under the same name."""

    def __init__(self, link):
        self.master, slave = os.openpty()
        # Never block on a full pty (an agent that stopped reading): the life fails instead.
        os.set_blocking(self.master, False)
        import tty

        tty.setraw(slave)
        name = os.ttyname(slave)
        os.close(slave)
        staging = link + ".new"
        os.symlink(name, staging)
        os.replace(staging, link)
        self.link, self.name = link, name
        self.transport = CustomTransport(lambda _u: True, lambda _u: True, self._write,
                                         self._read, framing=True, local_addr=1, remote_addr=0)

    def _write(self, _user, data):
        try:
            return os.write(self.master, bytes(data))
        except OSError:  # EAGAIN: the agent is not reading; EIO: it has not opened its end
            return 0

    def _read(self, _user, buf, size, timeout_ms):
        ready, _, _ = select.select([self.master], [], [], max(timeout_ms, 0) / 1000.0)
        if not ready:
            return 0
        try:
            data = os.read(self.master, size)
        except OSError:  # EIO: the agent has not (re)opened its end yet
            time.sleep(min(max(timeout_ms, 0), 20) / 1000.0)
            return 0
        buf[:len(data)] = data
        return len(data)

    def close(self):
        # The link goes first, as an unplugged USB device's node does: closing the master frees
        # the pty's number, and an agent reopening a link that still named /dev/pts/N would open
        # (and lock) whatever pty took that number next, another process's (seen while a test
        # suite ran beside the serial churn).
        try:
            if os.readlink(self.link) == self.name:
                os.unlink(self.link)
        except OSError:
            pass
        os.close(self.master)


class Board:
    """One life of a board: ping, session, participant, /odom (reliable) and /imu (best-effort)
    writers, a /cmd_vel reader; ``vanish()`` closes its link without DELETE."""

    def __init__(self, key, domain_id, prefix="", udp_port=None, serial_link=None):
        self.link = PtyBoardLink(serial_link) if serial_link else None
        transport = self.link.transport if self.link else UdpTransport("127.0.0.1", udp_port)
        self.session = Session(transport, key=key, history=4, auto_recover=False,
                               largest_sample=LARGEST_SAMPLE)
        self.domain_id = domain_id
        self.prefix = prefix
        self.odom = self.imu = None
        self.commands = 0

    def create(self):
        """None when every STATUS came back OK in time, else what failed."""
        session = self.session
        if ping_agent(session.transport, 200, 15) is None:
            return "ping"
        if not session.create(attempts=1, timeout_ms=STATUS_WAIT_MS):
            return "session"
        node = session.create_participant(domain_id=self.domain_id, name="churn_board")
        if not session.run_until_all_status(STATUS_WAIT_MS):
            return "participant"
        self.odom = session.create_writer(node, self.prefix + "/odom", Odometry, reliable=True)
        if not session.run_until_all_status(STATUS_WAIT_MS):
            return "odom writer"
        self.imu = session.create_writer(node, self.prefix + "/imu", Imu, reliable=False)
        if not session.run_until_all_status(STATUS_WAIT_MS):
            return "imu writer"
        session.create_reader(node, self.prefix + "/cmd_vel", Twist, self._on_cmd_vel)
        if not session.run_until_all_status(STATUS_WAIT_MS):
            return "cmd_vel reader"
        return None

    def _on_cmd_vel(self, _twist):
        self.commands += 1

    def publish(self, odom, imu):
        self.session.write(self.odom, odom, stream_id=self.session.reliable)
        self.session.write(self.imu, imu, stream_id=self.session.best_effort)
        self.session.flush()

    def vanish(self):
        self.session.close()  # UDP: the socket; serial: nothing (the pty end goes below)
        if self.link is not None:
            self.link.close()


def life_keys(same_key):
    rng = random.Random(os.getpid())
    while True:
        yield SAME_KEY if same_key else rng.randrange(1, 0xFFFFFFFF)


def churn_lives(args, agent, domain_id, deadline, stats, stopped):
    """One board life a second until ``deadline``, each vanishing after its 5 samples."""
    keys = life_keys(args.same_key)
    odom, imu = Odometry(), Imu()
    odom.header.frame_id, odom.child_frame_id, imu.header.frame_id = "odom", "base_footprint", "imu"
    due = time.monotonic()
    while True:
        now = time.monotonic()
        if due >= deadline or stopped.is_set():
            return
        if due > now:
            time.sleep(due - now)
        elif now - due > args.period:
            # This process fell behind (a stalled machine): the lives it missed are skipped, not
            # made up in a burst, which would be another pace than one life a period.
            stats["skipped"] = stats.get("skipped", 0) + int((now - due) // args.period)
            due = now
        due += args.period
        board = Board(next(keys), domain_id, udp_port=agent.port, serial_link=args.link)
        try:
            failed = board.create()
            if failed is None:
                for _ in range(SAMPLES_PER_LIFE):
                    board.publish(odom, imu)
                    board.session.run_until_timeout(20)
                board.session.run_until_timeout(100)  # the reliable samples' acknowledgements
        finally:
            board.vanish()
        stats["lives"] += 1
        if failed is not None:
            stats["failed"] += 1
            stats["failures"][failed] = stats["failures"].get(failed, 0) + 1


def soak_boards(args, agent, domain_id, deadline, stats, stopped, boards=10, life_s=10.0):
    """``boards`` boards beside the robot, each living ``life_s`` seconds (a sample a second)
    then vanishing, staggered so that one reconnects every ``life_s / boards`` seconds."""
    keys = life_keys(False)
    odom, imu = Odometry(), Imu()
    live = {}  # slot -> (board, vanish at, next sample at)
    start = time.monotonic()
    next_life = [start + slot * life_s / boards for slot in range(boards)]
    while time.monotonic() < deadline and not stopped.is_set():
        now = time.monotonic()
        for slot in range(boards):
            if slot in live and now >= live[slot][1]:
                live.pop(slot)[0].vanish()
            if slot not in live and now >= next_life[slot]:
                next_life[slot] += life_s
                board = Board(next(keys), domain_id, prefix="/board", udp_port=agent.port)
                failed = board.create()
                stats["lives"] += 1
                if failed is not None:
                    stats["failed"] += 1
                    stats["failures"][failed] = stats["failures"].get(failed, 0) + 1
                    board.vanish()
                    continue
                live[slot] = (board, next_life[slot], time.monotonic())
        for slot, (board, vanish_at, sample_at) in list(live.items()):
            if time.monotonic() >= sample_at:
                board.publish(odom, imu)
                live[slot] = (board, vanish_at, sample_at + 1.0)
            board.session.spin_once(0)
        time.sleep(0.02)
    for board, _, _ in live.values():
        board.vanish()


# ---------------------------------------------------------------------- the robot (soak)

ROBOT = r"""
import sys
from xrce.examples.turtlebot3 import TurtleBot3
from xrce.transports.udp import UdpTransport
robot = TurtleBot3(UdpTransport("127.0.0.1", int(sys.argv[1])), domain_id=int(sys.argv[2]),
                   log=lambda text: None)
if robot.connect(attempts=30) is None or not robot.setup():
    print("error no session", flush=True)
    sys.exit(1)
print("ready", flush=True)
sys.stdin.readline()  # go: the ROS subscriber has matched the agent's /odom writer
import select
while not select.select([sys.stdin], [], [], 0)[0]:
    robot.step()
sys.stdin.readline()  # stop publishing; acknowledge what is in flight, then say what went out
robot.session.run_until_timeout(3000)
print("published %d" % robot.published["odom"], flush=True)
sys.stdin.readline()
robot.shutdown()
"""


# ---------------------------------------------------------------------- measuring


class Sampler(threading.Thread):
    """Every SAMPLE_PERIOD_S: (seconds since start, agent RSS MB, agent CPU s, /odom publishers)."""

    def __init__(self, pid, ros, topic, rss_limit_mb=None):
        super().__init__(daemon=True)
        self.rss_limit_mb = rss_limit_mb
        self.stop_boards = threading.Event()  # the agent's RSS passed rss_limit_mb, or SIGUSR1
        self.pid, self.ros, self.topic = pid, ros, topic
        self.samples = []
        self.stopping = threading.Event()
        self.start_time = time.monotonic()

    def sample(self):
        publishers = int(self.ros.ask("publishers %s" % self.topic))
        self.samples.append((time.monotonic() - self.start_time, rss_mb(self.pid),
                             cpu_seconds(self.pid), publishers))
        if self.rss_limit_mb and self.samples[-1][1] > self.rss_limit_mb:
            self.stop_boards.set()

    def run(self):
        while True:
            self.sample()
            if self.stopping.wait(SAMPLE_PERIOD_S):
                return

    def finish(self):
        self.stopping.set()
        self.join()
        self.sample()
        return self.samples


def slope_mb_per_hour(points):
    """Least-squares slope of (seconds, MB) points, in MB/h; None under 3 points."""
    if len(points) < 3:
        return None
    n = float(len(points))
    mean_t = sum(t for t, _ in points) / n
    mean_m = sum(m for _, m in points) / n
    var = sum((t - mean_t) ** 2 for t, _ in points)
    return 3600.0 * sum((t - mean_t) * (m - mean_m) for t, m in points) / var if var else None


def summarize(samples, warmup_s):
    rss_at = lambda when: min(samples, key=lambda s: abs(s[0] - when))[1]  # noqa: E731
    after = [(t, rss) for t, rss, _cpu, _pubs in samples if t >= warmup_s]
    windows = []
    for index in range(1, len(samples)):
        t, _rss, cpu, _pubs = samples[index]
        w = int(samples[index - 1][0] // CPU_WINDOW_S)  # the window the interval starts in
        while len(windows) <= w:
            windows.append([0.0, 0.0])
        windows[w][0] += cpu - samples[index - 1][2]
        windows[w][1] += t - samples[index - 1][0]
    return {
        "rss_start": samples[0][1],
        "rss_warm": rss_at(warmup_s) if samples[-1][0] >= warmup_s else None,
        "rss_end": samples[-1][1],
        "slope_mb_h": slope_mb_per_hour(after),
        "cpu_windows": [round(100.0 * c / d, 1) for c, d in windows if d > 0],
        "cpu_mean": round(100.0 * (samples[-1][2] - samples[0][2])
                          / max(samples[-1][0] - samples[0][0], 1e-9), 1),
        "publishers_end": samples[-1][3],
        "publishers_max": max(s[3] for s in samples),
    }


def run(args):
    from ros_helpers import DomainLease

    lease = DomainLease()
    env = dict(os.environ, ROS_DOMAIN_ID=str(lease.domain_id),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    workdir = tempfile.mkdtemp(prefix="xrce-churn-")
    args.link = os.path.join(workdir, "ttyBOARD") if args.serial else None
    agent = ros = robot = None
    stats = {"lives": 0, "failed": 0, "failures": {}}
    result = {"mode": "soak" if args.soak else ("serial" if args.serial else "churn"),
              "same_key": args.same_key, "minutes": args.minutes}
    try:
        if args.agent_cmd:
            agent = CommandAgent(args.agent_cmd, env, options=["-m", "dds"])
            result["agent"] = args.agent_cmd
        else:
            if args.link:
                PtyBoardLink(args.link).close()  # a device for the agent to open first
            agent = XrceAgent(env, shlex.split(args.agent_args), serial_link=args.link)
            result["agent"] = "xrce-agent " + args.agent_args
        ros = Child(["bench/common/ros_peer.py"], env=env, ready="ready")
        topic = "/board/odom" if args.soak else "/odom"
        if args.soak:
            ros.ask("sub /odom rel nav_msgs/msg/Odometry")
            robot = subprocess.Popen([PYTHON, "-c", ROBOT, str(agent.port), str(lease.domain_id)],
                                     cwd=REPO, env=env, stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                     bufsize=1)
            if robot.stdout.readline().strip() != "ready":
                raise RuntimeError("the simulated robot did not start")
            if not wait_for(lambda: ros.ask("publishers /odom") != "0", timeout_s=60):
                raise RuntimeError("the robot's /odom never reached the ROS graph")
            time.sleep(2.0)  # both sides' discovery: the writer matches the subscriber
            robot.stdin.write("go\n")
            robot.stdin.flush()
        time.sleep(2.0)
        sampler = Sampler(agent.pid, ros, topic, args.rss_limit)
        sampler.start()
        # SIGUSR1 ends the boards' part early and reports as usual (a run the machine cannot
        # afford any longer).
        signal.signal(signal.SIGUSR1, lambda *_: sampler.stop_boards.set())
        deadline = time.monotonic() + 60.0 * args.minutes
        if args.soak:
            soak_boards(args, agent, lease.domain_id, deadline, stats, sampler.stop_boards)
        else:
            churn_lives(args, agent, lease.domain_id, deadline, stats, sampler.stop_boards)
        samples = sampler.finish()
        if args.soak:
            robot.stdin.write("stop\n")
            robot.stdin.flush()
            sent = int(robot.stdout.readline().split()[1])
            time.sleep(2.0)
            received = int(ros.ask("count /odom").split()[0])
            result.update(odom_sent=sent, odom_received=received, odom_lost=sent - received)
            robot.stdin.write("quit\n")
            robot.stdin.flush()
        result.update(stats)
        result["minutes_run"] = round(samples[-1][0] / 60.0, 1)
        result["stopped_early"] = sampler.stop_boards.is_set()
        result.update(summarize(samples, args.warmup))
        result["samples"] = [(round(t), round(m, 2), round(c, 2), p) for t, m, c, p in samples]
        if isinstance(agent, XrceAgent):
            result["agent_log_tail"] = agent.log[-5:]
    finally:
        if robot is not None:
            try:
                robot.wait(10)
            except subprocess.TimeoutExpired:
                interrupt(robot, 10)
            robot.stdin.close()
            robot.stdout.close()
        if ros is not None:
            ros.close()
        if agent is not None:
            agent.stop()
        lease.release()
        shutil.rmtree(workdir, ignore_errors=True)
    return result


def report(result):
    fmt = lambda v, spec="%.1f": "-" if v is None else spec % v  # noqa: E731
    lines = [
        "%s, %s%s, %g min%s: %d board lives, %d creations failed %s"
        % (result["agent"], result["mode"], " (same key)" if result["same_key"] else "",
           result["minutes_run"], " (stopped early: RSS limit or SIGUSR1)" if result["stopped_early"]
           else "", result["lives"], result["failed"], result["failures"] or ""),
        "  agent RSS %s -> %s (after warm-up) -> %s MB; slope after warm-up %s MB/h"
        % (fmt(result["rss_start"]), fmt(result["rss_warm"]), fmt(result["rss_end"]),
           fmt(result["slope_mb_h"], "%.2f")),
        "  agent CPU %s%% mean, per 5-min window %s" % (result["cpu_mean"], result["cpu_windows"]),
        "  publishers of the boards' /odom in the ROS graph: %d at the end, %d at most"
        % (result["publishers_end"], result["publishers_max"]),
    ]
    if "odom_sent" in result:
        lines.append("  robot /odom: %d sent, %d received, %d lost"
                     % (result["odom_sent"], result["odom_received"], result["odom_lost"]))
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=6.0)
    parser.add_argument("--period", type=float, default=1.0, help="seconds between board lives")
    parser.add_argument("--same-key", action="store_true", help="every life under one client key")
    parser.add_argument("--agent-cmd", metavar="CMD", help="another agent's command line")
    parser.add_argument("--agent-args", default="", metavar="ARGS",
                        help="options for this tree's agent, e.g. '--client-expire-time 3000'")
    parser.add_argument("--serial", action="store_true", help="boards over re-created ptys")
    parser.add_argument("--soak", action="store_true", help="TurtleBot3 + 10 reconnecting boards")
    parser.add_argument("--warmup", type=float, default=300.0, metavar="S",
                        help="seconds left out of the RSS slope (default 300)")
    parser.add_argument("--rss-limit", type=float, metavar="MB",
                        help="stop the boards early once the agent holds this much (a leaking "
                             "agent must not take the machine's memory)")
    parser.add_argument("--json", metavar="FILE", help="also write the figures and samples here")
    args = parser.parse_args(argv)
    if args.serial and (args.agent_cmd or args.soak):
        parser.error("--serial runs this tree's agent in churn mode only")
    result = run(args)
    print(report(result), flush=True)
    if args.json:
        with open(args.json, "w") as out:
            json.dump(result, out, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
