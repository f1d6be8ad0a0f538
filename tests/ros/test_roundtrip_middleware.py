"""Issue 53 item 4 inside RosMiddleware: which board's Naming translates what it reads back, and
what stays off the compiled UDP path (``subscription_address``/``publisher_address`` None).

Two boards in one domain, named apart as a fleet file names them (``fleet.assign(origin)``): the
one the agent gives ``/robot1`` reads the shared Graph in its own names, the one it names as it
asked reads the bytes as they came; only the first one's graph reader and parameter-event
writer leave the compiled path."""

from __future__ import annotations

import pytest

from ros_helpers import async_wait_until, ros_domain  # noqa: F401
from xrce.agent.middleware import ClientOrigin, EndpointQosSpec, TopicSpec
from xrce.agent.middleware.ros.ros_middleware import RosMiddleware
from xrce.agent.middleware.ros.graph import GRAPH_SPEC, decode_graph
from xrce.agent.middleware.ros.naming import Naming

QOS = EndpointQosSpec(reliable=True, keep_last=True, depth=10, durability="volatile")
ROBOT1, PLAIN = b"\x00\x00\x00\x01", b"\x00\x00\x00\x02"
EVENTS = TopicSpec("rt/parameter_events", "rcl_interfaces::msg::dds_::ParameterEvent_")


class TwoBoards:
    """What a fleet file decides, reduced to its interface: a Naming per client key."""

    def assign(self, origin: ClientOrigin):
        if origin.client_key == ROBOT1:
            return Naming("/robot1"), "robot1"
        return Naming(), None


@pytest.fixture
async def middleware(ros_domain):  # noqa: F811
    from xrce.agent import interfaces

    interfaces.build(names=["micro_ros_msgs"])  # a cache hit after the first time
    mw = RosMiddleware(fleet=TwoBoards())
    await mw.start()
    try:
        yield mw
    finally:
        await mw.close()


def _board(mw, client: int, key_bytes: bytes, domain_id: int, received: list):
    def key(object_id):
        return (client, object_id)
    mw.create_participant(key(1), domain_id, "tb3_params", ClientOrigin(key_bytes))
    mw.create_subscriber(key(4), key(1))
    mw.create_topic(key(2), key(1), GRAPH_SPEC)
    mw.create_datareader(key(6), key(4), key(2), QOS, received.append)
    mw.create_publisher(key(3), key(1))
    mw.create_topic(key(12), key(1), EVENTS)
    mw.create_datawriter(key(5), key(3), key(12), QOS)
    return key


async def test_each_board_reads_the_graph_in_its_own_names(middleware, ros_domain):  # noqa: F811
    robot1_graphs, plain_graphs = [], []
    robot1 = _board(middleware, 1, ROBOT1, ros_domain, robot1_graphs)
    plain = _board(middleware, 2, PLAIN, ros_domain, plain_graphs)

    def nodes(graphs):
        return {(namespace, name) for namespace, name, _ in decode_graph(graphs[-1])} \
            if graphs else set()

    def both_listed(graphs):
        return bool(graphs) and len(decode_graph(graphs[-1])) >= 2

    assert await async_wait_until(lambda: both_listed(robot1_graphs) and both_listed(plain_graphs),
                                  15), (nodes(robot1_graphs), nodes(plain_graphs))
    # The plain board sees both as ROS has them; robot 1 its own node as it created it, and the
    # plain board's node, which is in the root namespace, as it is: two ("/", "tb3_params").
    assert nodes(plain_graphs) == {("/robot1", "tb3_params"), ("/", "tb3_params")}
    robot1_view = decode_graph(robot1_graphs[-1])
    assert [(ns, name) for ns, name, _ in robot1_view] == [("/", "tb3_params")] * 2
    names = {entity for _, _, entities in robot1_view for _, entity, _ in entities}
    assert "/parameter_events" in names and not [n for n in names if n.startswith("/robot1")]

    # The compiled path would carry the bytes as they are: not for what is translated.
    compiled = middleware.compiled_path_support()
    assert compiled.subscription_address(robot1(6)) is None
    assert compiled.publisher_address(robot1(5)) is None
    assert compiled.subscription_address(plain(6)) and compiled.publisher_address(plain(5))
