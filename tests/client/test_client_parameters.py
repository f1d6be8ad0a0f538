"""The client's parameter server (xrce.client.parameters).

Against rclc: the entities it creates and the replies and /parameter_events samples it writes for the
requests rclpy sent rclc's parameter server in tests/golden/microros/actions_params.jsonl, through a
real client session whose transport records what it sends. End to end: under real MicroPython
(tests/helpers/mp_harness.py) through a live ``xrce-agent -m dds``, driven by rclpy's parameter client.
"""

import re
import threading
from pathlib import Path

import pytest

from client_capture import RclcCapture
from client_recorder import RecordingSession
from xrce.client.parameters import ParameterServer
from xrce.msgs import rcl_interfaces

SERVICES = ("get_parameters", "get_parameter_types", "set_parameters", "set_parameters_atomically",
            "list_parameters", "describe_parameters")


@pytest.fixture(scope="module")
def rclc():
    return RclcCapture()


def _as_rclc(recorder=None, **kwargs):
    # The capture's firmware: node /mcu/feat_fw with p_int 7, p_double 0.5, p_bool true.
    recorder = recorder or RecordingSession()
    node = recorder.session.create_participant(name="/mcu/feat_fw")
    params = ParameterServer(recorder.session, node, "/mcu/feat_fw", **kwargs)
    params.declare("p_int", 7)
    params.declare("p_double", 0.5)
    params.declare("p_bool", True)
    return recorder, params


def _texts(body):
    return [t.decode() for t in re.findall(rb"[ -~]{4,}", body[1:])]


def test_entities_are_rclcs(rclc):
    recorder = RecordingSession()
    recorder.session.create_participant(name="/mcu/feat_fw")
    recorder.take()
    ParameterServer(recorder.session, 1, "/mcu/feat_fw")
    created = recorder.creations()
    ours = [_texts(body) for oid, body in created if body[0] == 8]
    theirs = [rclc.entities[rclc.replier("/mcu/feat_fw/" + name)][1] for name in SERVICES]
    assert sorted(ours) == sorted(theirs)
    # /parameter_events: topic and type, and the datawriter's QoS (reliable, keep-last 1000); the
    # representations differ only in rclc's uninitialised alignment byte after has-depth (and in
    # the parent publisher's id).
    topic = [body for oid, body in created if body[0] == 2]
    assert _texts(topic[0]) == ["rt/parameter_events", "rcl_interfaces::msg::dds_::ParameterEvent_"]
    ours_writer = [body for oid, body in created if body[0] == 5][0]
    theirs_writer = rclc.writer_of("rt/parameter_events")[1]
    masked = lambda body: body[10:15] + body[16:-2]  # noqa: E731  (past the topic id; byte 15 is garbage)
    assert masked(ours_writer) == masked(theirs_writer)


def _decoded(cls, body):
    return cls.from_bytes(body).to_dict() if body is not None else None


@pytest.mark.parametrize("service,srv", [("list_parameters", rcl_interfaces.ListParameters),
                                         ("get_parameters", rcl_interfaces.GetParameters),
                                         ("set_parameters", rcl_interfaces.SetParameters)])
def test_replies_are_rclcs(rclc, service, srv):
    # rclpy's list, get, set (42, 2.5, false) and get again, replayed in the capture's order: each
    # reply decodes to what rclc answered.
    recorder, params = _as_rclc()
    recorder.take()
    replier = params.repliers[SERVICES.index(service)]
    order = ("list_parameters", "get_parameters", "set_parameters")
    exchanges = {name: rclc.exchanges("/mcu/feat_fw/" + name) for name in order}
    assert all(exchanges.values())
    # The set happens between the two gets: apply it first where the service asked comes later.
    if service == "get_parameters":
        first, second = exchanges["get_parameters"]
        assert _decoded(srv.Response, recorder.serve(replier, b"\x01" * 24, first[0])) == \
            _decoded(srv.Response, first[1])
        set_request, _ = exchanges["set_parameters"][0]
        recorder.serve(params.repliers[2], b"\x02" * 24, set_request)
        assert _decoded(srv.Response, recorder.serve(replier, b"\x03" * 24, second[0])) == \
            _decoded(srv.Response, second[1])
        return
    for request, reply in exchanges[service]:
        assert _decoded(srv.Response, recorder.serve(replier, b"\x04" * 24, request)) == \
            _decoded(srv.Response, reply)


