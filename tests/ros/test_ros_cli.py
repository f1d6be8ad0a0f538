"""``xrce-ros``, the ros2 verbs for a venv without ros2cli, run as a real command against a live
board: our client (CPython) in a thread, through a real ``xrce-agent -m dds``, into the ROS graph.

The board publishes ``/chatter`` (10 Hz, reliable), subscribes ``/cmd_in`` and serves
``/double_it`` (test_msgs/srv/BasicTypes). Parameters and actions come from an rclpy node in the
test: the board-side parameter server is not there yet, and neither is the agent's action bridging;
a board-side action server goes through the agent once that lands, and these tests then point at
it. Every expected output is what ros2cli (Jazzy) prints for the same graph: ros2topic,
ros2node, ros2service, ros2param and ros2action print these lines for these verbs.

One agent, board and ROS peer per module (a private ROS domain with localhost-only discovery);
everything started here is stopped at the end.
"""

import os
import re
import selectors
import signal
import subprocess
import sys
import threading
import time

import pytest
from rclpy.action import ActionServer
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message, serialize_message
from test_msgs.action import Fibonacci
from test_msgs.srv import BasicTypes

from agent_process import REPO, AgentProcess, restore_default_signals
from ros_helpers import DomainLease, RosPeer, wait_until
from xrce.client.session import Session
from xrce.msgs.std_msgs import String
from xrce.transports.udp import UdpTransport

BOARD_NODE = "mcu_board"
PARAM_NODE = "board_params"
CLI_TIMEOUT_S = 60
# The lists must hold the whole graph: on a loaded machine discovery can take longer than ros2cli's
# 0.5 s (xrce-ros also waits for the graph to settle); a participant Fast DDS missed at first is
# found at its next announcement, so a list that lacks one is asked again (``Graph.run_until``).
SPIN = []
WAIT = ["--timeout", "10"]  # param get/set: how long to wait for the node (ros2param's option)
HZ_LINES = (re.compile(r"^average rate: (\d+\.\d{3})$"),
            re.compile(r"^\tmin: \d+\.\d{3}s max: \d+\.\d{3}s std dev: \d+\.\d{5}s window: \d+$"))


def xrce_ros_command():
    """The installed console script when this venv has it (what a user runs), else the module."""
    script = os.path.join(os.path.dirname(sys.executable), "xrce-ros")
    if os.path.exists(script):
        return [script]
    return [sys.executable, "-m", "xrce.tools.ros_cli"]


class RawBasicTypes:
    """test_msgs/srv/BasicTypes for the board, which (de)serializes with rclpy."""

    TYPE_NAME_REQUEST = "test_msgs::srv::dds_::BasicTypes_Request_"
    TYPE_NAME_RESPONSE = "test_msgs::srv::dds_::BasicTypes_Response_"
    Request = None
    Response = None


class Board(threading.Thread):
    """The firmware side in one thread (a session is single-threaded, as on an MCU)."""

    def __init__(self, port, domain_id):
        super().__init__(daemon=True, name="ros-cli-board")
        self.session = Session(UdpTransport("127.0.0.1", port), history=8)
        self.domain_id = domain_id
        self.received = []
        self.requests = []
        self.ready = threading.Event()
        self.failed = None
        self._halt = threading.Event()

    def run(self):
        session = self.session
        try:
            if not session.create(attempts=5, timeout_ms=1000):
                self.failed = "no agent"
                return
            node = session.create_participant(domain_id=self.domain_id, name=BOARD_NODE)
            chatter = session.create_writer(node, "/chatter", String, reliable=True, depth=10)
            session.create_reader(node, "/cmd_in", String, self.received.append, reliable=True,
                                  depth=10)

            def serve(identity, body):
                request = deserialize_message(b"\x00\x01\x00\x00" + bytes(body),
                                              BasicTypes.Request)
                self.requests.append(request.int32_value)
                response = BasicTypes.Response(int32_value=request.int32_value * 2,
                                               string_value="doubled")
                session.send_reply(replier, identity, serialize_message(response)[4:])

            replier = session.create_service_server(node, "/double_it", RawBasicTypes, serve)
            if not session.run_until_all_status(10000):
                self.failed = "entities refused: %r" % (session.last_statuses,)
                return
            self.ready.set()
            count = 0
            next_at = time.monotonic()
            while not self._halt.is_set():
                if time.monotonic() >= next_at:
                    count += 1
                    session.write(chatter, String(data="hello %d" % count))
                    next_at += 0.1
                session.spin_once(10)
        except Exception as exc:  # reported by the fixture, which would otherwise only time out
            self.failed = repr(exc)
            raise
        finally:
            self.ready.set()

    def stop(self):
        self._halt.set()
        self.join(10)
        self.session.delete(attempts=2, timeout_ms=500)
        self.session.close()


