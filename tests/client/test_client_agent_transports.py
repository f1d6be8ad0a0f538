"""Our client completes sessions against a real ``xrce-agent`` process over UDP, TCP and a serial
pseudo-terminal, on best-effort and reliable streams, keyed and unkeyed."""

import time

import pytest

from agent_process import AgentProcess
from xrce.client.session import Session, ping_agent
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


REFS = """<?xml version="1.0"?>
<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <profiles>
    <participant profile_name="robot_participant"><rtps><name>robot</name></rtps></participant>
    <topic profile_name="chatter_topic"><name>rt/chatter</name>
      <dataType>std_msgs::msg::dds_::String_</dataType></topic>
    <data_writer profile_name="chatter_writer">
      <topic><kind>NO_KEY</kind><name>rt/chatter</name><dataType>std_msgs::msg::dds_::String_</dataType></topic>
      <qos><reliability><kind>RELIABLE</kind></reliability></qos>
    </data_writer>
    <data_reader profile_name="chatter_reader">
      <topic><kind>NO_KEY</kind><name>rt/chatter</name><dataType>std_msgs::msg::dds_::String_</dataType></topic>
      <qos><reliability><kind>RELIABLE</kind></reliability></qos>
    </data_reader>
  </profiles>
</dds>
"""


def test_entities_created_by_reference_and_by_xml(tmp_path):
    """The client's three representations against one agent: by reference (profiles from -r),
    XML, and binary — all interoperating on one topic."""
    refs = tmp_path / "refs.xml"
    refs.write_text(REFS)
    with AgentProcess("udp4", "-m", "ced", "-r", str(refs)) as agent:
        session = Session(UdpTransport("127.0.0.1", agent.port), history=8)
        try:
            assert session.create(attempts=3, timeout_ms=1000)
            node = session.create_participant(ref="robot_participant")
            # Endpoints defined by XML or reference name their topic: it must exist first.
            topic = session.create_topic(node, xml="<dds><topic><name>rt/chatter</name><dataType>"
                                         "std_msgs::msg::dds_::String_</dataType></topic></dds>")
            publisher = session.create_publisher(node, xml="")
            writer = session.create_datawriter(publisher, ref="chatter_writer")
            subscriber = session.create_subscriber(node, xml="")
            by_ref = session.create_datareader(subscriber, ref="chatter_reader")
            binary = session.create_datareader(subscriber, topic, session.endpoint_qos(True))
            assert session.run_until_all_status(3000), session.last_statuses
            got = {by_ref: [], binary: []}
            for reader in got:
                session.set_reader_callback(reader, got[reader].append, String)
                session.read_data(reader)
            session.write(writer, String(data="by reference"))
            assert session.run_until_confirm_delivery(2000)
            deadline = time.monotonic() + 5
            while not all(got.values()) and time.monotonic() < deadline:
                session.spin_once(20)
            assert [m.data for m in got[by_ref]] == ["by reference"] == [m.data for m in got[binary]]
            # An unknown profile is refused with the reference error, not silently created.
            session.create_datawriter(publisher, ref="no_such_profile")
            assert not session.run_until_all_status(2000)
            assert list(session.last_statuses.values()) != [0]
            assert session.delete(attempts=3, timeout_ms=500)
        finally:
            session.close()
