"""One client Session over a serial device writing best-effort samples back to back, for
bench/run.py's serial goodput figure.

    python bench/agent/serial_flood.py --device PATH --count N --size BYTES

Creates participant, topic ``/serial_goodput`` (std_msgs/String) and a best-effort writer, prints
``ready``, waits for a line on stdin, then writes N strings of BYTES characters, each in its own
message (write + flush, as micro-ROS publishes), and prints ``sent N ELAPSED``. The serial write
blocks when the line (the relay's pacing behind the pty) is full, so the client runs at line rate.
"""

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout, for xrce

from xrce.client.session import Session  # noqa: E402
from xrce.msgs.std_msgs import String  # noqa: E402
from xrce.transports.serial import SerialTransport  # noqa: E402


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--device", required=True)
    parser.add_argument("--baudrate", type=int, default=115200)
    parser.add_argument("--count", type=int, required=True)
    parser.add_argument("--size", type=int, default=200)
    args = parser.parse_args()
    session = Session(SerialTransport(args.device, baudrate=args.baudrate), history=8)
    try:
        if not session.create(attempts=10, timeout_ms=1000):
            print("error no session", flush=True)
            return 1
        node = session.create_participant(domain_id=0, name="serial_goodput")
        writer = session.create_writer(node, "/serial_goodput", String, reliable=False)
        if not session.run_until_all_status(5000):
            print("error entities %r" % session.last_statuses, flush=True)
            return 1
        print("ready", flush=True)
        sys.stdin.readline()
        sample = String(data="x" * args.size)
        start = time.monotonic()
        for _ in range(args.count):
            session.write(writer, sample, stream_id=session.best_effort)
            session.flush()
        print("sent %d %.6f" % (args.count, time.monotonic() - start), flush=True)
        sys.stdin.readline()
        session.delete(attempts=2, timeout_ms=500)
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