def _fibonacci(goal_handle):
    feedback = Fibonacci.Feedback(sequence=[0, 1])
    for _ in range(1, goal_handle.request.order):
        feedback.sequence.append(feedback.sequence[-1] + feedback.sequence[-2])
        goal_handle.publish_feedback(feedback)
    goal_handle.succeed()
    return Fibonacci.Result(sequence=feedback.sequence)


class Graph:
    def __init__(self, domain_id, agent, board, peer, param_node):
        self.domain_id, self.agent, self.board, self.peer = domain_id, agent, board, peer
        self.param_node = param_node
        self.env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id),
                        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
        self.env.pop("ROS_LOCALHOST_ONLY", None)

    def run(self, *args, expect_rc=0, timeout_s=CLI_TIMEOUT_S, env=None):
        """``xrce-ros ARGS`` to its end: (stdout lines, stderr text)."""
        done = subprocess.run(xrce_ros_command() + list(args), env=dict(self.env, **(env or {})),
                              cwd=REPO, text=True, capture_output=True, timeout=timeout_s)
        if expect_rc is not None:
            assert done.returncode == expect_rc, (args, done.returncode, done.stdout, done.stderr)
        return done.stdout.splitlines(), done.stderr

    def run_until(self, expected, *args, attempts=4, timeout_s=CLI_TIMEOUT_S):
        """``run(*args)`` until its lines are ``expected`` (a list, or a test on the list): a
        command that ran before discovery found everything is asked again, as a user would. So is
        one still waiting after ``timeout_s``: now and then (a few in a hundred runs on a loaded
        machine) Fast DDS leaves a new reader unmatched on the writer's side, and the sample or
        the response never comes, to ros2 as to xrce-ros (it waits, as ros2 does)."""
        for _ in range(attempts):
            try:
                lines, error = self.run(*args, expect_rc=None, timeout_s=timeout_s)
            except subprocess.TimeoutExpired as timed_out:
                lines, error = [], "timed out: %r" % (timed_out.stderr,)
            if (expected(lines) if callable(expected) else lines == expected):
                return lines
        assert lines == expected, (args, lines, error)
        return lines

    def start(self, *args):
        return subprocess.Popen(xrce_ros_command() + list(args), env=self.env, cwd=REPO,
                                text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                preexec_fn=restore_default_signals)  # Ctrl-C stops it


