"""What the agent process leaves out to stay small (bench/agent/cost.py measures the memory)."""

import importlib.util
import subprocess
import sys
import time

import pytest

from agent_process import REPO, AgentProcess
from ros_helpers import async_wait_until, ros_domain, ros_peer, wait_until  # noqa: F401


def test_no_rcl_log_file(ros_domain, tmp_path):  # noqa: F811
    """rcl's own log file stays closed (xrce/agent/middleware/ros/domain.py ROS_ARGS); every rclpy process
    that opens it leaves one file per start in ROS_LOG_DIR."""
    pytest.importorskip("rclpy")
    with AgentProcess("udp4", env={"ROS_LOG_DIR": str(tmp_path)}) as agent:
        assert agent.banner
    assert agent.proc.returncode == 0
    assert list(tmp_path.iterdir()) == []


_MODULES_OF_A_SERVING_AGENT = r"""
import io, os, sys, threading
banner = threading.Event()


class Watch(io.TextIOWrapper):
    def write(self, text):
        if "agent on port" in text:
            banner.set()
        return super().write(text)


sys.stdout = Watch(sys.stdout.detach(), line_buffering=True)


def report():
    banner.wait(60)
    sys.stderr.write("MODULES " + " ".join(sorted(sys.modules)) + "\n")
    sys.stderr.flush()
    os._exit(0)


threading.Thread(target=report, daemon=True).start()
from xrce.agent.launcher import main
main(sys.argv[1:])
"""

# Each was imported by every agent once; each is only needed by some subcommand or option.
_NOT_IMPORTED_BY_A_UDP_AGENT = ("xrce.agent.demo", "xrce.agent.links.tcp",
                                "xrce.agent.links.serial", "shutil", "ssl",
                                "xml.etree.ElementTree", "xrce.agent.engine.xmlrep",
                                "xrce.agent.observe.capture", "xrce.agent.observe.stats_view",
                                "xrce.agent.interfaces.builder")


def _modules_of_a_serving_agent(*args):
    run = subprocess.run([sys.executable, "-c", _MODULES_OF_A_SERVING_AGENT, *args], cwd=REPO,
                         capture_output=True, text=True, timeout=60)
    line = [text for text in run.stderr.splitlines() if text.startswith("MODULES ")]
    assert line, run.stdout + run.stderr
    return set(line[0].split()[1:])


def test_a_udp_agent_leaves_out_what_other_subcommands_use():
    modules = _modules_of_a_serving_agent("udp4", "-p", "0", "-m", "ced")
    assert "xrce.agent.links.udp" in modules and "xrce.agent.engine.agent" in modules
    assert not modules.intersection(_NOT_IMPORTED_BY_A_UDP_AGENT)


def test_a_ros_agent_leaves_out_the_service_types_its_nodes_never_serve(ros_domain):  # noqa: F811
    """rclpy's parameter and logger services stay unloaded (xrce/agent/middleware/ros/rclpy_services.py): of
    rcl_interfaces' eight service types only the one rclpy.node names is imported."""
    pytest.importorskip("rclpy")
    modules = _modules_of_a_serving_agent("udp4", "-p", "0")
    assert "rclpy.node" in modules and "rcl_interfaces.srv._list_parameters" in modules
    loaded = sorted(name for name in modules if name.startswith("rcl_interfaces.srv._"))
    assert loaded == ["rcl_interfaces.srv._list_parameters"]
    assert not modules.intersection(_NOT_IMPORTED_BY_A_UDP_AGENT)
    if importlib.util.find_spec("xrce.agent._heap") is not None:
        # The start-up malloc_trim goes through the agent's own helper, not the ctypes package.
        assert "xrce.agent._heap" in modules and "ctypes" not in modules


_NODE_WITH_PARAMETER_SERVICES = """
import sys
import time
import rclpy
from xrce.agent.middleware.ros import rclpy_services
rclpy_services.defer_unused()
from rclpy.context import Context
from rclpy.node import Node
import rcl_interfaces.srv
assert "rcl_interfaces.srv._get_parameters" not in sys.modules
context = Context()
rclpy.init(args=[], context=context)
node = Node("deferred_services", context=context, enable_rosout=False, enable_logger_service=True)
services = dict(node.get_service_names_and_types_by_node("deferred_services", "/"))
print(sorted(services))
print(rcl_interfaces.srv.GetParameters.Request().names)
node.destroy_node()
rclpy.shutdown(context=context)
"""


