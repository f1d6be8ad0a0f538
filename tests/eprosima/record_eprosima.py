"""Record tests/golden/eprosima/: eProsima's client (programs/, built against XRCE_EPROSIMA_CLIENT)
against eProsima's agent (``--agent``, default $XRCE_EPROSIMA_AGENT: the ``agent.sh`` the peers
build script writes, run with -m ced, and -m dds for the dds_ exchanges), through a transparent relay that writes down
every message. Run by hand, as root, where both are built (PEERS: where they were built):

    XRCE_EPROSIMA_CLIENT=$PEERS/install XRCE_EPROSIMA_AGENT=$PEERS/agent.sh unshare -n sh -c \\
        'ip link set lo up multicast on; ip route add 224.0.0.0/4 dev lo; .venv/bin/python tests/eprosima/record_eprosima.py'

(a private loopback, with a route for multicast: eProsima's discovery port does not open without
one; the agent answers discovery with that host's addresses, 127.0.0.1 and ::1 only). One file
per scenario of scenarios.py: a first line with what ran and what the program printed, then one
line per message ``{"t", "dir": "C->A" | "A->C", "client", "hex"}`` (and over TCP and serial
``frame``: the bytes as framed on the wire). Creations and exchanges over UDP4, UDP6, TCP4, TCP6
and serial (two pseudo-terminal pairs per exchange, eProsima's agent as ``multiserial``).
"""

from __future__ import annotations

import argparse
import json
import os
import select
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import tty
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent / "helpers")]

import eprosima_client  # noqa: E402
import eprosima_scenarios as scenarios  # noqa: E402

GOLDEN = HERE.parent / "golden" / "eprosima"
AGENT_PORT, RELAY_PORT, DISCOVERY_PORT = 7711, 7712, 7713


def split_frames(buffer):
    """Complete serial frames at the start of ``buffer`` (bytearray, consumed): [(raw frame,
    message)], the frame as eProsima's framing wrote it (7E, addresses, length, escaped message,
    CRC), the message unescaped. Bytes before a flag are skipped."""
    frames = []
    while True:
        start = buffer.find(0x7E)
        if start < 0:
            del buffer[:]
            return frames
        del buffer[:start]
        body, i = bytearray(), 1
        while i < len(buffer) and (len(body) < 4 or len(body) < 4 + (body[2] | body[3] << 8) + 2):
            if buffer[i] == 0x7E:  # a new frame began: this one was cut
                break
            if buffer[i] == 0x7D:
                if i + 1 >= len(buffer):
                    break
                body.append(buffer[i + 1] ^ 0x20)
                i += 2
            else:
                body.append(buffer[i])
                i += 1
        if len(body) >= 4 and len(body) == 4 + (body[2] | body[3] << 8) + 2:
            frames.append((bytes(buffer[:i]), bytes(body[4:-2])))
            del buffer[:i]
        elif i < len(buffer) and buffer[i] == 0x7E:
            del buffer[:i]
        else:
            return frames


class Relay(threading.Thread):
    """Clients <-> relay <-> agent, every message recorded with its time and which client (in the
    order they first spoke, or the pseudo-terminal pair's for serial). UDP: one socket toward the
    agent per client, so the agent tells them apart as it would; TCP: one connection per client,
    messages split at their length prefix (``frame``: the prefixed bytes); serial: the bytes
    between each client's pseudo-terminal and the agent's, split into frames (``frame``: eProsima's
    raw frame). Subclasses say how."""

    def __init__(self):
        super().__init__(daemon=True)
        self.records = []
        self.stopping = False
        self.start_time = time.monotonic()
        self.lock = threading.Lock()

    def note(self, direction, client, message, frame=None):
        row = {"t": round(time.monotonic() - self.start_time, 6), "dir": direction, "client": client,
               "hex": message.hex()}
        if frame is not None:
            row["frame"] = frame.hex()
        with self.lock:
            self.records.append(row)

    def stop(self):
        self.stopping = True
        self.join(2)
        self.close()


class UdpRelay(Relay):
    def __init__(self, family, host, listen_port, agent_port):
        super().__init__()
        self.family, self.host, self.agent_port = family, host, agent_port
        self.front = socket.socket(family, socket.SOCK_DGRAM)
        self.front.bind((host, listen_port))
        self.backs = {}  # client address -> (index, socket toward the agent)

    def run(self):
        while not self.stopping:
            sockets = [self.front] + [back for _, back in self.backs.values()]
            ready, _, _ = select.select(sockets, [], [], 0.05)
            for sock in ready:
                data, source = sock.recvfrom(65536)
                if sock is self.front:
                    if source not in self.backs:
                        back = socket.socket(self.family, socket.SOCK_DGRAM)
                        back.connect((self.host, self.agent_port))
                        self.backs[source] = (len(self.backs), back)
                    index, back = self.backs[source]
                    self.note("C->A", index, data)
                    back.send(data)
                else:
                    for client, (index, back) in self.backs.items():
                        if back is sock:
                            self.note("A->C", index, data)
                            self.front.sendto(data, client)

    def close(self):
        self.front.close()
        for _, back in self.backs.values():
            back.close()