@pytest.fixture(scope="module")
def graph():
    lease = DomainLease()
    agent = board = peer = param_node = None
    environment = pytest.MonkeyPatch()
    # The test's own rclpy participant discovers as the agent and the commands do.
    environment.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    environment.delenv("ROS_LOCALHOST_ONLY", raising=False)
    try:
        agent = AgentProcess("udp4", "-m", "dds",
                             env={"ROS_DOMAIN_ID": str(lease.domain_id),
                                  "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"})
        agent.__enter__()
        board = Board(agent.port, lease.domain_id)
        board.start()
        assert board.ready.wait(30) and board.failed is None, board.failed
        peer = RosPeer(lease.domain_id)
        param_node = Node(PARAM_NODE, context=peer.context, parameter_overrides=[
            Parameter("rate", value=7), Parameter("name", value="bot"),
            Parameter("gain", value=0.5)], automatically_declare_parameters_from_overrides=True)
        ActionServer(param_node, Fibonacci, "/fibonacci", _fibonacci)
        peer.executor.add_node(param_node)
        assert wait_until(lambda: (BOARD_NODE, "/") in peer.node_names(), 20), peer.node_names()
        yield Graph(lease.domain_id, agent, board, peer, param_node)
    finally:
        if param_node is not None:
            peer.executor.remove_node(param_node)
            param_node.destroy_node()
        if peer is not None:
            peer.close()
        if board is not None:
            board.stop()
        if agent is not None:
            agent.stop()
        lease.release()
        environment.undo()


# ----------------------------------------------------------------------------- topic

def test_topic_list_shows_the_boards_topics_as_ros2_does(graph):
    # ros2 topic list: the names, sorted, one a line; /parameter_events and /rosout are there as
    # in any graph ros2 joins (its own node has them), /diagnostics is the agent's; the action's
    # topics are hidden.
    graph.run_until(["/chatter", "/cmd_in", "/diagnostics", "/parameter_events", "/rosout"],
                    "topic", "list", *SPIN)
    graph.run_until(["/chatter [std_msgs/msg/String]", "/cmd_in [std_msgs/msg/String]",
                     "/diagnostics [diagnostic_msgs/msg/DiagnosticArray]",
                     "/parameter_events [rcl_interfaces/msg/ParameterEvent]",
                     "/rosout [rcl_interfaces/msg/Log]"], "topic", "list", "-t", *SPIN)
    graph.run_until(lambda lines: {"/fibonacci/_action/status", "/fibonacci/_action/feedback",
                                   "/chatter"} <= set(lines),
                    "topic", "list", "--include-hidden-topics", *SPIN)
    graph.run_until(["5"], "topic", "list", "-c", *SPIN)
    # -v: ros2's two blocks, a count per topic and role, each block closed by a blank line.
    graph.run_until(lambda lines: lines[:1] == ["Published topics:"]
                    and " * /chatter [std_msgs/msg/String] 1 publisher" in lines
                    and lines[lines.index("Subscribed topics:") - 1] == ""
                    and " * /cmd_in [std_msgs/msg/String] 1 subscriber" in lines
                    and lines[-1] == "", "topic", "list", "-v", *SPIN)


def _endpoint_blocks(endpoints):
    """What ros2topic info -v prints for each endpoint: rclpy's own text of it, a blank line."""
    return [line for endpoint in endpoints for line in str(endpoint).split("\n") + [""]]


def test_topic_info_prints_counts_nodes_and_qos_as_ros2_does(graph):
    # ros2 topic info: the type and the counts; -v each endpoint as rclpy's TopicEndpointInfo
    # prints itself (ros2topic prints that object), a blank line after each block. What ros2
    # would print is taken from the test's own participant, which sees the same graph.
    graph.run_until(["Type: std_msgs/msg/String", "Publisher count: 1", "Subscription count: 0"],
                    "topic", "info", "/chatter", *SPIN)
    graph.run_until(["Type: std_msgs/msg/String", "Publisher count: 0", "Subscription count: 1"],
                    "topic", "info", "/cmd_in", *SPIN)
    peer = graph.peer.node

    def as_ros2_prints(topic):
        publishers = peer.get_publishers_info_by_topic(topic)
        subscriptions = peer.get_subscriptions_info_by_topic(topic)
        return (["Type: std_msgs/msg/String", "", "Publisher count: %d" % len(publishers), ""]
                + _endpoint_blocks(publishers)
                + ["Subscription count: %d" % len(subscriptions), ""]
                + _endpoint_blocks(subscriptions))

    for topic, kind in (("/chatter", "PUBLISHER"), ("/cmd_in", "SUBSCRIPTION")):
        lines = graph.run_until(lambda lines: lines == as_ros2_prints(topic),
                                "topic", "info", "-v", topic, *SPIN)
        # The board's endpoint, as the board asked for it: its node, reliable (the board's
        # writer and reader are), a topic type hash as rclpy prints it.
        first = lines.index("Node name: %s" % BOARD_NODE)
        assert lines[first + 1] == "Node namespace: /", lines
        assert "Endpoint type: %s" % kind in lines and "  Reliability: RELIABLE" in lines, lines
        assert any(re.fullmatch(r"Topic type hash: RIHS01_[0-9a-f]{64}", line) for line in lines)
        assert any(re.fullmatch(r"GID: ([0-9a-f]{2}\.){15}[0-9a-f]{2}", line) for line in lines)
    lines, error = graph.run("topic", "info", "/nobody", expect_rc=1)
    assert lines == [] and error == "Unknown topic '/nobody'\n"