def test_deferred_rclpy_services_still_start_when_a_node_asks(ros_domain):  # noqa: F811
    pytest.importorskip("rclpy")
    run = subprocess.run([sys.executable, "-c", _NODE_WITH_PARAMETER_SERVICES], cwd=REPO,
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stdout + run.stderr
    for service in ("/deferred_services/get_parameters", "/deferred_services/list_parameters",
                    "/deferred_services/set_logger_levels"):
        assert service in run.stdout, run.stdout


def test_agent_nodes_publish_no_parameter_events(ros_peer, ros_domain):  # noqa: F811
    """The agent's nodes leave rclpy's /parameter_events publisher out (ros_domain.AgentNode):
    nothing can change their parameters, and that publisher's history cost memory. The agent
    has nodes in a domain once a client has a participant there: the client's, and the hidden
    ``_xrce_agent`` that publishes /diagnostics."""
    from xrce.client import Session
    from xrce.transports.udp import UdpTransport

    def publishers(node):
        try:
            # no_demangle: the wake topic is a DDS-level one, which ROS listings leave out.
            return dict(ros_peer.node.get_publisher_names_and_types_by_node(node, "/",
                                                                             no_demangle=True))
        except Exception:  # the node is not discovered yet
            return {}

    with AgentProcess("udp4") as agent:
        session = Session(UdpTransport("127.0.0.1", agent.port), history=8)
        try:
            assert session.create(attempts=5, timeout_ms=1000)
            session.create_participant(domain_id=ros_domain, name="footprint_board")
            assert session.run_until_all_status(5000), session.last_statuses
            # The wake topic's publisher (on the client's node) and /diagnostics' (on the
            # hidden one) seen: the nodes' publishers have been discovered.
            assert wait_until(lambda: any("/_xrce_agent/wake_" in name
                                          for name in publishers("footprint_board"))
                              and "rt/diagnostics" in publishers("_xrce_agent"), timeout_s=20), \
                (publishers("footprint_board"), publishers("_xrce_agent"))
            assert "rt/parameter_events" not in publishers("footprint_board")
            assert "rt/parameter_events" not in publishers("_xrce_agent")
        finally:
            session.close()


def test_agent_node_creates_a_parameter_events_writer_a_client_asks_for(ros_domain):  # noqa: F811
    """Only the publisher of rclpy's own construction is left out: a client's writer on
    /parameter_events, made later through the same node, is a real one."""
    import rclpy
    from rcl_interfaces.msg import ParameterEvent
    from rclpy.context import Context
    from rclpy.publisher import Publisher

    from xrce.agent.middleware.ros.agent_node import AgentNode
    from xrce.agent.middleware.ros.domain import NO_TYPE_DESCRIPTION

    context = Context()
    rclpy.init(args=[], context=context, domain_id=ros_domain)
    try:
        node = AgentNode("footprint_probe", context=context, start_parameter_services=False,
                         enable_rosout=False, parameter_overrides=[NO_TYPE_DESCRIPTION])
        assert node.get_parameter("use_sim_time").value is False  # declared without a publisher
        assert not any(p.topic_name == "/parameter_events" for p in node.publishers)
        writer = node.create_publisher(ParameterEvent, "/parameter_events", 10)
        assert isinstance(writer, Publisher) and writer.topic_name == "/parameter_events"
        writer.publish(ParameterEvent())
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_agent_node_forgets_the_entities_it_destroys(ros_domain):  # noqa: F811
    """Issue 39, serial churn: rclpy's callback group kept a weak reference to every entity and
    event handler ever made on a node. The anchor node hosts the wake-up each time a serial board
    is replaced, so its group grew by ~5 references a board life for the agent's lifetime."""
    import rclpy
    from rclpy.context import Context
    from std_msgs.msg import String
    from test_msgs.srv import BasicTypes

    from xrce.agent.middleware.ros.agent_node import AgentNode
    from xrce.agent.middleware.ros.domain import NO_TYPE_DESCRIPTION

    context = Context()
    rclpy.init(args=[], context=context, domain_id=ros_domain)
    try:
        node = AgentNode("callback_group_probe", context=context, start_parameter_services=False,
                         enable_rosout=False, parameter_overrides=[NO_TYPE_DESCRIPTION])
        group = node.default_callback_group
        before = len(group.entities)
        for round_ in range(20):
            made = [(node.destroy_subscription,
                     node.create_subscription(String, "/probe_%d" % round_, lambda _m: None, 10)),
                    (node.destroy_publisher, node.create_publisher(String, "/probe", 10)),
                    (node.destroy_guard_condition, node.create_guard_condition(lambda: None)),
                    (node.destroy_timer, node.create_timer(60.0, lambda: None)),
                    (node.destroy_service, node.create_service(BasicTypes, "/probe_srv",
                                                               lambda _q, r: r)),
                    (node.destroy_client, node.create_client(BasicTypes, "/probe_srv"))]
            assert len(group.entities) > before  # what the group holds while they live
            for destroy, entity in made:
                assert destroy(entity)
            del made
        assert len(group.entities) == before, "%d references left behind" % (
            len(group.entities) - before)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


async def test_the_agents_own_entities_stop_moving_once_a_hosting_board_goes(
        ros_domain, ros_peer):  # noqa: F811
    """Issue 39: each move of the agent's own entities (the wake-up) between nodes makes their
    DDS endpoints anew, and Fast DDS keeps ~60 bytes for every endpoint that ever matched, for the
    participant's life. Over UDP, vanished boards retire oldest first, so the wake-up moved at
    each retirement; over serial, one board at a time, it went to the anchor and back each life
    (1-2 MB/h at a life a second). Once a hosting board goes it stays on the hidden anchor."""
    from xrce.agent.middleware.ros.ros_middleware import RosMiddleware

    def board(life):
        return (0x0B0A0000 + life, 0x01)

    mw = RosMiddleware()
    await mw.start()
    try:
        mw.create_participant(board(0), ros_domain, "board")
        domain = mw.domains.runtime(ros_domain)
        # The domain joined for this board makes its wake-up after the board's first burst.
        assert wait_until(lambda: domain.call(lambda: domain._wake_item is not None, 20.0), 20)
        mw.create_participant(board(1), ros_domain, "board")
        mw.delete(board(0))  # the first board's node hosted the agent's entities
        assert domain.call(lambda: domain.agent_node is domain._anchor, 20.0)
        moves = domain.call(lambda: domain._wake_item.generation, 20.0)
        # Over UDP: a new board comes, the oldest vanished one is retired.
        for life in range(2, 8):
            mw.create_participant(board(life), ros_domain, "board")
            mw.delete(board(life - 1))
        # Over serial: the board goes before the next one comes.
        for life in range(8, 12):
            mw.delete(board(life - 1))
            mw.create_participant(board(life), ros_domain, "board")
        assert domain.call(lambda: domain._wake_item.generation, 20.0) == moves
        assert domain.call(lambda: 42, 20.0) == 42  # the wake-up still works
        assert await async_wait_until(lambda: sorted(ros_peer.node_names()) == [
            ("_xrce_agent", "/"), ("board", "/")], 20.0), ros_peer.node_names()
    finally:
        await mw.close()


def test_interface_jobs_run_one_at_a_time_on_threads_that_end():
    """The lazy listing and builds of xrce.agent.interfaces leave no idle worker behind (a pool's
    stayed for the agent's whole life, with its stack and malloc arena)."""
    import threading

    from xrce.agent import interfaces

    running, most = [0], [0]
    lock = threading.Lock()

    def job(value):
        with lock:
            running[0] += 1
            most[0] = max(most[0], running[0])
        time.sleep(0.05)
        with lock:
            running[0] -= 1
        if value == "bad":
            raise ValueError(value)
        return value * 2

    futures = [interfaces._submit(job, value) for value in (1, 2, "bad", 3)]
    assert [f.result(timeout=30) for f in futures if f is not futures[2]] == [2, 4, 6]
    with pytest.raises(ValueError):
        futures[2].result(timeout=30)
    assert most[0] == 1
    assert wait_until(lambda: not any(thread.name.startswith("xrce-interfaces")
                                      for thread in threading.enumerate()), timeout_s=10)
