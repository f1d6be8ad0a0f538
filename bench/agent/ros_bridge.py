"""The ros and latency groups of bench/run.py: samples between a client and rclpy through a
``-m dds`` agent, each figure beside the same traffic between two bare rclpy processes
(bench/common/ros_peer.py); ping round trips beside a raw UDP echo; end-to-end latency beside rclpy's own.
"""

import json
import threading
import time

import bench.common  # noqa: F401  (the test helpers on sys.path, for agent_process)
from agent_process import AgentProcess  # noqa: E402

from bench.common.figures import percentile, record
from bench.common.harness import Child, cpu_seconds, udp_echo_rtts, wait_for


def arrival_rate(peer, topic):
    count, first, last = peer.ask("count %s" % topic).split()
    count, first, last = int(count), float(first), float(last)
    return (count - 1) / (last - first) if count > 1 and last > first else 0.0, count


def ros_benchmarks(env, domain_id, seconds, latency_count, ping_count, groups):
    from xrce.client.session import Session
    from xrce.msgs.geometry_msgs import Twist, Vector3
    from xrce.transports.udp import UdpTransport

    sink = Child(["bench/common/ros_peer.py"], env=env, ready="ready")
    source = Child(["bench/common/ros_peer.py"], env=env, ready="ready")
    agent = AgentProcess("udp4", "-m", "dds", "-v", "0", "--stats-port", "0", env=env)
    agent.__enter__()
    session = Session(UdpTransport("127.0.0.1", agent.port), history=16)
    try:
        if not session.create(attempts=5, timeout_ms=2000):
            raise RuntimeError("no session with the dds agent")
        node = session.create_participant(domain_id=domain_id, name="bench_client")

        if "ros" in groups:
            for kind, reliable in (("be", False), ("rel", True)):
                bare = "/bare_%s" % kind
                sink.ask("sub %s %s" % (bare, kind))
                source.ask("flood %s %s %.1f" % (bare, kind, seconds), timeout=seconds + 30)
                time.sleep(0.3)
                baseline, _ = arrival_rate(sink, bare)

                topic = "/xrce_%s" % kind
                sink.ask("sub %s %s" % (topic, kind))
                writer = session.create_writer(node, topic, Twist, reliable=reliable, depth=1000)
                if not session.run_until_all_status(5000):
                    raise RuntimeError("writer not created: %r" % session.last_statuses)
                wait_for(lambda: sink.ask("publishers %s" % topic) != "0")
                time.sleep(0.5)
                stream = session.reliable if reliable else session.best_effort
                sample = Twist(linear=Vector3(x=1.0))
                sent = 0
                cpu_before = cpu_seconds(agent.proc.pid)
                start = time.monotonic()
                end = start + seconds
                while time.monotonic() < end:
                    for _ in range(50):
                        session.write(writer, sample, stream_id=stream)
                        session.flush()
                    sent += 50
                    if reliable:
                        session.spin_once(0)
                elapsed = time.monotonic() - start
                agent_cpu = (cpu_seconds(agent.proc.pid) - cpu_before) / elapsed
                if reliable:
                    session.run_until_confirm_delivery(5000)
                time.sleep(0.5)
                rate, received = arrival_rate(sink, topic)
                record("client->ROS %s" % ("reliable" if reliable else "best-effort"), rate,
                       "msg/s", baseline, "bare rclpy pub->same sub",
                       ">= 0.8" if not reliable else "",
                       "client sent %.0f msg/s, sub got %d of %d, agent CPU %.0f %% of one core"
                       % (sent / elapsed, received, sent, 100 * agent_cpu))

            # ROS -> client: the bare publisher's own rate is the baseline.
            topic = "/to_client"
            got = []
            session.create_reader(node, topic, Twist, lambda m: got.append(time.monotonic()),
                                  reliable=False, depth=1000)
            if not session.run_until_all_status(5000):
                raise RuntimeError("reader not created: %r" % session.last_statuses)
            answer = []
            flood = threading.Thread(target=lambda: answer.append(
                source.ask("flood %s be %.1f" % (topic, seconds), timeout=seconds + 30)))
            flood.start()
            while flood.is_alive():
                session.spin_once(10)
            session.run_until_timeout(500)
            published, published_s = answer[0].split()[:2]
            baseline = int(published) / float(published_s)
            rate = (len(got) - 1) / (got[-1] - got[0]) if len(got) > 1 else 0.0
            record("ROS->client best-effort", rate, "msg/s", baseline, "bare rclpy publish rate",
                   "", "client got %d of %s" % (len(got), published))

        if "latency" in groups:
            # Ping: GET_INFO in the session, timed by the client; baseline: raw UDP echo.
            rtts = []
            for _ in range(ping_count):
                if session.ping(timeout_ms=1000):
                    rtts.append(session.last_rtt_us)
            echo = udp_echo_rtts(ping_count)
            record("ping RTT p50", percentile(rtts, 0.5), "us", percentile(echo, 0.5),
                   "raw UDP echo p50 (Python, loopback)", "< 200 us")
            record("ping RTT p99", percentile(rtts, 0.99), "us", percentile(echo, 0.99),
                   "raw UDP echo p99")

            # End to end: client write -> rclpy callback; baseline: rclpy pub -> same sub.
            sink.ask("lat /bare_lat be")
            source.ask("stamped /bare_lat be %d 200" % latency_count, timeout=latency_count / 100 + 30)
            time.sleep(0.3)
            bare = [s * 1e3 for s in json.loads(sink.ask("latency /bare_lat"))]
            sink.ask("lat /xrce_lat be")
            writer = session.create_writer(node, "/xrce_lat", Twist, reliable=False)
            if not session.run_until_all_status(5000):
                raise RuntimeError("latency writer not created")
            wait_for(lambda: sink.ask("publishers /xrce_lat") != "0")
            time.sleep(0.5)
            sample = Twist()
            start = time.monotonic()
            for index in range(latency_count):
                due = start + index / 200.0
                while True:
                    now = time.monotonic()
                    if now >= due:
                        break
                    session.spin_once(0)
                    remaining = due - time.monotonic()
                    if remaining > 0.001:
                        time.sleep(remaining - 0.0005)
                sample.linear.x = time.monotonic()
                session.write(writer, sample, stream_id=session.best_effort)
                session.flush()
            time.sleep(0.5)
            xrce = [s * 1e3 for s in json.loads(sink.ask("latency /xrce_lat"))]
            note = "received %d of %d" % (len(xrce), latency_count)
            record("end-to-end latency p50", percentile(xrce, 0.5), "ms", percentile(bare, 0.5),
                   "bare rclpy pub->sub p50", "< 1 ms", note)
            record("end-to-end latency p99", percentile(xrce, 0.99), "ms", percentile(bare, 0.99),
                   "bare rclpy pub->sub p99", "< 5 ms", note)
    finally:
        try:
            session.delete(attempts=2, timeout_ms=500)
        finally:
            session.close()
            agent.stop()
            sink.close()
            source.close()