def test_topic_echo_once_prints_the_boards_sample_as_yaml(graph):
    # ros2 topic echo: the message as YAML, then a line '---'.
    def one_sample(pattern):
        return lambda lines: (len(lines) == 2 and re.fullmatch(pattern, lines[0]) is not None
                              and lines[1] == "---")

    graph.run_until(one_sample(r"data: hello \d+"), "topic", "echo", "/chatter", "--once",
                    timeout_s=20)
    graph.run_until(one_sample(r"data: hello \d+"), "topic", "echo", "/chatter",
                    "std_msgs/msg/String", "--once", "--qos-reliability", "best_effort",
                    timeout_s=20)
    graph.run_until(one_sample(r"hello \d+"), "topic", "echo", "/chatter", "--once", "--field",
                    "data", timeout_s=20)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_topic_echo_runs_until_ctrl_c_or_sigterm(graph, signum):
    echo = graph.start("topic", "echo", "/chatter")
    try:
        lines = [echo.stdout.readline() for _ in range(4)]  # two samples
        echo.send_signal(signum)
        # ros2cli's main returns signal.SIGINT (2) or, its context shut down, signal.SIGTERM (15).
        assert echo.wait(20) == int(signum)
    finally:
        if echo.poll() is None:
            echo.kill()
            echo.wait()
        echo.stdout.close()
        echo.stderr.close()
    assert [line for line in lines[1::2]] == ["---\n", "---\n"], lines
    first, second = (int(re.fullmatch(r"data: hello (\d+)\n", line).group(1)) for line in lines[::2])
    assert second > first, lines


def test_topic_hz_prints_ros2s_rate_lines(graph):
    hz = graph.start("topic", "hz", "/chatter")
    try:
        lines = []
        selector = selectors.DefaultSelector()
        selector.register(hz.stdout, selectors.EVENT_READ)
        deadline = time.monotonic() + CLI_TIMEOUT_S
        while len(lines) < 4:  # two reports of two lines each
            assert time.monotonic() < deadline, lines
            if selector.select(0.5):
                line = hz.stdout.readline()
                assert line, (lines, hz.stderr.read())
                lines.append(line.rstrip("\n"))
        selector.close()
        hz.send_signal(signal.SIGINT)  # hz runs until Ctrl-C, as ros2's
        assert hz.wait(20) == 2
    finally:
        if hz.poll() is None:
            hz.kill()
            hz.wait()
        hz.stdout.close()
        hz.stderr.close()
    assert len(lines) == 4, lines
    for index, line in enumerate(lines):
        assert HZ_LINES[index % 2].match(line), line
    rate = float(HZ_LINES[0].match(lines[2]).group(1))
    assert 2.0 < rate < 50.0, rate  # the board publishes at 10 Hz; a loaded machine bunches them


