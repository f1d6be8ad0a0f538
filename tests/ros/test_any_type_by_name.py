"""Types the agent knows only by name, and service names as eProsima's agent derives them (issue 37).

PX4 names px4_msgs types, which eProsima's agent carries by name without the package. Here a small
interface package (``xrce_byname_msgs``) is built for the ROS node's side only, into a directory of
its own that the node reaches through PYTHONPATH/LD_LIBRARY_PATH: never registered, so the agent
(another process, without those variables) has it nowhere. XRCE clients speak its types as raw CDR
through binary-created entities, as PX4 does: topics both ways, a replier that a ROS client calls
(PX4's vehicle_command, once per "vehicle", the second namespaced as PX4's ``-i 1`` does) and a
requester that calls a ROS service.
"""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
import threading
import time

import pytest

from agent_process import AgentProcess
from ros_helpers import ros_domain  # noqa: F401
from xrce.client.session import Session
from xrce.transports.udp import UdpTransport

PACKAGE = "xrce_byname_msgs"
READING = PACKAGE + "::msg::dds_::Reading_"
COMMAND_REQUEST = PACKAGE + "::srv::dds_::Command_Request_"
COMMAND_RESPONSE = PACKAGE + "::srv::dds_::Command_Response_"

PACKAGE_XML = """<?xml version="1.0"?>
<package format="3">
  <name>xrce_byname_msgs</name>
  <version>0.0.1</version>
  <description>A package only the ROS node of tests/ros/test_any_type_by_name.py has.</description>
  <maintainer email="xrce@example.invalid">xrce project</maintainer>
  <license>Apache-2.0</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
"""
CMAKE_LISTS = """cmake_minimum_required(VERSION 3.8)
project(xrce_byname_msgs)
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
rosidl_generate_interfaces(${PROJECT_NAME} "msg/Reading.msg" "srv/Command.srv")
ament_export_dependencies(rosidl_default_runtime)
ament_package()
"""
# Every alignment CDR has: a byte, an 8-byte float after padding, a string, a sequence.
READING_MSG = "uint8 flag\nfloat64 value\nstring label\nint32[] counts\n"
COMMAND_SRV = "uint32 command\nfloat32 param1\nstring note\n---\nuint8 result\nstring text\n"


@pytest.fixture(scope="module")
def node_side_env(tmp_path_factory):
    """Environment variables under which a Python of this venv imports xrce_byname_msgs; the
    package is built once for the module (about 25 s) and registered nowhere."""
    from xrce.agent.interfaces.builder import build

    root = tmp_path_factory.mktemp("byname")
    source = root / "src" / PACKAGE
    (source / "msg").mkdir(parents=True)
    (source / "srv").mkdir()
    (source / "package.xml").write_text(PACKAGE_XML)
    (source / "CMakeLists.txt").write_text(CMAKE_LISTS)
    (source / "msg" / "Reading.msg").write_text(READING_MSG)
    (source / "srv" / "Command.srv").write_text(COMMAND_SRV)
    [result] = build([str(root / "src")], cache_root=str(root / "cache"), names=[PACKAGE],
                     register_results=False)
    site = os.path.join(result.prefix, "lib", "python%d.%d" % sys.version_info[:2], "site-packages")
    return {"PYTHONPATH": site, "LD_LIBRARY_PATH": os.path.join(result.prefix, "lib")}


def with_node_side(env: dict, node_side: dict) -> dict:
    """``env`` with the package's directories before what the variables already hold."""
    env = dict(env)
    for name, value in node_side.items():
        env[name] = os.pathsep.join([value] + ([env[name]] if env.get(name) else []))
    return env


def encode_reading(flag: int, value: float, label: str, counts) -> bytes:
    out = bytearray(struct.pack("<B7xd", flag, value))
    text = label.encode() + b"\0"
    out += struct.pack("<I", len(text)) + text
    out += bytes(-len(out) % 4)
    out += struct.pack("<I%di" % len(counts), len(counts), *counts)
    return bytes(out)


def decode_reading(cdr: bytes):
    flag, value, length = struct.unpack_from("<B7xdI", cdr)
    label = cdr[20:20 + length - 1].decode()
    at = 20 + length + (-(20 + length) % 4)
    count, = struct.unpack_from("<I", cdr, at)
    return flag, value, label, list(struct.unpack_from("<%di" % count, cdr, at + 4))


def encode_request(command: int, param1: float, note: str) -> bytes:
    text = note.encode() + b"\0"
    return struct.pack("<IfI", command, param1, len(text)) + text


