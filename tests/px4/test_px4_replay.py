"""Real PX4 traffic (tests/golden/px4/: PX4 v1.16.2 SITL's ``uxrce_dds_client`` talking to eProsima's
MicroXRCEAgent 2.4.3) replayed against a live ``xrce-agent`` that has no ``px4_msgs``: PX4's side is
sent as PX4 sent it (tests/helpers/px4_replay.py), and our agent must answer as eProsima's did: the same
STATUS (object and status code) for each of the 155 CREATEs of every boot, STATUS_AGENT, a
TIMESTAMP_REPLY for each of PX4's time-sync TIMESTAMPs, an INFO for each ping.

Into ROS (``-m dds``) an rclpy node does what px4_ros_com's examples do, with a trimmed px4_msgs
(tests/px4_interfaces) registered in this test process only: the agent moves PX4's CDR by type name,
as eProsima's does. It subscribes to ``/fmu/out/sensor_combined``, streams offboard setpoints,
commands DO_SET_MODE and ARM, and calls ``/fmu/vehicle_command``: a DATA for every READ_DATA
eProsima answered with one, carrying what the node sent, and PX4's recorded answer back to the
node. With two vehicles, ``/fmu/vehicle_command`` and ``/px4_1/fmu/vehicle_command`` each reach
their own vehicle; after a PX4 restart the second boot is accepted and streams into ROS again.
"""

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from agent_process import REPO, AgentProcess
from microros_replay import UdpChannel
from px4_replay import NAMES, REPLIER, Px4Capture, Px4Replayer
from ros_helpers import ros_domain, ros_peer, wait_until  # noqa: F401
from xrce.wire import constants as C

PX4_INTERFACES = Path(__file__).resolve().parents[1] / "px4_interfaces"
SENSOR_COMBINED_WRITER = 0x0D95  # PX4's datawriter of rt/fmu/out/sensor_combined
VEHICLE_COMMAND_READER = 0x8146  # PX4's datareader of rt/fmu/in/vehicle_command
DO_SET_MODE, ARM_DISARM, NAV_LAND = 176, 400, 21


def check_answers(capture: Px4Capture, ours) -> None:
    """Per boot and request id the STATUS eProsima sent, and its other answers by count."""
    theirs = capture.eprosima
    requests = {(boot, rid) for boot, rid, _ in capture.requests()}
    assert len(requests) >= 155 * capture.boots and requests <= set(theirs.statuses)
    mismatched = {"request %d (boot %d)" % (rid, boot):
                  (theirs.statuses[(boot, rid)], ours.statuses.get((boot, rid)))
                  for boot, rid in sorted(requests)
                  if ours.statuses.get((boot, rid)) != theirs.statuses[(boot, rid)]}
    assert not mismatched, "(object, status) eProsima vs ours: %r" % mismatched
    assert sorted(ours.status_agent) == sorted(theirs.status_agent) == \
        [(boot, C.STATUS_OK) for boot in range(capture.boots)]
    counted = lambda counts: {boot: n for boot, n in counts.items() if n}  # noqa: E731
    assert counted(ours.timestamp_replies) == counted(theirs.timestamp_replies)
    assert counted(ours.infos) == counted(theirs.infos)


@pytest.mark.timeout(120)
@pytest.mark.parametrize("name", NAMES)
def test_px4_capture_replayed_gets_eprosimas_answers(name):
    """Without ROS (``-m ced``): the protocol alone, PX4 paced on our answers as on eProsima's."""
    capture = Px4Capture(name)
    with AgentProcess("udp4", "-m", "ced", "-v", "0") as agent:
        channel = UdpChannel(agent.port)
        try:
            ours = Px4Replayer(capture, channel).run()
        finally:
            channel.close()
        assert agent.proc.poll() is None
    check_answers(capture, ours)


# ------------------------------------------------------------------------- with ROS (-m dds)

@pytest.fixture(scope="module")
def px4_msgs(tmp_path_factory):
    """The trimmed px4_msgs, built (a cache hit after the first time) and importable in this
    process only: registered in a site folder of the test's own, which no agent reads."""
    from xrce.agent import interfaces
    from xrce.agent.interfaces.registry import register

    results = interfaces.build([str(PX4_INTERFACES)], names=["px4_msgs"], register_results=False)
    register(results, site_dir=str(tmp_path_factory.mktemp("px4_msgs_site")))
    import px4_msgs.msg
    import px4_msgs.srv

    return px4_msgs