def test_topic_pub_reaches_the_board(graph):
    lines, _ = graph.run("topic", "pub", "--once", "/cmd_in", "std_msgs/msg/String",
                         "data: hi board")
    # ros2 topic pub --once waits for the board's subscription (and says so when it has to).
    lines = [line for line in lines
             if line != "Waiting for at least 1 matching subscription(s)..."]
    assert lines == ["publisher: beginning loop",
                     "publishing #1: std_msgs.msg.String(data='hi board')", ""]
    assert wait_until(lambda: any(m.data == "hi board" for m in graph.board.received), 10)
    lines, _ = graph.run("topic", "pub", "-t", "3", "-r", "20", "-p", "2", "/cmd_in",
                         "std_msgs/msg/String", "{data: again}")
    assert "publishing #2: std_msgs.msg.String(data='again')" in lines
    assert not any(line.startswith(("publishing #1", "publishing #3")) for line in lines)
    assert wait_until(lambda: sum(m.data == "again" for m in graph.board.received) == 3, 10)


# ----------------------------------------------------------------------------- node

def test_node_list_shows_the_board_and_hides_hidden_nodes(graph):
    # ros2 node list: full names, sorted; the agent shows no node of its own beside a board (its
    # entities live on the board's node, or on the hidden _xrce_agent for /diagnostics) and the
    # CLI's own node is hidden (a leading underscore).
    graph.run_until(sorted(["/" + BOARD_NODE, "/" + PARAM_NODE, "/xrce_test_peer"]),
                    "node", "list", *SPIN)
    graph.run_until(lambda lines: "/" + BOARD_NODE in lines
                    and any(line.startswith("/_xrce_ros_") for line in lines),
                    "node", "list", "-a", *SPIN)
    graph.run_until(["3"], "node", "list", "-c", *SPIN)
    # ROS_DOMAIN_ID is read as ros2 reads it: another domain has none of these nodes.
    other = DomainLease()
    try:
        lines, _ = graph.run("node", "list", "--spin-time", "2",
                             env={"ROS_DOMAIN_ID": str(other.domain_id)})
    finally:
        other.release()
    assert lines == []


def test_node_info_lists_the_boards_endpoints_as_ros2_does(graph):
    # ros2 node info: each kind's names and types, indented; an empty kind is a blank line; the
    # board's node is what the board created (the agent adds nothing to it).
    graph.run_until(["/" + BOARD_NODE,
                     "  Subscribers:", "    /cmd_in: std_msgs/msg/String",
                     "  Publishers:", "    /chatter: std_msgs/msg/String",
                     "  Service Servers:", "    /double_it: test_msgs/srv/BasicTypes",
                     "  Service Clients:", "",
                     "  Action Servers:", "",
                     "  Action Clients:", ""], "node", "info", "/" + BOARD_NODE, *SPIN)
    # An action server is one line among the action servers; its topics and services are hidden
    # (/fibonacci/_action/...) unless asked for.
    lines = graph.run_until(lambda lines: "    /fibonacci: test_msgs/action/Fibonacci" in lines,
                            "node", "info", "/" + PARAM_NODE, *SPIN)
    assert lines[lines.index("  Action Servers:") + 1] == "    /fibonacci: test_msgs/action/Fibonacci"
    assert "    /%s/list_parameters: rcl_interfaces/srv/ListParameters" % PARAM_NODE in lines
    assert not any("/_action/" in line for line in lines), lines
    graph.run_until(lambda lines: "    /fibonacci/_action/send_goal: "
                                  "test_msgs/action/Fibonacci_SendGoal" in lines,
                    "node", "info", "/" + PARAM_NODE, "--include-hidden", *SPIN)
    # As typed: ros2 finds /mcu_board, not mcu_board.
    lines, error = graph.run("node", "info", BOARD_NODE, expect_rc=1)
    assert lines == [] and error == "Unable to find node '%s'\n" % BOARD_NODE


# ----------------------------------------------------------------------------- service

