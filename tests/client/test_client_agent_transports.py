"""Our client completes sessions against a real ``xrce-agent`` process over UDP, TCP and a serial
pseudo-terminal, on best-effort and reliable streams, keyed and unkeyed."""

import time

import pytest

from agent_process import AgentProcess
from xrce.client.session import Session, ping_agent
from xrce.wire import constants as C
from xrce.msgs.std_msgs import String
from xrce.transports.serial import SerialTransport
from xrce.transports.tcp import TcpTransport
from xrce.transports.udp import UdpTransport

TRANSPORTS = {
    "udp4": lambda agent: UdpTransport("127.0.0.1", agent.port),
    "tcp4": lambda agent: TcpTransport("127.0.0.1", agent.port),
    "pseudoterminal": lambda agent: SerialTransport(agent.device, 115200),
}


@pytest.mark.parametrize("session_id", [0x81, 0x01], ids=["unkeyed", "keyed"])
@pytest.mark.parametrize("kind", sorted(TRANSPORTS))
def test_session_echo_through_the_agent(kind, session_id):
    with AgentProcess(kind, "-m", "ced") as agent:
        transport = TRANSPORTS[kind](agent)
        try:
            assert ping_agent(transport, 500, 3) is not None
            session = Session(transport, session_id=session_id, history=8)
            assert session.create(attempts=3, timeout_ms=1000)
            node = session.create_participant(name="echo")
            received = {"reliable": [], "best_effort": []}
            for qos in received:
                reliable = qos == "reliable"
                session.create_reader(node, "/echo_" + qos, String, received[qos].append, reliable=reliable)
            writers = {qos: session.create_writer(node, "/echo_" + qos, String, reliable=qos == "reliable")
                       for qos in received}
            assert session.run_until_all_status(3000), session.last_statuses
            big = "z" * 1500  # fragmented on the reliable stream in both directions
            for i in range(5):
                session.write(writers["reliable"], String(data="r%d" % i))
            session.write(writers["reliable"], String(data=big))
            assert session.run_until_confirm_delivery(3000)
            deadline = time.monotonic() + 10
            while not received["best_effort"] and time.monotonic() < deadline:
                session.write(writers["best_effort"], String(data="b"), stream_id=session.best_effort)
                session.run_until_timeout(20)
            while len(received["reliable"]) < 6 and time.monotonic() < deadline:
                session.spin_once(20)
            assert [m.data for m in received["reliable"]] == ["r%d" % i for i in range(5)] + [big]
            assert received["best_effort"][0].data == "b"
            assert session.ping(500, 3) and session.sync_time(500, 3)
            assert session.delete(attempts=3, timeout_ms=500)
        finally:
            transport.close()


def test_entities_created_by_reference_and_by_xml():
    """The client's three representations against one agent in ``-m ced``, read as eProsima's CED
    reads them: a participant's reference names nothing, a topic's reference (``__t`` dropped) is
    the topic's name, an endpoint's reference (``__dw``/``__dr`` dropped) or XML string names its
    topic; all interoperate on one topic with a binary reader."""
    with AgentProcess("udp4", "-m", "ced") as agent:
        session = Session(UdpTransport("127.0.0.1", agent.port), history=8)
        try:
            assert session.create(attempts=3, timeout_ms=1000)
            node = session.create_participant(ref="robot_participant")
            topic = session.create_topic(node, ref="rt/chatter__t")
            publisher = session.create_publisher(node, xml="")
            writer = session.create_datawriter(publisher, ref="rt/chatter__dw")
            subscriber = session.create_subscriber(node, xml="")
            by_ref = session.create_datareader(subscriber, ref="rt/chatter__dr")
            by_xml = session.create_datareader(subscriber, xml="rt/chatter")
            binary = session.create_datareader(subscriber, topic, session.endpoint_qos(True))
            assert session.run_until_all_status(3000), session.last_statuses
            got = {by_ref: [], by_xml: [], binary: []}
            for reader in got:
                session.set_reader_callback(reader, got[reader].append, String)
                session.read_data(reader)
            session.write(writer, String(data="by reference"))
            assert session.run_until_confirm_delivery(2000)
            deadline = time.monotonic() + 5
            while not all(got.values()) and time.monotonic() < deadline:
                session.spin_once(20)
            assert [[m.data for m in got[r]] for r in got] == [["by reference"]] * 3
            # A writer naming a topic the participant does not have is refused, not created.
            session.create_datawriter(publisher, ref="rt/no_such_topic__dw")
            assert not session.run_until_all_status(2000)
            assert list(session.last_statuses.values()) == [C.STATUS_ERR_DDS_ERROR]
            assert session.delete(attempts=3, timeout_ms=500)
        finally:
            session.close()