def test_parameter_events_are_rclcs(rclc):
    # One event per declared parameter, then one per parameter set; the node by its base name.
    recorder = RecordingSession()
    _, params = _as_rclc(recorder)
    writer_id = params.events_writer
    set_request, _ = rclc.exchanges("/mcu/feat_fw/set_parameters")[0]
    declared = [body for oid, body in recorder.writes() if oid == writer_id]
    recorder.serve(params.repliers[2], b"\x05" * 24, set_request)
    changed = [body for oid, body in recorder.last_writes if oid == writer_id]
    theirs = rclc.writes[rclc.writer_of("rt/parameter_events")[0]]

    def unstamped(body):
        event = rcl_interfaces.ParameterEvent.from_bytes(body).to_dict()
        assert event.pop("stamp")["sec"] > 1_600_000_000  # wall-clock time, as rclc's
        return event

    def kinds(event, field):
        return [(p["name"], p["value"]["type"]) for p in event[field]]

    ours = [unstamped(b) for b in declared + changed]
    theirs = [unstamped(b) for b in theirs]
    assert len(ours) == 6 and len(theirs) == 9
    assert all(event["node"] == "feat_fw" for event in ours + theirs)
    # rclc's firmware adds each parameter (an event with the value still 0) and then sets its
    # default (a second event); a declaration here is one event that carries the default. Same
    # names, types and values.
    assert [kinds(e, "new_parameters") for e in ours[:3]] == [kinds(e, "new_parameters") for e in theirs[:3]]
    assert [e["new_parameters"] for e in ours[:3]] == [e["changed_parameters"] for e in theirs[3:6]]
    assert ours[3:] == theirs[6:]


def _serve(params, recorder, index, request):
    srv = (rcl_interfaces.GetParameters, rcl_interfaces.GetParameterTypes, rcl_interfaces.SetParameters,
           rcl_interfaces.SetParametersAtomically, rcl_interfaces.ListParameters,
           rcl_interfaces.DescribeParameters)[index]
    recorder.take()
    return srv.Response.from_bytes(recorder.serve(params.repliers[index], b"\x06" * 24, request.to_bytes()))


def _parameter(name, kind, **value):
    return rcl_interfaces.Parameter(name=name, value=rcl_interfaces.ParameterValue(type=kind, **value))


def test_refusals_carry_their_reasons():
    seen = []

    def on_change(name, value):
        seen.append((name, value))
        if name == "gain" and value > 100:
            return "gain above 100 would saturate the motor"
        return name != "mode" or value != "off"  # False: rclc's plain refusal

    recorder, params = _as_rclc(on_change=on_change)
    params.declare("gain", 10, min_value=0, max_value=1000)
    params.declare("ratio", 0.5, min_value=0.0, max_value=1.0)
    params.declare("serial", "tb3-0042", read_only=True)
    params.declare("mode", "auto")
    request = rcl_interfaces.SetParameters.Request(parameters=[
        _parameter("gain", 2, integer_value=500),
        _parameter("gain", 3, double_value=5.0),
        _parameter("ratio", 3, double_value=1.5),
        _parameter("serial", 4, string_value="x"),
        _parameter("nope", 1, bool_value=True),
        _parameter("mode", 4, string_value="off"),
        _parameter("mode", 4, string_value="manual"),
        _parameter("gain", 2, integer_value=50),
    ])
    results = _serve(params, recorder, 2, request).results
    assert [(r.successful, r.reason) for r in results] == [
        (False, "gain above 100 would saturate the motor"), (False, "Type mismatch"),
        (False, "Value out of range"), (False, "Read only parameter"), (False, "Parameter not found"),
        (False, "Rejected by server"), (True, ""), (True, "")]
    assert params["gain"] == 50 and params["mode"] == "manual" and params["serial"] == "tb3-0042"
    assert ("gain", 5.0) not in seen  # a mistyped value never reaches the callback

    # All or nothing: one refusal leaves every parameter as it was.
    atomic = rcl_interfaces.SetParametersAtomically.Request(parameters=[
        _parameter("gain", 2, integer_value=60), _parameter("ratio", 3, double_value=7.0)])
    result = _serve(params, recorder, 3, atomic).result
    assert (result.successful, result.reason) == (False, "ratio: Value out of range")
    assert params["gain"] == 50
    atomic.parameters[1].value.double_value = 0.25
    assert _serve(params, recorder, 3, atomic).result.successful
    assert (params["gain"], params["ratio"]) == (60, 0.25)

    described = _serve(params, recorder, 5, rcl_interfaces.DescribeParameters.Request(
        names=["gain", "ratio", "serial", "nope"])).descriptors
    assert [(d.name, d.type, d.read_only) for d in described] == [
        ("gain", 2, False), ("ratio", 3, False), ("serial", 4, True), ("nope", 0, False)]
    assert (described[0].integer_range[0].from_value, described[0].integer_range[0].to_value) == (0, 1000)
    assert described[1].floating_point_range[0].to_value == 1.0
    types = _serve(params, recorder, 1, rcl_interfaces.GetParameterTypes.Request(names=["mode", "p_bool", "x"]))
    assert list(types.types) == [4, 1, 0]