def decode_request(cdr: bytes):
    command, param1, length = struct.unpack_from("<IfI", cdr)
    return command, param1, cdr[12:12 + length - 1].decode()


def encode_response(result: int, text: str) -> bytes:
    raw = text.encode() + b"\0"
    return struct.pack("<B3xI", result, len(raw)) + raw


def decode_response(cdr: bytes):
    result, length = struct.unpack_from("<B3xI", cdr)
    return result, cdr[8:8 + length - 1].decode()


# The ROS node that has the package: what it does and sees, one line each on stdout.
NODE_SCRIPT = r"""
import rclpy
import rclpy.executors
from rclpy.node import Node
from xrce_byname_msgs.msg import Reading
from xrce_byname_msgs.srv import Command

rclpy.init()
node = Node("byname_peer")
done = set()

def up(msg):
    if "up" not in done:
        print("up", msg.flag, msg.value, msg.label, list(msg.counts), flush=True)
        done.add("up")

def serve(request, response):
    if "served" not in done:
        print("served", request.command, round(request.param1, 3), request.note, flush=True)
    response.result = request.command % 256
    response.text = "node did " + request.note
    done.add("served")
    return response

node.create_subscription(Reading, "/byname/up", up, 10)
down = node.create_publisher(Reading, "/byname/down", 10)
node.create_service(Command, "/node_side/command", serve)
vehicles = {name: node.create_client(Command, name)
            for name in ("/fmu/byname_command", "/px4_1/fmu/byname_command")}
calls = {}
timer_ticks = [0]

def tick():
    down.publish(Reading(flag=7, value=-2.25, label="down", counts=[5, -6, 7]))
    for name, client in vehicles.items():
        if name not in calls and client.service_is_ready():
            calls[name] = client.call_async(Command.Request(command=400 + len(calls),
                                                            param1=1.5, note=name))

node.create_timer(0.1, tick)
while True:
    try:
        rclpy.spin_once(node, timeout_sec=0.1)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        break
    for name, future in list(calls.items()):
        if future.done() and ("reply " + name) not in done:
            print("reply", name, future.result().result, future.result().text, flush=True)
            done.add("reply " + name)
    if len(done) == 4 and "graph" not in done:
        done.add("graph")
        services = dict(node.get_service_names_and_types())
        print("graph", services.get("/px4_1/fmu/byname_command"),
              services.get("/fmu/byname_command"), flush=True)
        info = node.get_publishers_info_by_topic("/byname/up")
        print("publisher", [(i.node_name, i.topic_type, str(i.topic_type_hash)) for i in info],
              flush=True)
        print("done", flush=True)
"""


class Vehicle:
    """One XRCE client (a PX4 instance): binary-created entities, raw CDR."""

    def __init__(self, port: int, domain: int, namespace: str, name: str):
        self.session = Session(UdpTransport("127.0.0.1", port), history=8)
        assert self.session.create(attempts=5, timeout_ms=1000)
        self.node = self.session.create_participant(domain_id=domain, name=name)
        prefix = namespace + "/fmu/byname_command"
        self.replier = self.session.create_replier(
            self.node, "byname_command", COMMAND_REQUEST, COMMAND_RESPONSE,
            "rq/%sRequest" % prefix.lstrip("/"), "rr/%sReply" % prefix.lstrip("/"))
        self.requests = []
        self.session.set_reader_callback(self.replier, self._request)
        self.session.read_data(self.replier, self.session.reliable)
        self.name = name

    def _request(self, identity, cdr):
        command, param1, note = decode_request(bytes(cdr))
        self.requests.append((command, param1, note))
        self.session.send_reply(self.replier, identity,
                                encode_response(command - 300, "%s did %s" % (self.name, note)))

    def close(self):
        self.session.delete(attempts=2, timeout_ms=500)
        self.session.close()


class _Lines:
    def __init__(self, proc):
        self.lines = []
        self._thread = threading.Thread(target=self._read, args=(proc,), daemon=True)
        self._thread.start()

    def _read(self, proc):
        for line in proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def starting(self, word):
        return [line for line in self.lines if line.split(" ", 1)[0] == word]