def assert_agent_has_no_px4_msgs():
    """What the agent's process would import: no px4_msgs (the venv's registry does not list it)."""
    probe = subprocess.run([sys.executable, "-c", "import px4_msgs"], cwd=REPO, env=dict(os.environ),
                           capture_output=True, text=True)
    assert probe.returncode != 0 and "px4_msgs" in probe.stderr, probe.stderr


def deserialize(cdr: bytes, message_type):
    """A PX4 sample (plain little-endian CDR, no encapsulation header) as a ROS message."""
    from rclpy.serialization import deserialize_message

    return deserialize_message(b"\x00\x01\x00\x00" + cdr, message_type)


def recorded_samples(capture: Px4Capture, writer: int, peer: int = 0) -> list:
    """The CDR of every sample PX4 wrote from ``writer`` (best effort, one WRITE_DATA each)."""
    return [bytes(body[4:]) for _index, sender, body in capture.submessages(C.WRITE_DATA)
            if sender == peer and ((body[2] << 8) | body[3]) == writer]


def command(px4_msgs, number, param1=0.0, param2=0.0, param3=0.0, target_system=1):
    return px4_msgs.msg.VehicleCommand(command=number, param1=param1, param2=param2, param3=param3,
                                       target_system=target_system, target_component=1,
                                       source_system=1, source_component=1, from_external=True)


class OffboardNode:
    """px4_ros_com's listener and offboard_control examples in one rclpy node: a best-effort
    /fmu/out/sensor_combined subscriber, OffboardControlMode + TrajectorySetpoint at 10 Hz, then
    DO_SET_MODE(1, 6) and ARM on /fmu/in/vehicle_command, then a NAV_LAND call of the
    /fmu/vehicle_command service."""

    def __init__(self, node, px4_msgs, prefix=""):
        """``prefix``: the namespace the agent gives PX4 (``--ros-args -r __ns:=/px4_2``)."""
        from rclpy.qos import qos_profile_sensor_data

        self.node, self.px4_msgs, self.prefix = node, px4_msgs, prefix
        msg = px4_msgs.msg
        self.sensor_combined = []
        node.create_subscription(msg.SensorCombined, prefix + "/fmu/out/sensor_combined",
                                 self.sensor_combined.append, qos_profile_sensor_data)
        self.offboard_mode = node.create_publisher(msg.OffboardControlMode,
                                                   prefix + "/fmu/in/offboard_control_mode", 10)
        self.setpoint = node.create_publisher(msg.TrajectorySetpoint,
                                              prefix + "/fmu/in/trajectory_setpoint", 10)
        self.vehicle_command = node.create_publisher(msg.VehicleCommand,
                                                     prefix + "/fmu/in/vehicle_command", 10)
        self.client = node.create_client(px4_msgs.srv.VehicleCommand, prefix + "/fmu/vehicle_command")
        self.commands = [command(px4_msgs, DO_SET_MODE, 1.0, 6.0), command(px4_msgs, ARM_DISARM, 1.0)]
        self.response = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="px4-offboard-node", daemon=True)

    def graph(self) -> dict:
        """What the node sees of PX4's entities it uses."""
        node, prefix = self.node, self.prefix
        seen = {prefix + "/fmu/out/sensor_combined":
                node.count_publishers(prefix + "/fmu/out/sensor_combined")}
        for topic in ("/fmu/in/offboard_control_mode", "/fmu/in/trajectory_setpoint",
                      "/fmu/in/vehicle_command"):
            seen[prefix + topic] = node.count_subscribers(prefix + topic)
        seen[prefix + "/fmu/vehicle_command"] = self.client.service_is_ready()
        seen["services"] = node.get_service_names_and_types()
        return seen

    def ready(self) -> bool:
        seen = self.graph()
        del seen["services"]
        return all(seen.values())

    def start(self):
        self._thread.start()

    def _run(self):
        msg = self.px4_msgs.msg
        count = 0
        while not self._stop.wait(0.1):
            count += 1
            stamp = count * 100_000
            self.offboard_mode.publish(msg.OffboardControlMode(timestamp=stamp, position=True))
            self.setpoint.publish(msg.TrajectorySetpoint(timestamp=stamp, position=[0.0, 0.0, -5.0],
                                                         yaw=-3.14))
            if count == 10:
                for vehicle_command in self.commands:
                    self.vehicle_command.publish(vehicle_command)
            if count == 12:
                request = self.px4_msgs.srv.VehicleCommand.Request(
                    request=command(self.px4_msgs, NAV_LAND))
                self.client.call_async(request).add_done_callback(
                    lambda future: setattr(self, "response", future.result()))

    def close(self):
        self._stop.set()
        if self._thread.ident is not None:  # started
            self._thread.join(2)