def test_service_list_shows_the_boards_service(graph):
    lines = graph.run_until(
        lambda lines: {"/double_it [test_msgs/srv/BasicTypes]",
                       "/%s/get_parameters [rcl_interfaces/srv/GetParameters]" % PARAM_NODE,
                       "/xrce_test_peer/get_type_description "
                       "[type_description_interfaces/srv/GetTypeDescription]"} <= set(lines),
        "service", "list", "-t", *SPIN)
    assert lines == sorted(lines)
    assert not any("/_action/" in line for line in lines)  # hidden: the action's services
    graph.run_until([line.split(" [")[0] for line in lines], "service", "list", *SPIN)
    graph.run_until(lambda hidden: {"/fibonacci/_action/send_goal", "/double_it"} <= set(hidden),
                    "service", "list", "--include-hidden-services", *SPIN)


def test_service_call_is_served_by_the_board(graph):
    lines = graph.run_until(lambda lines: "response:" in lines, "service", "call", "/double_it",
                            "test_msgs/srv/BasicTypes", "{int32_value: 21}", timeout_s=20)
    # ros2 service call: 'waiting for service...' when the client was not matched yet, the
    # request's repr, a blank line, 'response:', the response's repr, a blank line.
    if lines and lines[0] == "waiting for service to become available...":
        lines = lines[1:]
    assert lines == [
        "requester: making request: %r" % BasicTypes.Request(int32_value=21), "",
        "response:", "%r" % BasicTypes.Response(int32_value=42, string_value="doubled"), ""]
    assert 21 in graph.board.requests


# ----------------------------------------------------------------------------- param

def test_param_list_get_set_on_an_rclpy_node(graph):
    graph.run_until(["  gain", "  name", "  rate", "  start_type_description_service",
                     "  use_sim_time"], "param", "list", PARAM_NODE, *SPIN)
    graph.run_until(lambda lines: lines[:3] == ["  gain (type: double)", "  name (type: string)",
                                                "  rate (type: integer)"],
                    "param", "list", "/" + PARAM_NODE, "--param-type", *SPIN)
    # Each get and set is a new process whose service clients Fast DDS may leave unmatched on a
    # loaded machine (run_until's docstring): asked again as a user would. Setting 9 twice is 9.
    graph.run_until(["Integer value is: 7"], "param", "get", PARAM_NODE, "rate", *WAIT)
    graph.run_until(["String value is: bot"], "param", "get", PARAM_NODE, "name", *WAIT)
    graph.run_until(["Double value is: 0.5"], "param", "get", PARAM_NODE, "gain", *WAIT)
    graph.run_until(["7"], "param", "get", PARAM_NODE, "rate", "--hide-type", *WAIT)
    graph.run_until(["Set parameter successful"], "param", "set", PARAM_NODE, "rate", "9", *WAIT)
    assert graph.param_node.get_parameter("rate").value == 9
    graph.run_until(["Integer value is: 9"], "param", "get", PARAM_NODE, "rate", *WAIT)
    lines, error = graph.run("param", "get", "/nobody_here", "rate", expect_rc=1)
    assert lines == [] and error == "Node not found\n"


def test_param_list_does_not_wait_on_nodes_without_parameter_services(graph, monkeypatch, capsys):
    """ros2param waits 5 s on every node without parameter services (the board's, the test's
    peer); xrce-ros sees in the graph that they have none. Run in this process, so that which
    nodes were waited for is seen, not timed."""
    from xrce.tools.ros_cli import cli, param

    waited = []
    wait = param._client
    monkeypatch.setattr(param, "_client", lambda node, name: waited.append(name) or wait(node, name))
    monkeypatch.setenv("ROS_DOMAIN_ID", str(graph.domain_id))
    no_parameters = "Wait for service timed out waiting for parameter services for node %s"
    expected = ["/%s:" % PARAM_NODE, "  gain", "  name", "  rate",
                "  start_type_description_service", "  use_sim_time",
                no_parameters % ("/" + BOARD_NODE), no_parameters % "/xrce_test_peer"]
    # A run before discovery found every node (any of the three, the board's included) is asked
    # again, as run_until does; what is asserted is the last run's output.
    for _ in range(6):
        waited.clear()
        assert cli.main(["param", "list"]) == 0
        lines = capsys.readouterr().out.splitlines()
        if set(expected) <= set(lines):
            break
    assert waited == ["/" + PARAM_NODE], waited
    assert lines == expected, lines


