"""Run under MicroPython by tests/board/test_micropython_session_alloc.py: what a set-up client session
allocates per sample it publishes (best-effort and reliable), per sample it receives (decoded into
a preallocated message: create_reader's ``into``), per time sync and per ping, against a real
xrce-agent, over the real UdpTransport and the harness' port-like socket (tests/micropython/socket.py).

argv: agent_port count
This port collects no garbage while Python runs, so gc.mem_alloc() growth is every byte
allocated; what the socket's recv allocated (socket.recv_allocated: a board's recv allocates per
datagram too) is subtracted and printed apart. Prints "key value" lines: ``<what>_bytes`` (the
session's, over ``count`` repetitions), ``<what>_socket_bytes`` (the socket's), and counters.
"""

import gc
import sys

import socket
from xrce.client.session import Session
from xrce.msgs.builtin_interfaces import Time
from xrce.transports.udp import UdpTransport

# The phases the measurement loops run (one function each, defined once: a closure made per
# repetition would be an allocation of the loop's own).
state = {}


def publish_best_effort(i):
    sample = state["sample"]
    sample.nanosec = i
    session = state["session"]
    session.write(state["best"], sample, stream_id=session.best_effort)
    session.flush()


def publish_reliable(i):
    sample = state["sample"]
    sample.nanosec = i
    session = state["session"]
    session.write(state["reliable"], sample, stream_id=session.reliable)
    session.flush()


def receive_one(counter):
    # Spin until the sample just published came back through the agent (on_best / on_reliable
    # count them), acknowledgements and heartbeats included.
    session = state["session"]
    counts = state["counts"]
    target = counts[counter] + 1
    tries = 0
    while counts[counter] < target and tries < 400:
        session.spin_once(5)
        tries += 1


def on_best(msg):
    state["counts"][0] += 1
    state["last"][0] = msg.nanosec


def on_reliable(msg):
    state["counts"][1] += 1
    state["last"][1] = msg.nanosec


def measure(key, phase, argument, count):
    socket.recv_allocated = 0
    before = gc.mem_alloc()
    for i in range(count):
        phase(argument if argument is not None else i)
    total = gc.mem_alloc() - before
    print(key + "_bytes", total - socket.recv_allocated)
    print(key + "_socket_bytes", socket.recv_allocated)


def measure_pair(key, publish, counter, count):
    # Publication and reception measured apart, sample by sample.
    published = received = received_socket = 0
    for i in range(count):
        before = gc.mem_alloc()
        publish(i)
        published += gc.mem_alloc() - before
        socket.recv_allocated = 0
        before = gc.mem_alloc()
        receive_one(counter)
        received += gc.mem_alloc() - before - socket.recv_allocated
        received_socket += socket.recv_allocated
    print("publish_%s_bytes" % key, published)
    print("receive_%s_bytes" % key, received)
    print("receive_%s_socket_bytes" % key, received_socket)


def sync(_):
    state["session"].sync_time(timeout_ms=2000)


def ping(_):
    state["session"].ping(timeout_ms=2000)


def check_offset(session):
    # One more exchange, taken whatever its round trip, with the reply datagram and the client's
    # stamps printed for the test to redo the nanosecond arithmetic on CPython.
    replies = []
    handle = type(session).handle_message

    def capture(data):
        replies.append(bytes(data))
        handle(session, data)

    session.handle_message = capture
    session.time_synced = False
    print("offset_sync", session.sync_time(timeout_ms=2000))
    del session.handle_message
    demand = session._demand
    base = demand[0] << 16  # xrce.client.on_demand's _BASE, _T0_S, _T0_NS, _NOW_S, _NOW_NS
    print("offset_t0_ns", (base + demand[5]) * 1000000000 + demand[6])
    print("offset_t3_ns", (base + demand[3]) * 1000000000 + demand[4])
    print("offset_replies", " ".join(reply.hex() for reply in replies))
    print("offset_ns", session.time_offset_ns)
    print("offset_rtt_ns", session.time_rtt_ns)


def main():
    port = int(sys.argv[1])
    count = int(sys.argv[2])
    transport = UdpTransport("127.0.0.1", port)
    session = Session(transport, key=b"\x48\x32\x00\x01", history=4, largest_sample=8)
    state["session"] = session
    state["sample"] = Time(sec=1, nanosec=0)
    state["counts"] = [0, 0]
    state["last"] = [0, 0]
    print("create", session.create(attempts=5, timeout_ms=1000))
    node = session.create_participant(name="alloc")
    state["best"] = session.create_writer(node, "/alloc_best_effort", Time, reliable=False)
    state["reliable"] = session.create_writer(node, "/alloc_reliable", Time, reliable=True)
    session.create_reader(node, "/alloc_best_effort", Time, on_best, reliable=False, into=Time())
    session.create_reader(node, "/alloc_reliable", Time, on_reliable, reliable=True, into=Time())
    print("setup", session.run_until_all_status(5000))
    # Warm-up: every path once or more (plans, the first time sync's module, dictionary entries,
    # every history slot's buffer) before anything is measured.
    for i in range(8):
        publish_best_effort(i)
        receive_one(0)
        publish_reliable(i)
        receive_one(1)
    for _ in range(2):
        sync(0)
        ping(0)
    measure_pair("best_effort", publish_best_effort, 0, count)
    measure_pair("reliable", publish_reliable, 1, count)
    measure("time_sync", sync, 0, count)
    measure("ping", ping, 0, count)
    check_offset(session)
    print("received", state["counts"][0], state["counts"][1])
    print("last", state["last"][0], state["last"][1])
    print("time_synced", session.time_synced)
    print("dropped_writes", session.dropped_writes)
    session.delete(attempts=1, timeout_ms=500)
    session.close()
    print("done", True)


main()