@pytest.mark.timeout(240)
def test_px4_main_replayed_into_ros_without_px4_msgs(px4_msgs, ros_peer, ros_domain):  # noqa: F811
    capture = Px4Capture("px4_main")
    offboard = OffboardNode(ros_peer.node, px4_msgs)
    first_sample = capture.step_of_first(C.WRITE_DATA)
    assert_agent_has_no_px4_msgs()
    with AgentProcess("udp4", "-m", "dds", "-v", "0") as agent:
        channel = UdpChannel(agent.port)
        try:
            replay = Px4Replayer(capture, channel, domain_id=ros_domain, answer_requests=True)
            replay.run(until_step=first_sample)
            assert wait_until(offboard.ready, 30), offboard.graph()
            offboard.start()
            ours = replay.run(start_step=first_sample, speed=2.0)
        finally:
            offboard.close()
            channel.close()
        assert agent.proc.poll() is None
    check_answers(capture, ours)
    # A DATA for each READ_DATA eProsima answered with one: offboard_control_mode,
    # trajectory_setpoint, vehicle_command and the replier.
    reads = capture.read_requests()
    answered = sorted(key for key in capture.eprosima.data)
    assert [reads[key] for key in answered] == [0x8096, 0x80F6, VEHICLE_COMMAND_READER, REPLIER]
    assert all(ours.data.get(key) for key in answered), (answered, dict(ours.data))
    # PX4 gets the node's commands as the node sent them (raw CDR through the agent).
    got = [deserialize(sample, px4_msgs.msg.VehicleCommand)
           for sample in ours.samples[(0, VEHICLE_COMMAND_READER)]]
    assert [(c.command, c.param1, c.param2, c.target_system) for c in got] == \
        [(c.command, c.param1, c.param2, c.target_system) for c in offboard.commands]
    request = deserialize(ours.samples[(0, REPLIER)][0][24:], px4_msgs.msg.VehicleCommand)
    assert (request.command, request.target_system) == (NAV_LAND, 1)
    # ... and the node gets PX4's: its recorded answer to the service call, its sensor samples.
    assert wait_until(lambda: offboard.response is not None, 30)
    assert (offboard.response.reply.command, offboard.response.reply.result) == (NAV_LAND, 0)
    recorded = {deserialize(cdr, px4_msgs.msg.SensorCombined).timestamp
                for cdr in recorded_samples(capture, SENSOR_COMBINED_WRITER)}
    assert len(offboard.sensor_combined) >= 100
    assert {m.timestamp for m in offboard.sensor_combined} <= recorded


@pytest.mark.timeout(240)
def test_px4_behind_an_agent_namespace(px4_msgs, ros_peer, ros_domain):  # noqa: F811
    """Issue 53: the unchanged PX4 traffic behind ``--ros-args -r __ns:=/px4_2`` publishes
    ``/px4_2/fmu/out/...``, obeys ``/px4_2/fmu/in/...`` and answers ``/px4_2/fmu/vehicle_command``;
    nothing of it is left on PX4's own ``/fmu/...`` names."""
    capture = Px4Capture("px4_main")
    offboard = OffboardNode(ros_peer.node, px4_msgs, prefix="/px4_2")
    first_sample = capture.step_of_first(C.WRITE_DATA)
    with AgentProcess("udp4", "-m", "dds", "-v", "0", "--ros-args", "-r", "__ns:=/px4_2",
                      "--") as agent:
        channel = UdpChannel(agent.port)
        try:
            replay = Px4Replayer(capture, channel, domain_id=ros_domain, answer_requests=True)
            replay.run(until_step=first_sample)
            assert wait_until(offboard.ready, 30), offboard.graph()
            names = [name for name, _ in ros_peer.node.get_topic_names_and_types()]
            assert not [n for n in names if n.startswith("/fmu/")], names
            offboard.start()
            ours = replay.run(start_step=first_sample, speed=2.0)
        finally:
            offboard.close()
            channel.close()
        assert agent.proc.poll() is None
    check_answers(capture, ours)
    got = [deserialize(sample, px4_msgs.msg.VehicleCommand)
           for sample in ours.samples[(0, VEHICLE_COMMAND_READER)]]
    assert [c.command for c in got] == [c.command for c in offboard.commands]
    assert wait_until(lambda: offboard.response is not None, 30)
    assert (offboard.response.reply.command, offboard.response.reply.result) == (NAV_LAND, 0)
    assert len(offboard.sensor_combined) >= 100


