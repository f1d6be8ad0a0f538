"""How soon data crosses the bridge after either side appears, in each start order (issue 22).

    .venv/bin/python bench/restart/discovery.py [--trials 20] [--orders a,b,c,da,db,dc] [--restart-runs 5]
    .venv/bin/python bench/run.py --only discovery

Each trial starts what its order says and measures one delay; every rclpy peer is a process of its
own (a new DDS participant, as a newly launched ROS node is), the XRCE client runs in this process
(a CPython ``Session`` over UDP) and the agent is ``xrce-agent udp4 -m dds``:

- (a) agent up, then an rclpy subscriber starts, then the client creates its writer: time from the
  client's CREATE of the writer (stamped before it is sent) to the first sample in rclpy;
- (b) rclpy subscriber up, then the agent starts, then the client (as soon as the agent prints its
  banner): the same delay;
- (c) agent up with a client publishing, then a new rclpy subscriber starts: time from the
  subscription's creation in that process to its first sample;
- (da), (db), (dc): the same three orders with an rclpy publisher and an XRCE reader: time from
  the client's CREATE of the reader, or in (dc) from the rclpy publisher's creation, to the first
  sample in the client.

The writer and the rclpy publisher send a sample every 20 ms from the moment they exist, so a
delay has 20 ms granularity. Reliable QoS on both sides (rclpy's default, depth 10). Beside them,
``bench/restart/restart_gap.py``'s agent-restart gap (agent SIGKILLed, started again 1 s later).

Under (a), (c), (da) and (dc) one agent serves all trials (its participant is the old one, the
rclpy peer the new one); under (b) and (db) the rclpy peer stays and the agent starts afresh each
trial. Every figure is min / median / max of the trials; a trial that sees no sample in 10 s
counts as 10 s and is reported.
"""

import os
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from bench.common.procs import interrupt  # noqa: E402
from bench.restart.restart_gap import Agent, free_udp_port  # noqa: E402

PYTHON = sys.executable
PERIOD_S = 0.02
GIVE_UP_S = 10.0
ORDERS = ("a", "b", "c", "da", "db", "dc")
LABELS = {
    "a": "(a) agent, rclpy sub, client writer",
    "b": "(b) rclpy sub, agent, client writer",
    "c": "(c) agent + client writing, new rclpy sub",
    "da": "(d-a) agent, rclpy pub, client reader",
    "db": "(d-b) rclpy pub, agent, client reader",
    "dc": "(d-c) agent + client reading, new rclpy pub",
}


# ----------------------------------------------------------------------------- rclpy children

def ros_subscriber_main(topic):
    """Child: rclpy subscriber (default reliable QoS); prints ``ready <t>`` once the subscription
    exists, then the CLOCK_MONOTONIC time of each sample."""
    import rclpy
    from rclpy.node import Node
    from std_msgs.msg import String

    rclpy.init(args=["--ros-args", "--disable-external-lib-logs"])  # no log file in ~/.ros
    node = Node("discovery_listener", start_parameter_services=False, enable_rosout=False)
    out = sys.stdout
    node.create_subscription(String, topic, lambda _m: out.write("%.6f\n" % time.monotonic())
                             or out.flush(), 10)
    out.write("ready %.6f\n" % time.monotonic())
    out.flush()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass


def ros_publisher_main(topic):
    """Child: rclpy publisher (default reliable QoS), a sample every 20 ms; prints ``ready <t>``
    when the publisher exists."""
    import rclpy
    from rclpy.node import Node
    from std_msgs.msg import String

    rclpy.init(args=["--ros-args", "--disable-external-lib-logs"])  # no log file in ~/.ros
    node = Node("discovery_talker", start_parameter_services=False, enable_rosout=False)
    publisher = node.create_publisher(String, topic, 10)
    print("ready %.6f" % time.monotonic(), flush=True)
    message = String(data="hello")
    try:
        while True:
            publisher.publish(message)
            time.sleep(PERIOD_S)
    except KeyboardInterrupt:
        pass


