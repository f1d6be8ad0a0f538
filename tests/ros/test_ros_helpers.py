"""The ROS test helpers leave nothing of a test in the next holder's graph.

A CI run once failed because ``xrce-ros action list`` in one module's private domain also listed
``/mcu/fibonacci``: an earlier module on the same pytest worker had held that domain, and its
rclpy action client was still alive (action clients and servers sit in reference cycles with
their node, so ``destroy_node`` and dropping the last name do not end them; a full collection
does, whenever it next runs).
"""

import gc
import weakref

from rclpy.action import ActionClient, ActionServer
from rclpy.node import Node
from test_msgs.action import Fibonacci

from ros_helpers import DomainLease, RosPeer, wait_until

CLIENT_ACTION, SERVER_ACTION = "/helpers_check/client_side", "/helpers_check/server_side"


def _action_topics(peer):
    return {name for name, _ in peer.node.get_topic_names_and_types()
            if name.startswith("/helpers_check/")}


def test_a_closed_peer_and_a_released_domain_leave_no_action_behind(monkeypatch):
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    monkeypatch.delenv("ROS_LOCALHOST_ONLY", raising=False)
    lease = DomainLease()
    observer = leaker = None
    collecting = gc.isenabled()
    try:
        observer = RosPeer(lease.domain_id, "helpers_observer")
        leaker = RosPeer(lease.domain_id, "helpers_leaker")
        ActionClient(leaker.node, Fibonacci, CLIENT_ACTION)  # as tests keep one: never destroyed
        server_node = Node("helpers_server", context=leaker.context,
                           start_parameter_services=False, enable_rosout=False)
        server = weakref.ref(ActionServer(server_node, Fibonacci, SERVER_ACTION,
                                          lambda handle: Fibonacci.Result()))
        assert wait_until(lambda: len(_action_topics(observer)) == 4, 20), _action_topics(observer)

        gc.disable()  # what a test module sees while no full collection has run yet
        leaker.close()
        leaker = None
        # The peer's own node: its action client goes with it.
        assert wait_until(lambda: not any(name.startswith(CLIENT_ACTION)
                                          for name in _action_topics(observer)), 20), \
            _action_topics(observer)
        # A node the test destroys itself: its action server lives on...
        server_node.destroy_node()
        del server_node
        assert server() is not None
        observer.close()
        observer = None
        # ...until the domain is released, while it is still the test's.
        lease.release()
        assert server() is None
    finally:
        if collecting:
            gc.enable()
        for peer in (leaker, observer):
            if peer is not None:
                peer.close()
        lease.release()
