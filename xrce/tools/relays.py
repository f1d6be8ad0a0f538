"""Imperfect links for tests and benches (CPython only): a lossy UDP relay and a paced, noisy serial
relay, each running on its own thread with seeded randomness so a run's damage is reproducible.

``UdpRelay(agent_address, drop=0.2, duplicate=0.1, reorder=0.2, seed=1)``: clients send to
``relay.port`` on 127.0.0.1 instead of the agent. Each client address gets its own upstream socket,
so the agent still sees one endpoint per client (sessions >= 0x81 are identified by it). Every
datagram, both ways, is dropped, held back behind up to ``max_hold`` later datagrams (at most
``max_hold_s`` seconds) or forwarded, and a forwarded one may be sent twice.

``SerialRelay(agent_device=None, baudrate=None, bit_error_rate=0.0, seed=1)``: a client opens
``relay.client_path`` (a pty slave); the relay copies bytes to the agent side, either a device it is
given (e.g. an agent pseudoterminal's slave) or a fresh pty whose slave ``relay.agent_path`` the
agent opens (``xrce-agent serial -D`` / ``multiserial``). A pty moves bytes as fast as the CPU does,
so ``baudrate`` paces each direction at baudrate/10 bytes per second (8N1); ``bit_error_rate``
flips each bit independently with that probability.

Both count what they did in ``relay.stats`` (per direction: ``to_agent``, ``to_client``) and are
context managers that close every socket, fd and thread they opened.
"""

from __future__ import annotations

import math
import os
import random
import selectors
import socket
import termios
import threading
import time
import tty

_POLL_S = 0.005
_SERIAL_CHUNK = 4096
# A real UART blocks its writer once its FIFO is full; the relay stops reading the source beyond
# this many pending bytes, so the pty behind it fills and the writer sees that back-pressure.
_SERIAL_BACKLOG = 4096


class _Held:
    __slots__ = ("remaining", "deadline", "send")

    def __init__(self, remaining, deadline, send):
        self.remaining = remaining
        self.deadline = deadline
        self.send = send


class UdpRelay:
    """A UDP man in the middle with seeded drop, duplication and reordering (see module doc)."""

    def __init__(self, agent_address, *, drop=0.0, duplicate=0.0, reorder=0.0, max_hold=4,
                 max_hold_s=0.05, seed=1, host="127.0.0.1"):
        if drop + reorder > 1.0:
            raise ValueError("drop + reorder must not exceed 1")
        self.agent_address = agent_address
        self.drop, self.duplicate, self.reorder = drop, duplicate, reorder
        self.max_hold, self.max_hold_s = max_hold, max_hold_s
        self.rng = random.Random(seed)
        self.stats = {direction: {"datagrams": 0, "forwarded": 0, "dropped": 0, "duplicated": 0,
                                  "reordered": 0}
                      for direction in ("to_agent", "to_client")}
        self._front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._front.bind((host, 0))
        self._front.setblocking(False)
        self.port = self._front.getsockname()[1]
        self._upstream = {}  # client address -> socket towards the agent
        self._clients = {}  # upstream socket -> client address
        self._held = []
        self._selector = selectors.DefaultSelector()
        self._selector.register(self._front, selectors.EVENT_READ, None)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="udp-relay", daemon=True)
        self._thread.start()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        if self._thread is None:
            return
        self._stop.set()
        self._thread.join(5)
        self._thread = None
        self._selector.close()
        for sock in [self._front, *self._upstream.values()]:
            sock.close()
        self._upstream.clear()
        self._clients.clear()

    def totals(self):
        return {name: sum(d[name] for d in self.stats.values()) for name in self.stats["to_agent"]}

    def _run(self):
        while not self._stop.is_set():
            for key, _ in self._selector.select(_POLL_S):
                sock = key.fileobj
                while True:
                    try:
                        data, source = sock.recvfrom(65535)
                    except (BlockingIOError, InterruptedError):
                        break
                    except OSError:  # ICMP port unreachable from a client that went away
                        break
                    if sock is self._front:
                        upstream = self._upstream_for(source)
                        self._carry("to_agent", lambda d=data, s=upstream: _send(s, d, self.agent_address))
                    else:
                        client = self._clients[sock]
                        self._carry("to_client", lambda d=data, c=client: _send(self._front, d, c))
            self._release_expired()

    def _upstream_for(self, client):
        sock = self._upstream.get(client)
        if sock is None:
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind((self._front.getsockname()[0], 0))
            sock.setblocking(False)
            self._upstream[client] = sock
            self._clients[sock] = client
            self._selector.register(sock, selectors.EVENT_READ, None)
        return sock

    def _carry(self, direction, send):
        stats = self.stats[direction]
        stats["datagrams"] += 1
        for held in list(self._held):
            held.remaining -= 1
            if held.remaining <= 0:
                self._held.remove(held)
                held.send()
        roll = self.rng.random()
        if roll < self.drop:
            stats["dropped"] += 1
            return
        if roll < self.drop + self.reorder:
            stats["reordered"] += 1
            self._held.append(_Held(self.rng.randint(1, self.max_hold),
                                    time.monotonic() + self.max_hold_s, send))
            return
        send()
        stats["forwarded"] += 1
        if self.rng.random() < self.duplicate:
            stats["duplicated"] += 1
            send()

    def _release_expired(self):
        if not self._held:
            return
        now = time.monotonic()
        for held in [h for h in self._held if h.deadline <= now]:
            self._held.remove(held)
            held.send()


def _send(sock, data, address):
    try:
        sock.sendto(data, address)
    except OSError:
        pass  # the peer is gone or the buffer is full: a lossy link loses it