# ----------------------------------------------------------------------------- action

def test_action_list_and_send_goal_on_an_rclpy_action_server(graph):
    # An rclpy ActionServer: a board-side one goes through the agent once its action bridging
    # lands, and this test then uses it.
    graph.run_until(["/fibonacci"], "action", "list", *SPIN)
    graph.run_until(["/fibonacci [test_msgs/action/Fibonacci]"], "action", "list", "-t", *SPIN)
    lines, _ = graph.run("action", "send_goal", "/fibonacci", "test_msgs/action/Fibonacci",
                         "{order: 5}", "--feedback")
    text = "\n".join(lines)
    assert lines[:3] == ["Waiting for an action server to become available...", "Sending goal:",
                         "     order: 5"], lines
    assert re.search(r"^Goal accepted with ID: [0-9a-f]{32}$", text, re.M), text
    assert "Result:\n    sequence:\n- 0\n- 1\n- 1\n- 2\n- 3\n- 5\n" in text, text
    assert lines[-1] == "Goal finished with status: SUCCEEDED"


# ----------------------------------------------------------------------------- bad arguments

@pytest.mark.parametrize("args, says", [
    (["topic", "pub", "/x", "std_msgs/msg/Nope"], "The passed message type is invalid"),
    (["topic", "pub", "/x", "std_msgs/msg/String", "[1, 2]"], "needs to be a dictionary"),
    (["topic", "pub", "/x", "std_msgs/msg/String", "{nope: 1}"], "Failed to populate field"),
    (["topic", "hz", "/x", "-w", "0"], "value must be a positive integer"),
    (["service", "call", "/x", "std_msgs/msg/String"], "The passed service type is invalid"),
    (["action", "send_goal", "/x", "test_msgs/action/Nope"], "The passed action type is invalid"),
    (["node", "list", "--spin-time", "-1"], "value must be positive"),
    (["topic", "pub", "-n", "bad-node", "/x", "std_msgs/msg/String"], "Invalid node name"),
    (["topic", "echo", "bad topic", "std_msgs/msg/String"], "Invalid topic name"),
])
def test_a_bad_argument_gets_one_line_and_exit_2(args, says):
    done = subprocess.run(xrce_ros_command() + args, cwd=REPO, text=True, capture_output=True,
                          timeout=CLI_TIMEOUT_S)
    assert done.returncode == 2, done
    assert done.stdout == "" and done.stderr.count("\n") == 1, done.stderr
    assert done.stderr.startswith("xrce-ros: error: ") and says in done.stderr, done.stderr


@pytest.mark.parametrize("args, usage", [([], "usage: xrce-ros [-h] COMMAND ..."),
                                         (["topic"], "usage: xrce-ros topic [-h] VERB ...")])
def test_a_command_without_its_verb_prints_its_help_as_ros2_does(args, usage):
    done = subprocess.run(xrce_ros_command() + args, cwd=REPO, text=True, capture_output=True,
                          timeout=CLI_TIMEOUT_S)
    assert (done.returncode, done.stderr) == (0, ""), done
    assert done.stdout.splitlines()[0] == usage, done.stdout
    assert "    info      Print information about a topic" in done.stdout or args == []


# ----------------------------------------------------------------------------- interface show