@pytest.mark.timeout(240)
def test_px4_two_vehicles_answer_their_own_services(px4_msgs, ros_peer, ros_domain):  # noqa: F811
    """px4_two: PX4 -i 0 and -i 1 (namespace px4_1) on one agent. Each vehicle's service is its
    own ROS service, named as eProsima's agent names it (after PX4's request/reply topics), and a
    call to one reaches that vehicle only: the replay answers a request only with the vehicle
    (peer) it was delivered to, with that vehicle's recorded reply."""
    capture = Px4Capture("px4_two")
    services = {0: "/fmu/vehicle_command", 1: "/px4_1/fmu/vehicle_command"}
    node = ros_peer.node
    clients = {peer: node.create_client(px4_msgs.srv.VehicleCommand, name)
               for peer, name in services.items()}
    first_reply = min(capture.replier_reply_steps())
    assert_agent_has_no_px4_msgs()
    responses = {}
    with AgentProcess("udp4", "-m", "dds", "-v", "0") as agent:
        channel = UdpChannel(agent.port)
        try:
            replay = Px4Replayer(capture, channel, domain_id=ros_domain, answer_requests=True)
            replay.run(until_step=first_reply)
            assert wait_until(lambda: all(c.service_is_ready() for c in clients.values()), 30), \
                (node.get_service_names_and_types(), replay.answers.statuses)
            listed = dict(node.get_service_names_and_types())
            assert all(listed.get(name) == ["px4_msgs/srv/VehicleCommand"]
                       for name in services.values()), listed
            assert "/vehicle_command" not in listed, listed
            for peer, client in clients.items():
                # DO_SET_MODE(1, 4, 3): AUTO LOITER, what the recording's node asked each vehicle.
                request = px4_msgs.srv.VehicleCommand.Request(request=command(
                    px4_msgs, DO_SET_MODE, 1.0, 4.0, 3.0, target_system=peer + 1))
                client.call_async(request).add_done_callback(
                    lambda future, peer=peer: responses.__setitem__(peer, future.result()))
            ours = replay.run(start_step=first_reply, speed=2.0)
            assert wait_until(lambda: len(responses) == 2, 30), responses
        finally:
            channel.close()
        assert agent.proc.poll() is None
    check_answers(capture, ours)
    for peer in services:
        # One request reached each vehicle, the one addressed to it.
        delivered = [deserialize(sample[24:], px4_msgs.msg.VehicleCommand)
                     for sample in ours.samples[(peer, REPLIER)]]
        assert [(c.command, c.target_system) for c in delivered] == [(DO_SET_MODE, peer + 1)]
        reply = next(bytes(body[28:]) for _index, sender, body in capture.submessages(C.WRITE_DATA)
                     if sender == peer and ((body[2] << 8) | body[3]) == REPLIER)
        recorded = deserialize(reply, px4_msgs.msg.VehicleCommandAck)
        got = responses[peer].reply
        assert (got.command, got.result, got.target_system, got.timestamp) == \
            (recorded.command, recorded.result, recorded.target_system, recorded.timestamp)


@pytest.mark.timeout(240)
def test_px4_restart_second_boot_accepted_into_ros(px4_msgs, ros_peer, ros_domain):  # noqa: F811
    """px4_restart: PX4 killed, started again with the same key from a new port. Every STATUS of
    both boots as eProsima's (OK), and the second boot's samples reach ROS through one writer."""
    from rclpy.qos import qos_profile_sensor_data

    capture = Px4Capture("px4_restart")
    node = ros_peer.node
    samples = []
    node.create_subscription(px4_msgs.msg.SensorCombined, "/fmu/out/sensor_combined",
                             samples.append, qos_profile_sensor_data)
    second_boot = capture.step_of_first(C.WRITE_DATA, peer=1)
    assert_agent_has_no_px4_msgs()
    with AgentProcess("udp4", "-m", "dds", "-v", "0") as agent:
        channel = UdpChannel(agent.port)
        try:
            replay = Px4Replayer(capture, channel, domain_id=ros_domain)
            replay.run(until_step=second_boot)
            assert wait_until(lambda: node.count_publishers("/fmu/out/sensor_combined") == 1, 30), \
                node.count_publishers("/fmu/out/sensor_combined")
            before = len(samples)  # the first boot's
            ours = replay.run(start_step=second_boot, speed=2.0)
        finally:
            channel.close()
        assert node.count_publishers("/fmu/out/sensor_combined") == 1
        assert agent.proc.poll() is None
    check_answers(capture, ours)
    second = {deserialize(cdr, px4_msgs.msg.SensorCombined).timestamp
              for cdr in recorded_samples(capture, SENSOR_COMBINED_WRITER, peer=1)}
    assert len(samples) - before >= 100
    assert {m.timestamp for m in samples[before:]} <= second