class TcpRelay(Relay):
    def __init__(self, family, host, listen_port, agent_port):
        super().__init__()
        self.family, self.host, self.agent_port = family, host, agent_port
        self.listener = socket.socket(family, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind((host, listen_port))
        self.listener.listen(8)
        self.peers = {}  # socket -> (other socket, index, direction, buffer)

    def run(self):
        clients = 0
        while not self.stopping:
            ready, _, _ = select.select([self.listener, *self.peers], [], [], 0.05)
            for sock in ready:
                if sock is self.listener:
                    front, _ = self.listener.accept()
                    back = socket.create_connection((self.host, self.agent_port))
                    for s in (front, back):
                        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    self.peers[front] = (back, clients, "C->A", bytearray())
                    self.peers[back] = (front, clients, "A->C", bytearray())
                    clients += 1
                    continue
                if sock not in self.peers:
                    continue
                other, index, direction, buffer = self.peers[sock]
                data = sock.recv(65536)
                if not data:
                    for s in (sock, other):
                        self.peers.pop(s, None)
                        s.close()
                    continue
                other.sendall(data)
                buffer += data
                while len(buffer) >= 2 and len(buffer) >= 2 + (buffer[0] | buffer[1] << 8):
                    size = buffer[0] | buffer[1] << 8
                    self.note(direction, index, bytes(buffer[2:2 + size]), bytes(buffer[:2 + size]))
                    del buffer[:2 + size]

    def close(self):
        self.listener.close()
        for s in list(self.peers):
            s.close()


class SerialRelay(Relay):
    """``pairs`` pseudo-terminal pairs toward the clients (``client_fds``: the ends to hand them)
    and as many toward the agent (``agent_devices``: the device names to give it)."""

    def __init__(self, pairs):
        super().__init__()
        self.client_fds, self.agent_devices, self.links, self.opened = [], [], {}, []
        for index in range(pairs):
            client_end, relay_end = os.openpty()
            agent_master, agent_slave = os.openpty()
            for fd in (client_end, relay_end, agent_master, agent_slave):
                tty.setraw(fd)
            self.client_fds.append(client_end)
            self.agent_devices.append(os.ttyname(agent_slave))
            self.links[relay_end] = (agent_master, index, "C->A", bytearray())
            self.links[agent_master] = (relay_end, index, "A->C", bytearray())
            self.opened += [client_end, relay_end, agent_master, agent_slave]

    def run(self):
        while not self.stopping:
            ready, _, _ = select.select(list(self.links), [], [], 0.05)
            for fd in ready:
                other, index, direction, buffer = self.links[fd]
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    continue
                os.write(other, data)
                buffer += data
                for frame, message in split_frames(buffer):
                    self.note(direction, index, message, frame)

    def close(self):
        for fd in self.opened:
            try:
                os.close(fd)
            except OSError:
                pass


def start_agent(agent, transport, *extra, middleware=("-m", "ced")):
    where = ("--devs", " ".join(extra[0])) if transport == "multiserial" else ("-p", str(AGENT_PORT))
    rest = extra[1:] if transport == "multiserial" else extra
    process = subprocess.Popen([agent, transport, *where, *middleware, *rest],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(1.0)  # it prints nothing when ready; it is within a few ms
    return process


def stop_agent(process):
    process.send_signal(signal.SIGTERM)  # it ignores SIGINT while a session is open
    try:
        process.wait(10)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


def record(name, header, relay, run):
    relay.start()
    try:
        header["stdout"] = run()
    finally:
        time.sleep(0.3)  # the last answers
        relay.stop()
    path = GOLDEN / ("%s.jsonl" % name)
    with path.open("w") as out:
        out.write(json.dumps(header) + "\n")
        for row in relay.records:
            out.write(json.dumps(row) + "\n")
    print("%s: %d messages, %s" % (path.name, len(relay.records),
                                   " | ".join(l for l in header["stdout"] if not l.startswith("GOT"))))


def run_through(agent_exe, transport, clients, name, header, command, middleware=("-m", "ced")):
    """eProsima's agent, a relay of ``transport`` for ``clients`` clients, and ``command(where,
    pass_fds)`` run against the relay, recorded as ``name``; ``where`` is what the program takes
    after the transport: host and port, or (serial) the clients' descriptors."""
    if transport == "serial":
        relay = SerialRelay(clients)
        agent = start_agent(agent_exe, "multiserial", relay.agent_devices, middleware=middleware)
        where, fds = [str(fd) for fd in relay.client_fds], tuple(relay.client_fds)
    else:
        family, host = ((socket.AF_INET6, "::1") if transport.endswith("6")
                        else (socket.AF_INET, "127.0.0.1"))
        kind = TcpRelay if transport.startswith("tcp") else UdpRelay
        agent = start_agent(agent_exe, transport, middleware=middleware)
        if middleware[1] == "dds":
            time.sleep(1.0)  # its Fast DDS is slower to come up
        relay = kind(family, host, RELAY_PORT, AGENT_PORT)
        where, fds = [host, str(RELAY_PORT)], ()
    try:
        def run():
            result = command(where, fds)
            return result.stdout.splitlines() + ["exit %d" % result.returncode]

        record(name, header, relay, run)
    finally:
        stop_agent(agent)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agent", default=os.environ.get("XRCE_EPROSIMA_AGENT"),
                        help="eProsima's MicroXRCEAgent (default $XRCE_EPROSIMA_AGENT)")
    parser.add_argument("only", nargs="*", help="scenario names or prefixes (default: all)")
    args = parser.parse_args()
    if not args.agent:
        parser.error("name eProsima's agent: --agent or XRCE_EPROSIMA_AGENT")
    reason = eprosima_client.missing_reason()
    if reason:
        sys.exit(reason)

    def wanted(name):
        return not args.only or any(name.startswith(prefix) for prefix in args.only)

    GOLDEN.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="xrce-record-") as build:
        script_exe = eprosima_client.build("script.c", build)
        discover_exe = eprosima_client.build("discover.c", build)
        exchange_exe = eprosima_client.build("exchange.c", build)
        for name, (transport, lines) in scenarios.CREATIONS.items():
            if not wanted(name):
                continue

            def command(where, fds, lines=lines, transport=transport):
                argv = where + ["0"] if transport == "serial" else where
                return subprocess.run([str(script_exe), transport, *argv], pass_fds=fds,
                                      input="\n".join(lines) + "\n", capture_output=True,
                                      text=True, timeout=120)

            run_through(args.agent, transport, 1, name,
                        {"scenario": name, "transport": transport, "middleware": "ced",
                         "program": "script.c", "script": lines}, command)
        for name, (transport, cell) in scenarios.EXCHANGES.items():
            if not wanted(name):
                continue
            argv = scenarios.exchange_argv(cell)

            def command(where, fds, transport=transport, argv=argv):
                if transport == "serial":  # the reader's pair is the first: it speaks first
                    where = [where[1], where[0]]
                return subprocess.run([str(exchange_exe), transport, *where, *argv], pass_fds=fds,
                                      capture_output=True, text=True, timeout=120)

            run_through(args.agent, transport, 2, name,
                        {"scenario": name, "transport": transport, "middleware": "ced",
                         "program": "exchange.c", "argv": argv}, command)
        for name, (transport, cell) in scenarios.DDS_EXCHANGES.items():
            if not wanted(name):
                continue
            argv = scenarios.exchange_argv(cell, scenarios.DDS_SETTLE_MS)
            middleware = ["-m", "dds"]
            profiles = Path(build) / "profiles.xml"
            if cell[4] == "ref":
                profiles.write_text(scenarios.exchange_profiles(cell[0]))
                middleware += ["-r", str(profiles)]
            env = dict(os.environ, ROS_DOMAIN_ID=str(scenarios.DDS_RECORDED_DOMAIN))

            def command(where, fds, argv=argv, env=env):
                return subprocess.run([str(exchange_exe), "udp4", *where, *argv], env=env,
                                      capture_output=True, text=True, timeout=120)

            header = {"scenario": name, "transport": transport, "middleware": "dds",
                      "program": "exchange.c", "argv": argv,
                      "domain": scenarios.DDS_RECORDED_DOMAIN}
            if cell[4] == "ref":
                header["profiles"] = profiles.read_text()
            run_through(args.agent, transport, 2, name, header, command, middleware=middleware)
        for name, transport in scenarios.DISCOVERY.items():
            if not wanted(name):
                continue
            agent = start_agent(args.agent, transport, "-d", str(DISCOVERY_PORT))
            try:
                relay = UdpRelay(socket.AF_INET, "127.0.0.1", RELAY_PORT, DISCOVERY_PORT)

                def run():
                    result = subprocess.run([str(discover_exe), "127.0.0.1", str(RELAY_PORT)],
                                            capture_output=True, text=True, timeout=60)
                    return result.stdout.splitlines() + ["exit %d" % result.returncode]

                record(name, {"scenario": name, "transport": transport, "middleware": "ced",
                              "program": "discover.c", "agent_port": AGENT_PORT}, relay, run)
            finally:
                stop_agent(agent)


if __name__ == "__main__":
    main()
