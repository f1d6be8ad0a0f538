"""What the agent costs the robot's computer: CPU per message, idle CPU, robot load, memory, ping.

    .venv/bin/python bench/agent/cost.py [--quick] [--reference DIR] [--robot-only RUNS]
        [--reliable-only RUNS] [--agent-cmd CMD]

Run as ``bench/run.py --only cost`` or alone. Every figure comes from ``/proc/<agent pid>/stat``
(utime + stime of all its threads) or ``/proc/<agent pid>/status`` (VmRSS). ``--reference DIR``
runs the same measurements, in the same run, against the agent of another source tree (e.g. an
unpacked older commit): the figure is this tree's agent, the baseline that one's. Without it the
baseline is the closest floor measured in the same run: bare rclpy ``publish(bytes)`` per message,
a bare rclpy process idle, a Python UDP echo for ping. ``--agent-cmd CMD`` (with ``--robot-only`` or
``--reliable-only``) takes another agent started from a command line as the reference, e.g.
eProsima's MicroXRCEAgent
(``$PEERS/agent.sh``, bench/common/peer_agent.py); measure such runs on a private loopback and
/dev/shm (``unshare -nm sh -c 'ip link set lo up && mount -t tmpfs tmpfs /dev/shm && ...'``).

- "CPU per delivered message": bench/agent/xrce_flood.py offers Twist samples at a fixed rate
  (best-effort: one pre-encoded datagram per sample, a C client's cost) into a raw EventsExecutor
  subscriber (bench/common/ros_peer.py); agent CPU from the first send to 0.5 s after the last, divided by
  the samples the subscriber got.
- "idle": the agent with no client over 10 s (after a few seconds to settle discovery).
- "TurtleBot3 load": the simulated robot of ``xrce-agent demo`` (xrce/examples/turtlebot3.py:
  SensorState 10 Hz, imu, odom, tf, battery), a ROS subscriber on odom and imu, and reliable
  cmd_vel at 30 Hz from ROS; CPU over 10 s and the agent's resident memory at the end, then
  the CPU and switch-ins of its main thread and of all its threads over 5 s (schedstat, in ns).
- "ping": GET_INFO round trips timed around raw socket calls, out of a session (header 0x80) and
  in one, so the figure is the agent's answer plus loopback, not a client library's decode.
- floors (bench/agent/wakeup_floor.py): what a receiver that does nothing pays per wake-up (asyncio,
  uvloop, plain Python, C) at a robot's rate of wake-ups and at 5k/s, and a minimal Python bridge
  (asyncio reader + rclpy publish per datagram) at 5k and 20k/s into the same subscriber.
"""

import argparse
import os
import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from bench.agent.wakeup_floor import bridge_floor, record_floors, wakeup_floors  # noqa: E402
from bench.common.figures import percentile, record  # noqa: E402
from bench.common.harness import PYTHON, Child, cpu_seconds, udp_echo_rtts, wait_for  # noqa: E402
from bench.common.peer_agent import CommandAgent  # noqa: E402
from bench.common.procs import interrupt, read_until  # noqa: E402

from xrce.wire import constants as C  # noqa: E402
from xrce.wire.submessages import GetInfo, encode_message  # noqa: E402

IDLE_SECONDS = 10.0
SETTLE_SECONDS = 3.0
DRAIN_SECONDS = 0.5


def thread_times(pid):
    """{thread id: (name, ns on CPU, times switched in)} from /proc/<pid>/task/*/schedstat."""
    threads = {}
    for tid in os.listdir("/proc/%d/task" % pid):
        try:
            with open("/proc/%d/task/%s/comm" % (pid, tid)) as comm, \
                    open("/proc/%d/task/%s/schedstat" % (pid, tid)) as schedstat:
                name = comm.read().strip()
                on_cpu, _waited, switched_in = map(int, schedstat.read().split())
        except OSError:  # the thread ended meanwhile
            continue
        threads[int(tid)] = (name, on_cpu, switched_in)
    return threads


def rss_mb(pid):
    with open("/proc/%d/status" % pid) as status:
        return int(re.search(r"VmRSS:\s+(\d+) kB", status.read()).group(1)) / 1024.0


