"""An XRCE client that offers Twist samples to an agent at a fixed rate, for bench/agent/cost.py.

    python bench/agent/xrce_flood.py --port P --topic T [--reliable] [--domain D]

Prints "ready" once its session, node and writer exist, then takes one command per line on stdin:

    go RATE SECONDS   offer RATE msg/s for SECONDS -> "SENT ELAPSED"
    quit

Best-effort output is one pre-encoded datagram whose sequence number is patched per send, so the
client costs about one ``send()`` per sample and can offer more than the agent takes (a C client's
cost, not a Python client's). Reliable output goes through ``Session.write`` so the stream's window
and acknowledgements are honoured; what it offers is then bounded by the window and the round trip.
"""

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout, for xrce

from xrce.client.session import Session  # noqa: E402
from xrce.msgs.geometry_msgs import Twist, Vector3  # noqa: E402
from xrce.transports.udp import UdpTransport  # noqa: E402

BURST_PERIOD_S = 0.001  # pacing granularity: the samples due in each millisecond go together


class RecordingTransport:
    """A transport that keeps a copy of the last message it sent."""

    def __init__(self, transport):
        self.inner = transport
        self.last_sent = None

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def send(self, message):
        self.last_sent = bytes(message)
        return self.inner.send(message)

    def send_from(self, buf, length):
        # The session sends through send_from where a transport has one: without this, __getattr__
        # would hand it the inner transport's and nothing would be recorded.
        return self.send(memoryview(buf)[:length])


def capture_best_effort_datagram(session, writer, sample):
    """The exact datagram Session.write + flush produces for one best-effort sample."""
    session.write(writer, sample, stream_id=session.best_effort)
    session.flush()
    return bytearray(session.transport.last_sent)


def offer_best_effort(sock, datagram, rate, seconds):
    seq = datagram[2] | (datagram[3] << 8)
    send = sock.send
    sent = 0
    start = time.monotonic()
    end = start + seconds
    next_burst = start
    while True:
        now = time.monotonic()
        if now >= end:
            break
        if now < next_burst:
            time.sleep(next_burst - now)
            continue
        due = int((now - start) * rate) - sent
        for _ in range(due):
            seq = (seq + 1) & 0xFFFF
            datagram[2] = seq & 0xFF
            datagram[3] = seq >> 8
            try:
                send(datagram)
            except OSError:  # a full socket buffer: the sample is lost, as a C client's would be
                pass
        sent += due
        next_burst += BURST_PERIOD_S
    return sent, time.monotonic() - start


def offer_reliable(session, writer, sample, rate, seconds):
    sent = 0
    start = time.monotonic()
    end = start + seconds
    while True:
        now = time.monotonic()
        if now >= end:
            break
        due = int((now - start) * rate) - sent
        if due <= 0:
            session.spin_once(1)
            continue
        for _ in range(min(due, 16)):
            if session.write(writer, sample, stream_id=session.reliable):
                sent += 1
            session.flush()
        session.spin_once(0)
    session.run_until_confirm_delivery(5000)
    return sent, time.monotonic() - start


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--topic", required=True)
    parser.add_argument("--reliable", action="store_true")
    parser.add_argument("--domain", type=int, default=0)
    parser.add_argument("--key", type=lambda text: int(text, 0), default=0x0A0B0C0D)
    args = parser.parse_args()

    transport = RecordingTransport(UdpTransport(args.host, args.port))
    session = Session(transport, key=args.key.to_bytes(4, "big"), history=16)
    if not session.create(attempts=5, timeout_ms=2000):
        print("error no session", flush=True)
        return 1
    node = session.create_participant(domain_id=args.domain, name="xrce_flood")
    writer = session.create_writer(node, args.topic, Twist, reliable=args.reliable, depth=1000)
    if not session.run_until_all_status(5000):
        print("error writer not created", flush=True)
        return 1
    sample = Twist(linear=Vector3(x=1.0))
    datagram = None if args.reliable else capture_best_effort_datagram(session, writer, sample)
    print("ready", flush=True)
    try:
        for line in sys.stdin:
            words = line.split()
            if not words:
                continue
            if words[0] == "quit":
                break
            if words[0] == "go":
                rate, seconds = float(words[1]), float(words[2])
                if args.reliable:
                    sent, elapsed = offer_reliable(session, writer, sample, rate, seconds)
                else:
                    sent, elapsed = offer_best_effort(transport.inner._sock, datagram, rate, seconds)
                print("%d %.6f" % (sent, elapsed), flush=True)
            else:
                print("error unknown command %r" % words[0], flush=True)
    finally:
        session.delete(attempts=2, timeout_ms=500)
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