def test_interface_show_prints_the_definition_and_nested_ones_as_ros2_does():
    # ros2 interface show: the file as written; each nested message below its field, a tab
    # deeper, without its comments and blank lines (--all-comments keeps them); --no-comments
    # drops them everywhere. The expected text is geometry_msgs' and std_msgs' own files.
    done = subprocess.run(xrce_ros_command() + ["interface", "show",
                                                "geometry_msgs/msg/PoseStamped"],
                          cwd=REPO, text=True, capture_output=True, timeout=CLI_TIMEOUT_S)
    assert done.returncode == 0, done
    assert done.stdout.splitlines() == [
        "# A Pose with reference coordinate frame and timestamp", "",
        "std_msgs/Header header", "\tbuiltin_interfaces/Time stamp", "\t\tint32 sec",
        "\t\tuint32 nanosec", "\tstring frame_id",
        "Pose pose", "\tPoint position", "\t\tfloat64 x", "\t\tfloat64 y", "\t\tfloat64 z",
        "\tQuaternion orientation", "\t\tfloat64 x 0", "\t\tfloat64 y 0", "\t\tfloat64 z 0",
        "\t\tfloat64 w 1"]
    all_comments = subprocess.run(
        xrce_ros_command() + ["interface", "show", "--all-comments", "std_msgs/msg/Header"],
        cwd=REPO, text=True, capture_output=True, timeout=CLI_TIMEOUT_S).stdout.splitlines()
    assert "\t# The seconds component, valid over all int32 values." in all_comments, all_comments
    piped = subprocess.run(xrce_ros_command() + ["interface", "show", "--no-comments", "-"],
                           input="test_msgs/action/Fibonacci\n", cwd=REPO, text=True,
                           capture_output=True, timeout=CLI_TIMEOUT_S)
    assert piped.stdout.splitlines() == ["int32 order", "---", "int32[] sequence", "---",
                                         "int32[] sequence"], piped
    for name, says in (("std_msgs/String", "Invalid name 'std_msgs/String'. Expected three "
                                           "parts separated by '/'"),
                       ("nowhere_msgs/msg/X", "Unknown package 'nowhere_msgs' (package nowhere_msgs is "
                                              "not built for this venv: `xrce-agent build-interfaces DIR "
                                              "--package nowhere_msgs`, DIR holding nowhere_msgs/ with its "
                                              "package.xml)")):
        done = subprocess.run(xrce_ros_command() + ["interface", "show", name], cwd=REPO,
                              text=True, capture_output=True, timeout=CLI_TIMEOUT_S)
        assert (done.returncode, done.stdout, done.stderr) == (1, "", says + "\n"), done


# ----------------------------------------------------------------------------- banners

def test_banners_name_the_ros2_command_that_exists(tmp_path):
    from xrce.tools.ros_cli import ros2_command

    venv_bin = os.path.dirname(sys.executable)
    ours = os.path.join(venv_bin, "xrce-ros")
    if not os.path.exists(ours):
        pytest.skip("SKIPPED LOUDLY: this venv has no xrce-ros script (pip install -e . again)")
    ros_bin = tmp_path / "ros" / "bin"
    ros_bin.mkdir(parents=True)
    (ros_bin / "ros2").write_text("#!/bin/sh\n")
    (ros_bin / "ros2").chmod(0o755)
    empty = tmp_path / "empty"
    empty.mkdir()
    # A ROS install's ros2 on PATH wins; else this venv's xrce-ros, by name when PATH finds it,
    # else by a path the user can type from where they are.
    assert ros2_command({"PATH": "%s:%s" % (ros_bin, venv_bin)}) == "ros2"
    assert ros2_command({"PATH": "%s:/usr/bin" % venv_bin}) == "xrce-ros"
    assert ros2_command({"PATH": str(empty)}, cwd=str(REPO)) == os.path.relpath(ours, REPO)
    assert ros2_command({"PATH": str(empty)}, cwd=str(empty)) == ours  # not below: the full path