class RosPeer:
    """An rclpy child (``--ros-sub`` or ``--ros-pub``), its ``ready`` time and the arrivals it
    reports."""

    def __init__(self, role, topic, env):
        self.proc = subprocess.Popen([PYTHON, __file__, role, topic], cwd=REPO, env=env,
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        self.ready_at = None
        self.times = []
        self._ready = threading.Event()
        threading.Thread(target=self._read, daemon=True).start()
        if not self._ready.wait(60):
            self.close()
            raise RuntimeError("the rclpy %s did not start" % role)

    def _read(self):
        for line in self.proc.stdout:
            if line.startswith("ready"):
                self.ready_at = float(line.split()[1])
                self._ready.set()
            else:
                try:
                    self.times.append(float(line))
                except ValueError:
                    pass

    def first_after(self, moment):
        return next((t for t in list(self.times) if t >= moment), None)

    def close(self):
        interrupt(self.proc, 10)


# ----------------------------------------------------------------------------- XRCE client side

class Client:
    """A CPython XRCE session in this process, on its own thread so that it keeps writing or
    reading while the trial waits."""

    _next_key = 0x22000000

    def __init__(self, port, domain_id):
        from xrce.client import Session
        from xrce.transports.udp import UdpTransport

        Client._next_key += 1
        self.session = Session(UdpTransport("127.0.0.1", port), key=Client._next_key)
        if not self.session.create():
            raise RuntimeError("the agent did not answer CREATE_CLIENT")
        self.node = self.session.create_participant(domain_id=domain_id, name="discovery_client")
        if not self.session.run_until_all_status(5000):
            raise RuntimeError("participant not created: %r" % (self.session.last_statuses,))
        self.created_at = None
        self.received = []
        self._stop = threading.Event()
        self._thread = None

    def start_writer(self, topic):
        from xrce.msgs.std_msgs import String

        self.created_at = time.monotonic()
        writer = self.session.create_writer(self.node, topic, String, reliable=True, depth=10)
        if not self.session.run_until_all_status(5000):
            raise RuntimeError("writer not created: %r" % (self.session.last_statuses,))
        message = String(data="hello")

        def run():
            while not self._stop.is_set():
                self.session.write(writer, message)
                self.session.run_until_timeout(int(PERIOD_S * 1000))
        self._thread = threading.Thread(target=run, daemon=True)
        self._thread.start()

    def start_reader(self, topic):
        from xrce.msgs.std_msgs import String

        self.created_at = time.monotonic()
        self.session.create_reader(self.node, topic, String,
                                   lambda _m: self.received.append(time.monotonic()),
                                   reliable=True, depth=10)
        if not self.session.run_until_all_status(5000):
            raise RuntimeError("reader not created: %r" % (self.session.last_statuses,))

        def run():
            while not self._stop.is_set():
                self.session.spin_once(20)
        self._thread = threading.Thread(target=run, daemon=True)
        self._thread.start()

    def first_after(self, moment):
        return next((t for t in list(self.received) if t >= moment), None)

    def close(self):
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        try:
            self.session.delete()
        except Exception:  # the agent may already be gone (order b between trials)
            pass
        self.session.close()


def wait_first(source, since):
    deadline = time.monotonic() + GIVE_UP_S
    while time.monotonic() < deadline:
        first = source.first_after(since)
        if first is not None:
            return first - since
        time.sleep(0.005)
    return GIVE_UP_S


def start_agent(env):
    port = free_udp_port()
    agent = Agent(port, env, verbosity="3")
    if not agent.banner.wait(60):
        agent.kill()
        raise RuntimeError("agent did not start: %s" % "\n".join(agent.lines[-20:]))
    return agent, port


# ----------------------------------------------------------------------------- the orders

def trials_agent_first(order, env, domain_id, trials, log):
    """(a), (c), (da), (dc): one agent for all trials; a new rclpy peer per trial."""
    agent, port = start_agent(env)
    delays = []
    try:
        for index in range(trials):
            topic = "/discovery_%s_%d_%d" % (order, os.getpid(), index)
            client = Client(port, domain_id)
            peer = None
            try:
                if order == "a":
                    peer = RosPeer("--ros-sub", topic, env)
                    client.start_writer(topic)
                    delay = wait_first(peer, client.created_at)
                elif order == "da":
                    peer = RosPeer("--ros-pub", topic, env)
                    client.start_reader(topic)
                    delay = wait_first(client, client.created_at)
                elif order == "c":
                    client.start_writer(topic)
                    time.sleep(0.5)
                    peer = RosPeer("--ros-sub", topic, env)
                    delay = wait_first(peer, peer.ready_at)
                else:  # dc
                    client.start_reader(topic)
                    time.sleep(0.5)
                    peer = RosPeer("--ros-pub", topic, env)
                    delay = wait_first(client, peer.ready_at)
            finally:
                client.close()
                if peer is not None:
                    peer.close()
            delays.append(delay)
            log("  %s trial %d: %.3f s" % (order, index + 1, delay))
    finally:
        agent.stop()
    return delays


def trials_agent_second(order, env, domain_id, trials, log):
    """(b), (db): one rclpy peer for all trials; the agent starts afresh in each."""
    topic = "/discovery_%s_%d" % (order, os.getpid())
    peer = RosPeer("--ros-sub" if order == "b" else "--ros-pub", topic, env)
    delays = []
    try:
        for index in range(trials):
            agent, port = start_agent(env)
            client = None
            try:
                client = Client(port, domain_id)
                if order == "b":
                    client.start_writer(topic)
                    delay = wait_first(peer, client.created_at)
                else:
                    client.start_reader(topic)
                    delay = wait_first(client, client.created_at)
            finally:
                if client is not None:
                    client.close()
                agent.stop()
            delays.append(delay)
            log("  %s trial %d: %.3f s" % (order, index + 1, delay))
    finally:
        peer.close()
    return delays


def measure(env, domain_id, trials=20, orders=ORDERS, restart_runs=5, log=print):
    """{order: [delays]} plus ``"restart"``: the agent-restart gaps of bench/restart/restart_gap.py."""
    results = {}
    for order in orders:
        run = trials_agent_second if order in ("b", "db") else trials_agent_first
        results[order] = run(order, env, domain_id, trials, log)
    if restart_runs:
        from bench.restart import restart_gap
        figures = restart_gap.measure(env, runs=restart_runs, log=lambda line: log("  " + line))
        results["restart"] = figures["agent_gap"]
    return results


# ----------------------------------------------------------------------------- what it costs

def profile_without_discovery_settings(directory):
    """The agent's Fast DDS profile without what issue 22 added (the announcement period and the
    throughput controller that makes the builtin writers asynchronous), written to
    ``directory``: the agent as it was before, for a same-run comparison."""
    import xml.etree.ElementTree as ElementTree

    from xrce.agent.middleware.ros import fastdds_profile

    namespace = "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"
    ElementTree.register_namespace("", namespace)
    tree = ElementTree.parse(fastdds_profile.PROFILE_PATH)
    for rtps in tree.iter("{%s}rtps" % namespace):
        for name in ("builtin", "throughputController"):
            for element in rtps.findall("{%s}%s" % (namespace, name)):
                rtps.remove(element)
    path = os.path.join(directory, "without_discovery_settings.xml")
    tree.write(path, encoding="UTF-8", xml_declaration=True)
    return path


def cpu_ns(pid):
    """ns on CPU of all threads of ``pid`` (/proc/<pid>/task/*/schedstat)."""
    total = 0
    for tid in os.listdir("/proc/%d/task" % pid):
        try:
            with open("/proc/%d/task/%s/schedstat" % (pid, tid)) as handle:
                total += int(handle.read().split()[0])
        except OSError:
            pass
    return total


class DomainTraffic:
    """UDP datagrams on ``lo`` to the ports of one ROS domain (7400 + 250 x domain, 250 ports):
    count and IP bytes. Needs a packet socket (root or CAP_NET_RAW)."""

    def __init__(self, domain_id):
        import socket

        self.low = 7400 + 250 * domain_id
        self.packets = self.bytes = 0
        self.sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(0x0003))
        self.sock.bind(("lo", 0))
        self.sock.settimeout(0.2)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        import socket
        import struct

        while not self._stop.is_set():
            try:
                frame, address = self.sock.recvfrom(65535)
            except socket.timeout:
                continue
            ip = frame[14:]
            if address[2] == socket.PACKET_OUTGOING or len(ip) < 28 or ip[9] != 17:
                continue  # each loopback datagram shows up twice; UDP only
            header = (ip[0] & 15) * 4
            port = struct.unpack(">H", ip[header + 2:header + 4])[0]
            if self.low <= port < self.low + 250:
                self.packets += 1
                self.bytes += len(ip)

    def sample(self):
        return self.packets, self.bytes

    def close(self):
        self._stop.set()
        self._thread.join(2)
        self.sock.close()