def _open_pty():
    master, slave = os.openpty()
    tty.setraw(master, termios.TCSANOW)
    tty.setraw(slave, termios.TCSANOW)
    os.set_blocking(master, False)
    return master, slave, os.ttyname(slave)


class _Direction:
    """Bytes read from one fd waiting to be written to the other, with pacing and bit flips."""

    def __init__(self, name, source, sink, bytes_per_second, bit_error_rate, rng):
        self.name = name
        self.source = source
        self.sink = sink
        self.pending = bytearray()
        self.bytes_per_second = bytes_per_second
        # Up to 10 ms of line time may leave at once: pty writes are cheap, threads are not exact.
        self.burst = max(1.0, bytes_per_second * 0.01) if bytes_per_second else 0.0
        self.tokens = self.burst
        self.refilled = time.monotonic()
        self.bit_error_rate = bit_error_rate
        self.rng = rng
        self.bits_to_next_flip = self._next_gap()
        self.stats = {"bytes_in": 0, "bytes_out": 0, "flipped_bits": 0, "corrupted_bytes": 0}

    def _next_gap(self):
        if not self.bit_error_rate:
            return None
        # Bits between independent flips are geometric: one draw per flip, not one per bit.
        u = 1.0 - self.rng.random()
        return int(math.log(u) / math.log1p(-self.bit_error_rate))

    def corrupt(self, data):
        if self.bits_to_next_flip is None:
            return data
        bits = len(data) * 8
        position = self.bits_to_next_flip
        if position >= bits:
            self.bits_to_next_flip -= bits
            return data
        data = bytearray(data)
        last_byte = -1
        while position < bits:
            data[position >> 3] ^= 1 << (position & 7)
            self.stats["flipped_bits"] += 1
            if position >> 3 != last_byte:
                self.stats["corrupted_bytes"] += 1
                last_byte = position >> 3
            position += 1 + self._next_gap()
        self.bits_to_next_flip = position - bits
        return bytes(data)

    def wants_input(self):
        return len(self.pending) < _SERIAL_BACKLOG

    def feed(self, data):
        self.stats["bytes_in"] += len(data)
        self.pending += self.corrupt(data)

    def allowance(self, now):
        """Bytes that may leave now, and seconds until the next one may when none can."""
        if not self.bytes_per_second:
            return len(self.pending), None
        self.tokens = min(self.burst, self.tokens + (now - self.refilled) * self.bytes_per_second)
        self.refilled = now
        count = min(len(self.pending), int(self.tokens))
        if count:
            return count, None
        return 0, (1.0 - self.tokens) / self.bytes_per_second

    def wrote(self, count):
        del self.pending[:count]
        self.stats["bytes_out"] += count
        if self.bytes_per_second:
            self.tokens -= count


class SerialRelay:
    """Joins a client pty to the agent's side byte for byte, paced and noisy (see module doc)."""

    def __init__(self, agent_device=None, *, baudrate=None, bit_error_rate=0.0, seed=1):
        self.baudrate = baudrate
        self.bit_error_rate = bit_error_rate
        self._fds = []
        try:
            client_master, client_slave, self.client_path = _open_pty()
            self._fds += [client_master, client_slave]  # the slave stays open: no EIO meanwhile
            if agent_device is None:
                agent_fd, agent_slave, self.agent_path = _open_pty()
                self._fds += [agent_fd, agent_slave]
            else:
                agent_fd = os.open(agent_device, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
                self._fds.append(agent_fd)
                tty.setraw(agent_fd, termios.TCSANOW)
                self.agent_path = agent_device
        except BaseException:
            self._close_fds()
            raise
        rng = random.Random(seed)
        bytes_per_second = baudrate / 10.0 if baudrate else 0.0
        self._directions = [
            _Direction("to_agent", client_master, agent_fd, bytes_per_second, bit_error_rate, rng),
            _Direction("to_client", agent_fd, client_master, bytes_per_second, bit_error_rate, rng),
        ]
        self.stats = {d.name: d.stats for d in self._directions}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="serial-relay", daemon=True)
        self._thread.start()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        if self._thread is not None:
            self._stop.set()
            self._thread.join(5)
            self._thread = None
        self._close_fds()

    def _close_fds(self):
        for fd in self._fds:
            try:
                os.close(fd)
            except OSError:
                pass
        self._fds = []

    def totals(self):
        return {name: sum(d.stats[name] for d in self._directions)
                for name in self._directions[0].stats}

    def _run(self):
        selector = selectors.DefaultSelector()
        try:
            while not self._stop.is_set():
                timeout = _POLL_S
                now = time.monotonic()
                for direction in self._directions:
                    count, wait = direction.allowance(now)
                    if count:
                        try:
                            written = os.write(direction.sink, direction.pending[:count])
                        except (BlockingIOError, InterruptedError):
                            written = 0
                        except OSError:  # the far side is closed for good: a cut cable
                            written = count
                        direction.wrote(written)
                    elif wait is not None:
                        timeout = min(timeout, max(wait, 0.0005))
                wanted = {}
                for direction in self._directions:
                    if direction.wants_input():
                        wanted.setdefault(direction.source, []).append(direction)
                for fd in wanted:
                    selector.register(fd, selectors.EVENT_READ)
                if not wanted:
                    time.sleep(timeout)
                    continue
                try:
                    ready = selector.select(timeout)
                finally:
                    for fd in wanted:
                        selector.unregister(fd)
                for key, _ in ready:
                    try:
                        data = os.read(key.fd, _SERIAL_CHUNK)
                    except (BlockingIOError, InterruptedError):
                        continue
                    except OSError:  # EIO: nobody holds the other end right now
                        time.sleep(_POLL_S)
                        continue
                    for direction in wanted[key.fd]:
                        direction.feed(data)
        finally:
            selector.close()


__all__ = ["UdpRelay", "SerialRelay"]
