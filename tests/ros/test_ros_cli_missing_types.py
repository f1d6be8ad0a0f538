"""``xrce-ros`` against a board whose message package this venv lacks (issue 52): the agent carries
the board's ``wheel_msgs`` by name, and every verb that needs the type says which
``xrce-agent build-interfaces`` line builds it: topic echo (type from the graph, or given), service
call, interface show, and topic info -v beside its ``Topic type hash: INVALID``.

The board is our client on CPython through a real ``xrce-agent -m dds`` into a private ROS domain.
"""

import os
import subprocess
import sys
import threading
import time

import pytest

from agent_process import REPO, AgentProcess
from ros_helpers import DomainLease, wait_until
from xrce.client.session import Session
from xrce.transports.udp import UdpTransport

CLI_TIMEOUT_S = 60
HINT = "package wheel_msgs is not built for this venv: `xrce-agent build-interfaces DIR --package wheel_msgs`"


class WheelTicks:
    """A board's own type, as gen-msgs would name it; the board writes raw CDR."""

    TYPE_NAME = "wheel_msgs::msg::dds_::WheelTicks_"


def xrce_ros_command():
    script = os.path.join(os.path.dirname(sys.executable), "xrce-ros")
    return [script] if os.path.exists(script) else [sys.executable, "-m", "xrce.tools.ros_cli"]


@pytest.fixture(scope="module")
def board_graph():
    lease = DomainLease()
    env = {"ROS_DOMAIN_ID": str(lease.domain_id), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    stop = threading.Event()
    try:
        with AgentProcess("udp4", "-m", "dds", env=env) as agent:
            session = Session(UdpTransport("127.0.0.1", agent.port))
            assert session.create(attempts=5, timeout_ms=1000)
            node = session.create_participant(domain_id=lease.domain_id, name="wheel_board")
            writer = session.create_writer(node, "/wheel_ticks", WheelTicks, reliable=False)
            assert session.run_until_all_status(10000), session.last_statuses

            def publish():
                while not stop.is_set():
                    session.write(writer, b"\x00\x01\x00\x00\x07\x00\x00\x00", stream_id=session.best_effort)
                    session.spin_once(100)

            thread = threading.Thread(target=publish, daemon=True)
            thread.start()
            environment = dict(os.environ, PYTHONUNBUFFERED="1", **env)
            environment.pop("ROS_LOCALHOST_ONLY", None)
            yield environment
            stop.set()
            thread.join(10)
            session.delete(attempts=2, timeout_ms=500)
            session.close()
    finally:
        stop.set()
        lease.release()


def _run(env, *args):
    return subprocess.run(xrce_ros_command() + list(args), env=env, cwd=REPO, text=True, capture_output=True,
                          timeout=CLI_TIMEOUT_S)


def test_echo_and_info_of_a_topic_whose_type_this_venv_lacks_name_the_build(board_graph):
    # The type comes from the graph: once discovery shows the topic, echo says what to build.
    deadline = time.monotonic() + 40
    while True:
        echo = _run(board_graph, "topic", "echo", "/wheel_ticks", "--timeout", "10")
        if "is invalid" in echo.stderr or time.monotonic() > deadline:
            break
    assert echo.returncode == 1, echo
    assert echo.stderr.splitlines()[-1] == (
        "The message type 'wheel_msgs/msg/WheelTicks' is invalid (%s, DIR holding wheel_msgs/ with its package.xml)"
        % HINT), echo.stderr
    given = _run(board_graph, "topic", "echo", "/wheel_ticks", "wheel_msgs/msg/WheelTicks")
    assert given.returncode == 2 and HINT in given.stderr and given.stderr.count("\n") == 1, given
    assert wait_until(lambda: "Topic type hash: INVALID" in _run(board_graph, "topic", "info", "-v", "/wheel_ticks").stdout, 30)
    info = _run(board_graph, "topic", "info", "-v", "/wheel_ticks")
    assert info.returncode == 0 and info.stdout.startswith("Type: wheel_msgs/msg/WheelTicks\n\n"), info
    assert "Topic type hash: INVALID" in info.stdout, info.stdout
    assert info.stderr == ("xrce-ros: wheel_msgs/msg/WheelTicks is not a type this venv has (%s, DIR holding "
                           "wheel_msgs/ with its package.xml); its endpoints carried by name show Topic type "
                           "hash: INVALID\n" % HINT), info.stderr
    # Without -v, ros2's lines alone.
    plain = _run(board_graph, "topic", "info", "/wheel_ticks")
    assert plain.returncode == 0 and plain.stderr == "", plain


def test_service_call_and_interface_show_of_a_missing_package_name_the_build(board_graph):
    call = _run(board_graph, "service", "call", "/set_led", "wheel_msgs/srv/SetLed", "{led: 1, on: true}")
    assert call.returncode == 2 and call.stderr.count("\n") == 1, call
    assert call.stderr.startswith("xrce-ros: error: The passed service type is invalid: 'wheel_msgs/srv/SetLed' (")
    assert HINT in call.stderr, call.stderr
    show = _run(board_graph, "interface", "show", "wheel_msgs/msg/WheelTicks")
    assert show.returncode == 1 and show.stdout == "" and show.stderr.startswith("Unknown package 'wheel_msgs' ("), show
    assert HINT in show.stderr, show.stderr