def idle_cost(env, domain_id, runs=3, seconds=20.0, settle_s=3.0, log=print):
    """The agent idle next to one plain rclpy node, with its profile and without the discovery
    settings (taking turns): the agent's CPU, the rclpy node's CPU, and the domain's UDP
    datagrams and bytes per second on lo. Returns {label: [(agent %, node %, pkt/s, B/s)]}."""
    import tempfile

    results = {"now": [], "before": []}
    with tempfile.TemporaryDirectory(prefix="xrce-discovery-") as directory:
        before = profile_without_discovery_settings(directory)
        try:
            traffic = DomainTraffic(domain_id)
        except (PermissionError, OSError) as error:
            traffic = None
            log("no packet capture (%s): CPU only" % error)
        try:
            for run in range(runs):
                for label in ("now", "before"):
                    agent_env = env if label == "now" else dict(
                        env, FASTRTPS_DEFAULT_PROFILES_FILE=before)
                    peer = RosPeer("--ros-sub", "/discovery_idle", env)
                    agent = None
                    try:
                        agent, _port = start_agent(agent_env)
                        time.sleep(settle_s)
                        start = time.monotonic()
                        agent_ns, peer_ns = cpu_ns(agent.proc.pid), cpu_ns(peer.proc.pid)
                        packets, octets = traffic.sample() if traffic else (0, 0)
                        time.sleep(seconds)
                        elapsed = time.monotonic() - start
                        packets2, octets2 = traffic.sample() if traffic else (0, 0)
                        figures = (100.0 * (cpu_ns(agent.proc.pid) - agent_ns) / 1e9 / elapsed,
                                   100.0 * (cpu_ns(peer.proc.pid) - peer_ns) / 1e9 / elapsed,
                                   (packets2 - packets) / elapsed, (octets2 - octets) / elapsed)
                    finally:
                        if agent is not None:
                            agent.stop()
                        peer.close()
                    results[label].append(figures)
                    log("  run %d %-6s agent %.3f %% of a core, rclpy node %.3f %%, lo %.1f "
                        "datagrams/s, %.0f B/s" % ((run + 1, label) + figures))
        finally:
            if traffic is not None:
                traffic.close()
    return results