class Agent:
    """``python -m xrce.agent udp4 -p 0`` started from ``tree`` (its cwd, so that tree's code is
    the one imported), with the CLI's defaults otherwise."""

    def __init__(self, tree, env, *args):
        # An editable install's .pth imports this checkout's xrce before sys.path applies, so the
        # other tree's agent is started by a bootstrap that drops those modules first. The .pth
        # hook of the built interface packages (xrce.agent.interfaces.registry) ran in the dropped
        # modules, so the bootstrap activates the registry again in the tree's own: else the
        # agent would list and build turtlebot3_msgs again as on its first run (1 MB more RSS, a
        # cost an installed agent does not have).
        bootstrap = ("import os, runpy, site, sys\n"
                     "for name in [m for m in sys.modules if m == 'xrce' or m.startswith('xrce.')]:\n"
                     "    del sys.modules[name]\n"
                     "sys.meta_path[:] = [f for f in sys.meta_path\n"
                     "                    if type(f).__name__ != '_RegisteredInterfaceFinder']\n"
                     "sys.path.insert(0, %r)\n"
                     "from xrce.agent.interfaces import registry\n"
                     "for folder in site.getsitepackages():\n"
                     "    if os.path.exists(os.path.join(folder, registry.REGISTRY_NAME)):\n"
                     "        registry.activate_registry(os.path.join(folder, registry.REGISTRY_NAME))\n"
                     "sys.argv[0] = 'xrce-agent'\n"
                     "runpy.run_module('xrce.agent', run_name='__main__', alter_sys=True)\n" % tree)
        self.proc = subprocess.Popen([PYTHON, "-c", bootstrap, "udp4", "-p", "0", *args],
                                     cwd=tree, env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True)
        line, _output = read_until(self.proc, lambda text: re.search(r"on port (\d+)", text), 60)
        self.port = int(re.search(r"on port (\d+)", line).group(1)) if line else None
        if self.port is None:
            self.stop()
            raise RuntimeError("agent in %s did not start" % tree)
        # Keep the pipe drained so a chatty agent never blocks on its stdout.
        threading.Thread(target=self.proc.stdout.read, daemon=True).start()
        self.pid = self.proc.pid

    def cpu_over(self, seconds):
        before = cpu_seconds(self.pid)
        time.sleep(seconds)
        return (cpu_seconds(self.pid) - before) / seconds

    def main_thread_over(self, seconds):
        """(CPU fraction, switch-ins a second) of the agent's main thread (the asyncio loop's), of
        the whole process, and of Fast DDS's own threads (named dds.*), over ``seconds``: the
        wake-ups are what the agent's CPU at a robot's rates is made of, and what is neither main
        thread nor Fast DDS is mostly rclpy's executor thread."""
        before, start = thread_times(self.pid), time.monotonic()
        time.sleep(seconds)
        after, elapsed = thread_times(self.pid), time.monotonic() - start

        def share(tids):
            return tuple(sum(after[tid][i] - before.get(tid, (None, 0, 0))[i] for tid in tids) / scale
                         for i, scale in ((1, 1e9 * elapsed), (2, elapsed)))

        return (share([self.pid]), share(list(after)),
                share([tid for tid, values in after.items() if values[0].startswith("dds.")]))

    def stop(self):
        interrupt(self.proc, 20)


class OtherAgent(CommandAgent):
    """An agent from a command line (``--agent-cmd``), measured as ``Agent`` is."""

    cpu_over = Agent.cpu_over
    main_thread_over = Agent.main_thread_over


