"""Shared helpers for ROS 2 tests that must not see (or disturb) any other ROS graph.

- ``ros_domain`` fixture: a ROS_DOMAIN_ID from 40..99 held exclusively (an flock'ed file in the
  temp dir) for the test, with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, both set in os.environ.
- ``ros_peer`` fixture: the test's own rclpy Context + Node + SingleThreadedExecutor thread on that
  domain, for publishers/subscribers/clients/services the test uses to talk to the code under
  test. Everything it creates is destroyed when the test ends.

Usage: ``from ros_helpers import ros_domain, ros_peer  # noqa: F401`` in a test module.
"""

from __future__ import annotations

import fcntl
import gc
import os
import random
import tempfile
import threading
import time

import pytest
import rclpy
from rclpy.action import ActionClient, ActionServer
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

DOMAIN_RANGE = range(40, 100)


class DomainLease:
    """Exclusive use of one ROS domain id among processes on this machine."""

    def __init__(self):
        self.domain_id = None
        self._fd = None
        candidates = list(DOMAIN_RANGE)
        random.shuffle(candidates)
        for domain_id in candidates:
            path = os.path.join(tempfile.gettempdir(), "xrce-ros-domain-%d.lock" % domain_id)
            fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                continue
            # The holder unlinks the file when it releases it (nothing is left in /tmp): a lock
            # taken on a file that is no longer at ``path`` guards nothing, try the next domain.
            try:
                current = os.stat(path)
            except FileNotFoundError:
                current = None
            if current is None or current.st_ino != os.fstat(fd).st_ino:
                os.close(fd)
                continue
            self.domain_id, self._fd, self._path = domain_id, fd, path
            return
        raise RuntimeError("every ROS domain in %r is in use" % (DOMAIN_RANGE,))

    def release(self):
        if self._fd is not None:
            # rclpy's action clients and servers and the nodes they hold sit in reference cycles:
            # their DDS entities stay in the graph until a full collection. Collected here, while
            # the domain is still ours, they cannot show up in the next holder's graph.
            gc.collect()
            try:
                os.unlink(self._path)  # still locked: nobody can take the lock on it meanwhile
            except FileNotFoundError:
                pass
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None


def wait_until(predicate, timeout_s: float = 10.0, interval_s: float = 0.02) -> bool:
    """Poll ``predicate`` until true or ``timeout_s`` passes (blocking; for threads/sync code)."""
    deadline = time.monotonic() + timeout_s
    while True:
        if predicate():
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(interval_s)


async def async_wait_until(predicate, timeout_s: float = 10.0, interval_s: float = 0.02) -> bool:
    """Like wait_until, but yields to the asyncio loop between polls."""
    import asyncio

    deadline = time.monotonic() + timeout_s
    while True:
        if predicate():
            return True
        if time.monotonic() >= deadline:
            return False
        await asyncio.sleep(interval_s)


class RosPeer:
    """The test's own ROS participant: a context, one node and an executor thread."""

    def __init__(self, domain_id: int, node_name: str = "xrce_test_peer"):
        self.domain_id = domain_id
        self.context = Context()
        rclpy.init(args=[], context=self.context, domain_id=domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node(node_name, context=self.context, start_parameter_services=False,
                         enable_rosout=False, use_global_arguments=False)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = False
        self._thread = threading.Thread(target=self._spin, name="ros-test-peer", daemon=True)
        self._thread.start()

    def _spin(self):
        while not self._stop:
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except ExternalShutdownException:
                return

    def node_names(self) -> list[tuple[str, str]]:
        """(name, namespace) of every node this peer currently discovers, its own excluded."""
        own = (self.node.get_name(), self.node.get_namespace())
        return [n for n in self.node.get_node_names_and_namespaces() if n != own]

    def close(self):
        self._stop = True
        self.executor.wake()
        self._thread.join(5)
        self.executor.remove_node(self.node)
        # Node.destroy_node leaves action clients and servers alive, and with them the node's
        # DDS entities (event handlers go with their publisher or subscription).
        for waitable in list(self.node.waitables):
            if isinstance(waitable, (ActionClient, ActionServer)):
                waitable.destroy()
        self.node.destroy_node()
        self.executor.shutdown()
        self.context.try_shutdown()


@pytest.fixture
def ros_domain(monkeypatch):
    lease = DomainLease()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(lease.domain_id))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    try:
        yield lease.domain_id
    finally:
        lease.release()


@pytest.fixture
def ros_peer(ros_domain):
    peer = RosPeer(ros_domain)
    try:
        yield peer
    finally:
        peer.close()
