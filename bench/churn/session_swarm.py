"""Many client Sessions in one process, each publishing at a fixed rate, for bench/run.py.

    python bench/churn/session_swarm.py --port PORT --sessions N --rate HZ --seconds S [--first-key K]

Every session has its own UDP socket (so the agent sees N endpoints), a participant, a topic
``/swarm`` (std_msgs/String) and a best-effort writer. Writes are spread evenly over each period,
as independent devices would be. Prints ``created N SECONDS`` once all sessions exist, waits for
a line on stdin, publishes, then prints ``sent COUNT LATE`` (LATE: writes that missed their slot by
more than one period, i.e. this process could not keep the pace) and deletes the sessions.
"""

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout, for xrce

from xrce.client.session import Session  # noqa: E402
from xrce.msgs.std_msgs import String  # noqa: E402
from xrce.transports.udp import UdpTransport  # noqa: E402


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--sessions", type=int, required=True)
    parser.add_argument("--rate", type=float, default=10.0)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--first-key", type=int, default=1)
    args = parser.parse_args()

    started = time.monotonic()
    sessions = []
    for index in range(args.sessions):
        session = Session(UdpTransport("127.0.0.1", args.port), key=args.first_key + index,
                          history=4)
        if not session.create(attempts=10, timeout_ms=1000):
            print("error session %d not created" % index, flush=True)
            return 1
        node = session.create_participant(domain_id=0, name="swarm_%d" % index)
        writer = session.create_writer(node, "/swarm", String, reliable=False)
        if not session.run_until_all_status(5000):
            print("error entities of session %d: %r" % (index, session.last_statuses), flush=True)
            return 1
        sessions.append((session, writer))
    print("created %d %.3f" % (len(sessions), time.monotonic() - started), flush=True)
    sys.stdin.readline()

    period = 1.0 / args.rate
    slot = period / len(sessions)
    sample = String(data="0123456789abcdef")
    sent = late = 0
    start = time.monotonic()
    end = start + args.seconds
    tick = 0
    while True:
        base = start + tick * period
        if base >= end:
            break
        for index, (session, writer) in enumerate(sessions):
            due = base + index * slot
            now = time.monotonic()
            if due > now:
                time.sleep(due - now)
            elif now - due > period:
                late += 1
            session.write(writer, sample, stream_id=session.best_effort)
            session.flush()
            sent += 1
        tick += 1
    print("sent %d %d" % (sent, late), flush=True)
    for session, _ in sessions:
        session.delete(attempts=1, timeout_ms=50)
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