def bare_rclpy_idle(env, seconds):
    """CPU of a process with one rclpy node and an EventsExecutor waiting with no timeout."""
    code = ("import rclpy, sys\n"
            "from rclpy.context import Context\n"
            "from rclpy.experimental import EventsExecutor\n"
            "from rclpy.node import Node\n"
            "from rclpy.signals import SignalHandlerOptions\n"
            "c = Context(); rclpy.init(args=[], context=c, "
            "signal_handler_options=SignalHandlerOptions.NO)\n"
            "n = Node('idle_floor', context=c, start_parameter_services=False, enable_rosout=False)\n"
            "e = EventsExecutor(context=c); e.add_node(n)\n"
            "print('ready', flush=True)\n"
            "import threading; threading.Thread(target=e.spin, daemon=True).start()\n"
            "sys.stdin.readline()\n")
    proc = subprocess.Popen([PYTHON, "-c", code], env=env, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    try:
        proc.stdout.readline()
        time.sleep(SETTLE_SECONDS)
        before = cpu_seconds(proc.pid)
        time.sleep(seconds)
        return (cpu_seconds(proc.pid) - before) / seconds
    finally:
        proc.kill()
        proc.wait()
        proc.stdin.close()
        proc.stdout.close()


def ping_rtts(port, count, session=None):
    """GET_INFO round trips in µs; in ``session`` (a created xrce.client Session) when given."""
    if session is None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.connect(("127.0.0.1", port))
        message = encode_message(C.SESSION_ID_NONE_WITHOUT_KEY, C.STREAM_NONE, 0, None,
                                 [GetInfo()])
    else:
        sock = session.transport._sock
        # The session's own header on stream 0 (none), built here with the wire core rather than
        # through a private method of the client library.
        session_id = session.session_id
        message = encode_message(session_id, C.STREAM_NONE, 0,
                                 None if session_id & 0x80 else session.key, [GetInfo()])
    sock.settimeout(1.0)
    rtts = []
    try:
        for _ in range(count):
            start = time.perf_counter_ns()
            sock.send(message)
            try:
                sock.recv(2048)
            except socket.timeout:
                continue
            rtts.append((time.perf_counter_ns() - start) / 1000.0)
            time.sleep(0.0005)  # one ping at a time, as a user's ping tool
    finally:
        if session is None:
            sock.close()
    return rtts


def offered_load(agent, sink, env, domain_id, reliable, rate, seconds):
    """(agent CPU µs per delivered sample, delivered fraction, offered rate achieved)."""
    kind = "rel" if reliable else "be"
    topic = "/cost_%s_%d_%d" % (kind, rate, agent.pid)
    sink.ask("sub %s %s" % (topic, kind))
    args = ["bench/agent/xrce_flood.py", "--port", str(agent.port), "--topic", topic,
            "--domain", str(domain_id), "--key", hex(0x10000000 + rate)]
    if reliable:
        args.append("--reliable")
    flood = Child(args, env=env, ready="ready")
    try:
        wait_for(lambda: sink.ask("publishers %s" % topic) != "0")
        time.sleep(0.5)
        before = cpu_seconds(agent.pid)
        sent, elapsed = flood.ask("go %d %.1f" % (rate, seconds), timeout=seconds + 60).split()
        time.sleep(DRAIN_SECONDS)
        cpu = cpu_seconds(agent.pid) - before
    finally:
        flood.close()
    count = int(sink.ask("count %s" % topic).split()[0])
    sent = int(sent)
    per_message = 1e6 * cpu / count if count else None
    return per_message, (count / sent if sent else 0.0), sent / float(elapsed), count, sent


def robot_load(agent, env, domain_id, seconds):
    """(agent CPU fraction, RSS MB, ((main thread CPU fraction, its switch-ins/s), (all threads'
    CPU fraction, their switch-ins/s))) with the simulated TurtleBot3 and its ROS side running."""
    ros = Child(["bench/common/ros_peer.py"], env=env, ready="ready")
    robot = subprocess.Popen([PYTHON, "-m", "xrce.examples.turtlebot3", "udp4", "-p",
                              str(agent.port), "--domain", str(domain_id)],
                             cwd=REPO, env=env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
    driver = None
    try:
        ros.ask("sub /odom be nav_msgs/msg/Odometry")
        ros.ask("sub /imu be sensor_msgs/msg/Imu")
        if not wait_for(lambda: ros.ask("count /odom").split()[0] != "0", timeout_s=30):
            raise RuntimeError("the simulated robot's odometry never arrived")
        count = int((seconds + SETTLE_SECONDS + 5) * 30)
        driver = threading.Thread(target=lambda: ros.ask("stamped /cmd_vel rel %d 30" % count,
                                                         timeout=count / 30 + 60))
        driver.start()
        time.sleep(SETTLE_SECONDS)
        cpu = agent.cpu_over(seconds)
        memory = rss_mb(agent.pid)
        threads = agent.main_thread_over(min(seconds, 5.0))
        driver.join()
        return cpu, memory, threads
    finally:
        interrupt(robot, 10)
        ros.close()


def measure_tree(tree, env, domain_id, quick, sink, robot_env=None, robot_domain=None):
    """Every cost figure of the agent in ``tree``: a dict name -> value. The TurtleBot3 part runs
    in ``robot_domain`` when given, away from ``sink``'s subscriptions to the flood topics."""
    seconds = 2.0 if quick else 5.0
    pings = 500 if quick else 2000
    out = {}
    agent = Agent(tree, env)
    try:
        time.sleep(SETTLE_SECONDS)
        out["idle"] = agent.cpu_over(IDLE_SECONDS)
        out["rss_idle"] = rss_mb(agent.pid)
        out["ping_out"] = ping_rtts(agent.port, pings)

        from xrce.client.session import Session
        from xrce.msgs.geometry_msgs import Twist
        from xrce.transports.udp import UdpTransport

        session = Session(UdpTransport("127.0.0.1", agent.port), key=b"\x0c\x05\x70\x01",
                          history=16)
        try:
            if not session.create(attempts=5, timeout_ms=2000):
                raise RuntimeError("no session")
            out["ping_in"] = ping_rtts(agent.port, pings, session)
            node = session.create_participant(domain_id=domain_id, name="cost_10hz")
            writer = session.create_writer(node, "/cost_10hz", Twist, reliable=False)
            session.run_until_all_status(5000)
            sample = Twist()
            before = cpu_seconds(agent.pid)
            start = time.monotonic()
            for index in range(int(IDLE_SECONDS * 10)):
                due = start + index / 10.0
                time.sleep(max(0.0, due - time.monotonic()))
                session.write(writer, sample, stream_id=session.best_effort)
                session.flush()
            out["client_10hz"] = (cpu_seconds(agent.pid) - before) / (time.monotonic() - start)
        finally:
            session.delete(attempts=2, timeout_ms=500)
            session.close()

        rates = (5000, 20000, 50000)
        for reliable in (False, True):
            best = None
            for rate in rates:
                per, fraction, offered, count, sent = offered_load(
                    agent, sink, env, domain_id, reliable, rate, seconds)
                out[("rel" if reliable else "be", rate)] = (per, fraction, offered, count, sent)
                if fraction >= 0.99 and (best is None or offered > best[0]):
                    best = (offered, per, fraction, rate)
            out[("rel" if reliable else "be", "best")] = best
    finally:
        agent.stop()
    robot_env = env if robot_env is None else robot_env
    agent = Agent(tree, robot_env)
    try:
        out["robot_cpu"], out["robot_rss"], out["robot_threads"] = robot_load(
            agent, robot_env, domain_id if robot_domain is None else robot_domain, IDLE_SECONDS)
    finally:
        agent.stop()
    return out


def robot_only(env, domain_id, runs, reference=None, tree=None, agent_cmd=None):
    """Only the TurtleBot3 figures (CPU, RSS), ``runs`` times, this tree and the reference (a tree,
    or ``agent_cmd``) taking turns in each run (a memory change is checked in minutes, not the
    whole bench's half hour); each run's figures, then the medians and ranges."""
    trees = [("here", tree or str(REPO))] + ([("reference", reference)] if reference else [])
    if agent_cmd:
        trees.append(("command", None))
    results = {label: [] for label, _ in trees}
    for run in range(runs):
        for label, path in trees:
            agent = Agent(path, env) if path is not None else OtherAgent(agent_cmd, env)
            try:
                cpu, rss, threads = robot_load(agent, env, domain_id, IDLE_SECONDS)
            finally:
                agent.stop()
            results[label].append((cpu, rss))
            (main_cpu, main_switches), (all_cpu, all_switches), (dds_cpu, dds_switches) = threads
            print("run %d %s: TurtleBot3 load CPU %.2f %%, RSS %.2f MB; main thread %.2f %% at %.0f "
                  "switch-ins/s, all threads %.2f %% at %.0f/s, of which Fast DDS's %.2f %% at %.0f/s "
                  "and the rest (rclpy's executor) %.2f %% at %.0f/s"
                  % (run + 1, label, 100 * cpu, rss, 100 * main_cpu, main_switches, 100 * all_cpu,
                     all_switches, 100 * dds_cpu, dds_switches, 100 * (all_cpu - main_cpu - dds_cpu),
                     all_switches - main_switches - dds_switches), flush=True)
    here = results["here"]
    median = lambda values: sorted(values)[len(values) // 2]  # noqa: E731

    def figure(index, scale, there):
        values = [scale * r[index] for r in here]
        ref_values = [scale * r[index] for r in there] if there else None
        note = "median of %d runs, range %.2f-%.2f" % (runs, min(values), max(values))
        if ref_values:
            note += "; reference %.2f-%.2f" % (min(ref_values), max(ref_values))
        return median(values), median(ref_values) if ref_values else None, note

    references = [(label, reference if label == "reference" else agent_cmd)
                  for label, _ in trees[1:]] or [(None, None)]
    for label, source in references:
        there = results.get(label)
        ref = "reference agent (%s)" % source if source else "-"
        value, baseline, note = figure(1, 1.0, there)
        record("agent RSS, TurtleBot3 load", value, "MB", baseline, ref, "<= 50 MB", note)
        value, baseline, note = figure(0, 100.0, there)
        record("agent CPU, TurtleBot3 load", value, "% core", baseline, ref, "<= 1 %", note)


RELIABLE_RATES = (1000, 5000)


def reliable_only(env, domain_id, runs, reference=None, tree=None, agent_cmd=None, seconds=5.0):
    """Only the CPU per reliable sample at a robot's rates (``RELIABLE_RATES``), ``runs`` times,
    this tree and the reference (a tree, ``agent_cmd``, or both) taking turns in each run, a fresh
    agent each time; each run's figures, then the medians and ranges."""
    agents = [("here", tree or str(REPO), None)]
    if reference:
        agents.append(("reference", reference, None))
    if agent_cmd:
        agents.append(("command", None, agent_cmd))
    results = {(label, rate): [] for label, _, _ in agents for rate in RELIABLE_RATES}
    sink = Child(["bench/common/ros_peer.py"], env=env, ready="ready")
    try:
        for run in range(runs):
            for label, path, command in agents:
                agent = Agent(path, env) if command is None else OtherAgent(command, env)
                try:
                    time.sleep(SETTLE_SECONDS)
                    for rate in RELIABLE_RATES:
                        per, fraction, offered, count, sent = offered_load(
                            agent, sink, env, domain_id, True, rate, seconds)
                        results[(label, rate)].append(per)
                        print("run %d %s: reliable %dk/s: %s us per sample, delivered %d of %d "
                              "(offered %.0f msg/s)" % (run + 1, label, rate // 1000,
                                                         "-" if per is None else "%.1f" % per,
                                                         count, sent, offered), flush=True)
                finally:
                    agent.stop()
    finally:
        sink.close()
    median = lambda values: sorted(values)[len(values) // 2]  # noqa: E731
    for rate in RELIABLE_RATES:
        here = [v for v in results[("here", rate)] if v is not None]
        for label, _, command in agents[1:]:
            there = [v for v in results[(label, rate)] if v is not None]
            record("agent CPU per message, reliable %dk/s" % (rate // 1000),
                   median(here) if here else None, "us", median(there) if there else None,
                   "%s (%s)" % (label, command or reference), "<= 1.0x the reference",
                   "medians of %d interleaved runs, range %s; reference %s"
                   % (runs, "%.1f-%.1f" % (min(here), max(here)) if here else "-",
                      "%.1f-%.1f" % (min(there), max(there)) if there else "-"))


def cost_benchmarks(env, domain_id, quick=False, reference=None, tree=None):
    from ros_helpers import DomainLease

    # The TurtleBot3 figures in a domain of their own: an agent discovering the sink's
    # subscriptions to every flood topic held ~0.8 MB more, which is not the robot's load.
    robot_lease = DomainLease()
    robot_env = dict(env, ROS_DOMAIN_ID=str(robot_lease.domain_id))
    sink = Child(["bench/common/ros_peer.py"], env=env, ready="ready")
    source = Child(["bench/common/ros_peer.py"], env=env, ready="ready")
    try:
        here = measure_tree(tree or str(REPO), env, domain_id, quick, sink, robot_env,
                            robot_lease.domain_id)
        there = measure_tree(reference, env, domain_id, quick, sink, robot_env,
                             robot_lease.domain_id) if reference else None
        # The floor: bare rclpy publish(bytes) into the same kind of subscriber.
        sink.ask("sub /cost_floor be")
        sent, _elapsed, cpu = source.ask("flood /cost_floor be 3", timeout=60).split()
        floor = 1e6 * float(cpu) / int(sent)
        idle_floor = bare_rclpy_idle(env, IDLE_SECONDS)
        echo = udp_echo_rtts(500 if quick else 2000)
        # What waking up costs any Python receiver here, and a minimal Python bridge (asyncio
        # reader + rclpy publish per datagram) at the best-effort rates, into the same subscriber.
        floor_seconds = 2.0 if quick else 5.0
        floors = wakeup_floors(floor_seconds)
        sink.ask("sub /cost_bridge_floor be")
        bridge = bridge_floor(env, "/cost_bridge_floor", seconds=floor_seconds,
                              ready=lambda: wait_for(
                                  lambda: sink.ask("publishers /cost_bridge_floor") != "0"))
    finally:
        sink.close()
        source.close()
        robot_lease.release()
    ref = "reference agent (%s)" % reference if reference else None

    def base(key, fallback, index=None):
        if there is None:
            return fallback
        value = there[key]
        return value if index is None or value is None else value[index]

    for kind, label in (("be", "best-effort"), ("rel", "reliable")):
        for rate in (5000, 20000, 50000):
            per, fraction, offered, count, sent = here[(kind, rate)]
            target = {("be", 5000): "<= 20 us", ("be", 20000): "<= 10 us"}.get((kind, rate), "")
            note = "offered %.0f msg/s, delivered %d of %d (%.1f %%)" % (
                offered, count, sent, 100 * fraction)
            if there is not None:
                b = there[(kind, rate)]
                note += "; reference delivered %.1f %% of %.0f msg/s" % (100 * b[1], b[2])
            record("agent CPU per message, %s %dk/s" % (label, rate // 1000), per, "us",
                   base((kind, rate), floor, 0), ref or "bare rclpy publish(bytes) per message",
                   target, note)
        best = here[(kind, "best")]
        ref_best = there[(kind, "best")] if there is not None else None
        record("highest offered rate with >= 99 %% delivered, %s" % label,
               best[0] if best else 0, "msg/s", (ref_best[0] if ref_best else 0) if there else None,
               ref or "-", ">= 50000 (best-effort)" if kind == "be" else "",
               ("CPU %.1f us per message there" % best[1] if best else "none of 5k/20k/50k")
               + ("; the Python client's reliable window bounds what it offers"
                  if kind == "rel" else ""))
    record("agent idle CPU, no client", 100 * here["idle"], "% core",
           100 * base("idle", idle_floor), ref or "bare rclpy node + EventsExecutor, idle",
           "<= 0.2 %", "over %.0f s after %.0f s to settle" % (IDLE_SECONDS, SETTLE_SECONDS))
    record("agent CPU, one client at 10 Hz", 100 * here["client_10hz"], "% core",
           100 * base("client_10hz", idle_floor), ref or "bare rclpy node idle", "",
           "best-effort Twist")
    record("agent CPU, TurtleBot3 load", 100 * here["robot_cpu"], "% core",
           100 * base("robot_cpu", idle_floor), ref or "bare rclpy node idle", "<= 1 %",
           "simulated robot + odom/imu subscriber + reliable cmd_vel 30 Hz")
    (main_cpu, main_wakes), (all_cpu, all_wakes), _dds = here["robot_threads"]
    ref_threads = there["robot_threads"] if there is not None else None
    record("agent main thread CPU, TurtleBot3 load", 100 * main_cpu, "% core",
           100 * ref_threads[0][0] if ref_threads else None, ref or "-", "",
           "the asyncio loop's thread, %.0f switch-ins/s (%s); all threads %.2f %% at %.0f/s "
           "(%s), from /proc/<pid>/task/*/schedstat over 5 s (ns, where /proc/<pid>/stat "
           "counts 10 ms ticks)"
           % (main_wakes, "reference %.0f/s" % ref_threads[0][1] if ref_threads else "-",
              100 * all_cpu, all_wakes,
              "reference %.2f %% at %.0f/s" % (100 * ref_threads[1][0], ref_threads[1][1])
              if ref_threads else "-"))
    record("agent RSS, TurtleBot3 load", here["robot_rss"], "MB", base("robot_rss", None),
           ref or "-", "<= 50 MB", "idle, no client: %.1f MB" % here["rss_idle"])
    for key, label in (("ping_out", "out of session"), ("ping_in", "in session")):
        for fraction, name, target in ((0.5, "p50", "<= 90 us"), (0.99, "p99", "<= 250 us")):
            baseline = percentile(there[key], fraction) if there is not None else \
                percentile(echo, fraction)
            record("ping %s %s" % (label, name), percentile(here[key], fraction), "us", baseline,
                   ref or "Python UDP echo", target,
                   "%d answered; Python UDP echo %s %.0f us" % (len(here[key]), name,
                                                                  percentile(echo, fraction)))
    record("bare rclpy publish(bytes)", floor, "us", None, "-", "",
           "floor: CPU per message of a process that only publishes, same subscriber")
    for rate, (_fraction, per_datagram) in sorted(bridge.items()):
        record("floor: asyncio reader + rclpy publish, %dk/s" % (rate // 1000), per_datagram, "us",
               None, "-", "", "a minimal Python bridge: one Twist published per datagram read, "
               "same pacing and subscriber as the agent's best-effort figures")
    record_floors(floors)


def main(argv=None):
    from bench.common.figures import print_table
    from ros_helpers import DomainLease

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--reference", metavar="DIR",
                        help="source tree of another agent to measure in the same run as baseline")
    parser.add_argument("--tree", metavar="DIR",
                        help="measure the agent of this source tree instead of this checkout's")
    parser.add_argument("--robot-only", type=int, metavar="RUNS",
                        help="only the TurtleBot3 load's CPU and RSS, RUNS times (medians)")
    parser.add_argument("--reliable-only", type=int, metavar="RUNS",
                        help="only the CPU per reliable sample at 1k and 5k msg/s, RUNS times "
                             "(medians); takes --reference and --agent-cmd, both at once too")
    parser.add_argument("--agent-cmd", metavar="CMD",
                        help="with --robot-only or --reliable-only: another agent's command line "
                             "(it gets 'udp4 -p PORT') as a reference, e.g. $PEERS/agent.sh, "
                             "eProsima's agent built outside this repository; --reference may be "
                             "given too, all three then take turns")
    args = parser.parse_args(argv)
    if args.agent_cmd and not (args.robot_only or args.reliable_only):
        parser.error("--agent-cmd goes with --robot-only or --reliable-only")
    lease = DomainLease()
    env = dict(os.environ, ROS_DOMAIN_ID=str(lease.domain_id),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    try:
        if args.reliable_only:
            reliable_only(env, lease.domain_id, args.reliable_only, args.reference, args.tree,
                          args.agent_cmd)
        elif args.robot_only:
            robot_only(env, lease.domain_id, args.robot_only, args.reference, args.tree,
                       args.agent_cmd)
        else:
            cost_benchmarks(env, lease.domain_id, args.quick, args.reference, args.tree)
    finally:
        lease.release()
    print_table()
    return 0


if __name__ == "__main__":
    sys.exit(main())