def test_bounds():
    recorder, params = _as_rclc(max_params=4)
    params.declare("extra", 1)
    with pytest.raises(ValueError):
        params.declare("one_too_many", 1)
    with pytest.raises(ValueError):
        params.declare("p_int", 3)
    # A request naming more parameters than the server holds is answered empty, as rclc does.
    many = rcl_interfaces.GetParameters.Request(names=["p_int"] * 5)
    assert list(_serve(params, recorder, 0, many).values) == []
    listed = _serve(params, recorder, 4, rcl_interfaces.ListParameters.Request(prefixes=["p_int"]))
    assert list(listed.result.names) == ["p_int"]


# ---------------------------------------------------------------------------- end to end

from agent_process import AgentProcess  # noqa: E402
from mp_harness import run_micropython  # noqa: E402
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: E402,F401

BOARD = Path(__file__).resolve().parents[1] / "micropython" / "params_board.py"


def _wait(future, seconds=15.0):
    assert wait_until(future.done, seconds), "no answer from the board"
    return future.result()


@pytest.mark.timeout(180)
def test_ros_parameter_client_against_the_board_under_micropython(ros_peer, ros_domain):  # noqa: F811
    from rcl_interfaces.msg import ParameterEvent, ParameterType
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    node = ros_peer.node
    events = []
    node.create_subscription(ParameterEvent, "/parameter_events",
                             lambda e: events.append(e) if e.node == "tb3_params" else None,
                             QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    client = AsyncParameterClient(node, "/tb3_params")
    with AgentProcess("udp4", "-m", "dds") as agent:
        result = {}
        runner = threading.Thread(target=lambda: result.setdefault(
            "run", run_micropython(BOARD, agent.port, ros_domain, 90, timeout=150)), daemon=True)
        runner.start()
        try:
            assert client.wait_for_services(60), "the board's parameter services never appeared"
            listed = _wait(client.list_parameters())
            assert sorted(listed.result.names) == ["done", "motor_kp", "robot_name", "use_imu",
                                                   "wheel_radius"]
            values = _wait(client.get_parameters(["motor_kp", "wheel_radius", "use_imu", "robot_name"])).values
            assert [(v.type, v.integer_value, v.double_value, v.bool_value, v.string_value) for v in values] == [
                (ParameterType.PARAMETER_INTEGER, 120, 0.0, False, ""),
                (ParameterType.PARAMETER_DOUBLE, 0, 0.033, False, ""),
                (ParameterType.PARAMETER_BOOL, 0, 0.0, True, ""),
                (ParameterType.PARAMETER_STRING, 0, 0.0, False, "tb3-0042")]
            described = _wait(client.describe_parameters(["motor_kp", "robot_name"])).descriptors
            assert (described[0].description, described[0].integer_range[0].to_value) == ("wheel PID gain", 1000)
            assert described[1].read_only and described[1].type == ParameterType.PARAMETER_STRING
            results = _wait(client.set_parameters([
                Parameter("motor_kp", value=150), Parameter("wheel_radius", value=0.035),
                Parameter("motor_kp", value=900), Parameter("robot_name", value="x"),
                Parameter("use_imu", value=3)])).results
            assert [(r.successful, r.reason) for r in results] == [
                (True, ""), (True, ""), (False, "motor_kp above 500 saturates the driver"),
                (False, "Read only parameter"), (False, "Type mismatch")]
            after = _wait(client.get_parameters(["motor_kp", "wheel_radius"])).values
            assert (after[0].integer_value, after[1].double_value) == (150, 0.035)
            assert wait_until(lambda: len([e for e in events if e.changed_parameters]) >= 2, 15)
            changed = [(p.name, p.value.integer_value or p.value.double_value)
                       for e in events for p in e.changed_parameters]
            assert changed == [("motor_kp", 150), ("wheel_radius", 0.035)]
            _wait(client.set_parameters([Parameter("done", value=True)]))
        finally:
            runner.join(120)
    run = result["run"]
    assert run.returncode == 0, run.stdout + run.stderr
    lines = dict(line.split(" ", 1) for line in run.stdout.splitlines() if " " in line)
    assert lines["connect"] == lines["setup"] == lines["done"] == "True", run.stdout
    assert (lines["motor_kp"], lines["wheel_radius"], lines["use_imu"]) == ("150", "0.035", "True")
    # on_change saw the accepted and the rejected sets, never the read-only or mistyped ones.
    assert lines["changes"] == "motor_kp,wheel_radius,motor_kp,done", lines["changes"]