def summary_line(label, values, bound=1.0):
    within = sum(1 for v in values if v <= bound)
    return "%-46s min %.2f  median %.2f  max %.2f s  (%d of %d within %.1f s)" % (
        label, min(values), statistics.median(values), max(values), within, len(values), bound)


def report(record, env, domain_id, quick=False):
    """For bench/run.py: ``record(name, value, unit, baseline, baseline_name, target, note)``."""
    trials = 5 if quick else 20
    results = measure(env, domain_id, trials=trials, restart_runs=2 if quick else 5,
                      log=lambda line: print(line, flush=True))
    for order in ORDERS:
        values = results[order]
        within = sum(1 for v in values if v <= 1.0)
        record("first sample, %s (median of %d)" % (LABELS[order], len(values)),
               statistics.median(values), "s", None, "-", "<= 1.0 s in every trial",
               "min %.2f, max %.2f, %d of %d within 1.0 s"
               % (min(values), max(values), within, len(values)))
    if "restart" in results:
        gaps = results["restart"]
        record("agent SIGKILL + restart 1 s later: longest gap (median of %d)" % len(gaps),
               statistics.median(gaps), "s", None, "-", "",
               "min %.2f, max %.2f (bench/restart/restart_gap.py)" % (min(gaps), max(gaps)))


def main(argv=None):
    import argparse

    from ros_helpers import DomainLease

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--orders", default=",".join(ORDERS),
                        help="comma-separated: %s" % ", ".join(ORDERS))
    parser.add_argument("--restart-runs", type=int, default=5,
                        help="bench/restart/restart_gap.py runs beside them (0: none)")
    parser.add_argument("--idle-cost", type=int, metavar="RUNS",
                        help="instead: what the discovery settings cost at idle, RUNS runs")
    args = parser.parse_args(argv)
    orders = [o for o in args.orders.split(",") if o]
    unknown = set(orders) - set(ORDERS)
    if unknown:
        parser.error("unknown order(s): %s" % ", ".join(sorted(unknown)))
    lease = DomainLease()
    env = dict(os.environ, ROS_DOMAIN_ID=str(lease.domain_id),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    started = time.monotonic()
    if args.idle_cost:
        try:
            results = idle_cost(env, lease.domain_id, args.idle_cost)
        finally:
            lease.release()
        for label, name in (("now", "agent's profile"),
                            ("before", "without its discovery settings")):
            rows = results[label]
            print("%-32s agent %.3f %%  rclpy node %.3f %%  lo %.1f datagrams/s  %.0f B/s  "
                  "(medians of %d)" % ((name,) + tuple(statistics.median(r[i] for r in rows)
                                                      for i in range(4)) + (len(rows),)))
        return 0
    try:
        results = measure(env, lease.domain_id, args.trials, orders, args.restart_runs)
    finally:
        lease.release()
    for order in orders:
        print(summary_line(LABELS[order], results[order]))
    if "restart" in results:
        print(summary_line("agent SIGKILL + restart 1 s later: longest gap", results["restart"],
                           bound=3.5))
    print("total %.0f s on %d cores shared with whatever else runs" % (
        time.monotonic() - started, os.cpu_count()))
    return 0


if __name__ == "__main__":
    if sys.argv[1:2] == ["--ros-sub"]:
        ros_subscriber_main(sys.argv[2])
    elif sys.argv[1:2] == ["--ros-pub"]:
        ros_publisher_main(sys.argv[2])
    else:
        sys.exit(main())