def test_a_type_no_package_on_the_agents_side_has_flows_both_ways(node_side_env, ros_domain):  # noqa: F811
    env = with_node_side(os.environ, node_side_env)
    with AgentProcess("udp4", "-m", "dds") as agent:
        peer = subprocess.Popen([sys.executable, "-c", NODE_SCRIPT], env=env, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        lines = _Lines(peer)
        vehicles = []
        try:
            vehicles = [Vehicle(agent.port, ros_domain, "", "px4_0"),
                        Vehicle(agent.port, ros_domain, "/px4_1", "px4_1")]
            session = vehicles[0].session
            topic = session.create_topic(vehicles[0].node, "rt/byname/up", READING)
            publisher = session.create_publisher(vehicles[0].node)
            writer = session.create_datawriter(publisher, topic)
            down_topic = session.create_topic(vehicles[0].node, "rt/byname/down", READING)
            subscriber = session.create_subscriber(vehicles[0].node)
            reader = session.create_datareader(subscriber, down_topic)
            downs = []
            session.set_reader_callback(reader, lambda cdr: downs.append(bytes(cdr)))
            session.read_data(reader, session.reliable)
            requester = session.create_requester(
                vehicles[0].node, "command", COMMAND_REQUEST, COMMAND_RESPONSE,
                "rq/node_side/commandRequest", "rr/node_side/commandReply")
            replies = []
            session.set_reader_callback(requester, lambda rid, cdr: replies.append(bytes(cdr)))
            session.read_data(requester, session.reliable)
            assert session.run_until_all_status(30000), session.last_statuses
            assert vehicles[1].session.run_until_all_status(30000), vehicles[1].session.last_statuses

            up = encode_reading(3, 1234.5, "up by name", [1, -2, 300000])
            deadline = time.monotonic() + 90
            asked = 0.0
            while peer.poll() is None and not lines.starting("done") and time.monotonic() < deadline:
                session.write(writer, up)
                if not replies and time.monotonic() - asked > 2:  # until the service is there
                    session.send_request(requester, encode_request(77, 0.25, "from the board"))
                    asked = time.monotonic()
                for vehicle in vehicles:
                    vehicle.session.run_until_timeout(100)
            assert lines.starting("done"), "\n".join(lines.lines)
            # The node's own sample reached the XRCE reader as the node's CDR.
            while not downs and time.monotonic() < deadline:
                session.run_until_timeout(100)
        finally:
            if peer.poll() is None:
                peer.send_signal(signal.SIGINT)
            peer.wait(timeout=20)
            for vehicle in vehicles:
                vehicle.close()
        assert agent.stop() == 0
    log = "".join(agent.output)
    output = "\n".join(lines.lines)
    assert lines.starting("up") == ["up 3 1234.5 up by name [1, -2, 300000]"], output
    assert decode_reading(downs[0]) == (7, -2.25, "down", [5, -6, 7])
    assert lines.starting("served") == ["served 77 0.25 from the board"], output
    assert decode_response(replies[0]) == (77, "node did from the board")
    # Each vehicle answers its own service, named after its request/reply topics.
    assert sorted(lines.starting("reply")) == [
        "reply /fmu/byname_command %d px4_0 did /fmu/byname_command" % (vehicles[0].requests[0][0] - 300),
        "reply /px4_1/fmu/byname_command %d px4_1 did /px4_1/fmu/byname_command"
        % (vehicles[1].requests[0][0] - 300)], output
    assert [r[2] for r in vehicles[0].requests] == ["/fmu/byname_command"]
    assert [r[2] for r in vehicles[1].requests] == ["/px4_1/fmu/byname_command"]
    assert lines.starting("graph") == ["graph ['xrce_byname_msgs/srv/Command'] "
                                       "['xrce_byname_msgs/srv/Command']"], output
    # The agent's publisher: the type by its ROS name, no type hash (rmw has none to announce).
    [publisher_line] = lines.starting("publisher")
    assert "'xrce_byname_msgs/msg/Reading'" in publisher_line and "INVALID" in publisher_line, \
        publisher_line
    assert log.count("no package %s on the agent's side: its types are carried by name"
                     % PACKAGE) == 1, log
    assert "Traceback" not in log and "overwritten" not in log, log


# --------------------------------------------------------------------- the service name rule

@pytest.mark.parametrize("service, request_topic, reply_topic, expected", [
    # PX4 v1.16: the service name is the bare "vehicle_command", the topics carry the namespace.
    ("vehicle_command", "rq/fmu/vehicle_commandRequest", "rr/fmu/vehicle_commandReply",
     "/fmu/vehicle_command"),
    ("vehicle_command", "rq/px4_1/fmu/vehicle_commandRequest", "rr/px4_1/fmu/vehicle_commandReply",
     "/px4_1/fmu/vehicle_command"),
    # micro-ROS (rmw_microxrcedds): service name and topics agree; parameters and actions too.
    ("/add_two_ints", "rq/add_two_intsRequest", "rr/add_two_intsReply", "/add_two_ints"),
    ("/mcu/feat_fw/get_parameters", "rq/mcu/feat_fw/get_parametersRequest",
     "rr/mcu/feat_fw/get_parametersReply", "/mcu/feat_fw/get_parameters"),
    ("/mcu/fibonacci/_action/send_goal", "rq/mcu/fibonacci/_action/send_goalRequest",
     "rr/mcu/fibonacci/_action/send_goalReply", "/mcu/fibonacci/_action/send_goal"),
    # One well-formed topic names the service alone.
    ("x", "rq/ns/oneRequest", None, "/ns/one"),
    ("x", None, "rr/ns/oneReply", "/ns/one"),
    ("x", "calc_Request", "rr/ns/oneReply", "/ns/one"),
    # No topic in ROS' form: the service name, as before.
    ("calc", "calc_Request", "calc_Reply", "/calc"),
    ("/basic", None, None, "/basic"),
    ("basic", "rq/bad name!Request", None, "/basic"),
])
def test_service_name_comes_from_the_request_and_reply_topics(service, request_topic, reply_topic,
                                                              expected):
    from xrce.agent.middleware.ros.types import service_ros_name

    assert service_ros_name(service, request_topic, reply_topic) == expected


def test_topics_of_two_services_are_refused():
    from xrce.agent.middleware import MiddlewareError
    from xrce.agent.middleware.ros.types import service_ros_name

    with pytest.raises(MiddlewareError, match="name two services"):
        service_ros_name("s", "rq/aRequest", "rr/bReply")
    with pytest.raises(MiddlewareError, match="neither a name nor"):
        service_ros_name("", None, "calc_Reply")


# ------------------------------------------------------------------------------ hostile names

BOUND_SCRIPT = r"""
import rclpy  # loads rcl and rmw, which the helper looks its functions up in
from xrce.agent.middleware.ros import _rostypes
made = [_rostypes.named_message_type("made_up_%d_msgs" % i, "msg", "T", True) for i in range(1100)]
kinds = [type(m).__name__ for m in made]
print(kinds.index("str"), kinds.count("PyCapsule"), made[-1])
print(_rostypes.named_service_type("one_more_srvs", "srv", "X", True))
"""


def test_types_known_by_name_are_bounded_per_process():
    """A client inventing type names makes at most 1024 type supports in the agent's process
    (a few hundred bytes each, kept: rmw holds pointers into them); past that, an error."""
    done = subprocess.run([sys.executable, "-c", BOUND_SCRIPT], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.splitlines() == ["1024 1024 1024 types known by name already",
                                        "1024 types known by name already"], done.stdout


def test_a_long_name_and_a_missing_helper_are_refused_with_what_is_missing(monkeypatch):
    from xrce.agent.middleware import UnknownTypeError
    from xrce.agent.middleware.ros import compiled, raw_types

    long_package = "p" * 250
    with pytest.raises(UnknownTypeError, match="at most 255"):
        raw_types.named_message_type(long_package + "::msg::dds_::T_", long_package, "msg", "T")
    # An install without the compiled helper (no C compiler when xrce was installed).
    monkeypatch.setitem(sys.modules, compiled.MODULE, None)
    monkeypatch.setattr(compiled, "_helper", compiled._UNSET)  # looked up again, and not found
    # Names no other test uses: a type made by name earlier in this process is cached, and the
    # cache answers before the helper is looked for (test_agent_ros_middleware makes nope_srvs').
    with pytest.raises(UnknownTypeError, match="helperless_msgs is not installed, and carrying a "
                                               "type known only by its name needs the agent's "
                                               "compiled helper"):
        raw_types.named_message_type("helperless_msgs::msg::dds_::SensorCombined_",
                                     "helperless_msgs", "msg", "SensorCombined")
    from xrce.agent.middleware import TypeNotReady

    try:  # the interface directories are listed once per run first (a child interpreter)
        raw_types.named_service_type("helperless_srvs::srv::dds_::X_Request_")
    except TypeNotReady as pending:
        pending.future.result(timeout=60)
    except UnknownTypeError:
        pass
    with pytest.raises(UnknownTypeError, match="compiled helper"):
        raw_types.named_service_type("helperless_srvs::srv::dds_::X_Request_")
