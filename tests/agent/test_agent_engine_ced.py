"""Agent engine with ``-m ced``'s middleware: representations read as eProsima's CED reads them
(its CedMiddleware.cpp): a participant's XML or reference string is ignored and its domain kept as
sent; a topic's string (a reference's ``__t`` dropped) is its name; a writer's or reader's string
(``__dw``/``__dr`` dropped) names its participant's topic; REUSE compares only those names (and a
participant's domain), in any representation and whatever the parent. The same exchanges with
eProsima's own client and agent: tests/eprosima/ (live) and tests/golden/eprosima/ (replayed)."""

from engine_peer import BIN, REF, REPLACE, REUSE, XML, Peer, data_of
from xrce.wire import constants as C
from xrce.wire.objects import DataReaderBin, DataWriterBin, EndpointQos, ParticipantBin, PubSubBin, TopicBin

# What eProsima's client examples send (PublishHelloWorldClient's XML, by reference its profiles).
PARTICIPANT_XML = "<dds><participant><rtps><name>default_xrce_participant</name></rtps></participant></dds>"
TOPIC_XML = "<dds><topic><name>HelloWorldTopic</name><dataType>HelloWorld</dataType></topic></dds>"
WRITER_XML = ("<dds><data_writer><topic><kind>NO_KEY</kind><name>HelloWorldTopic</name>"
              "<dataType>HelloWorld</dataType></topic></data_writer></dds>")


def _connected(eprosima_ced_agent, endpoint=("h", 1), key=b"\x5a\xa5\x3c\xc3"):
    agent, link = eprosima_ced_agent
    peer = Peer(agent, link, endpoint, key=key)
    assert peer.connect()[1] == C.STATUS_OK
    return agent, peer


def test_participant_strings_are_ignored_and_the_domain_kept(eprosima_ced_agent):
    agent, peer = _connected(eprosima_ced_agent)
    mw = agent.middleware
    client = agent.clients[peer.key].key_int
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, XML, PARTICIPANT_XML, 0) == C.STATUS_OK
    # Not XML at all, and a profile nobody defined: eProsima's CED reads neither.
    assert peer.create(0x0021, C.OBJK_PARTICIPANT, XML, "<dds><participant", 7) == C.STATUS_OK
    assert peer.create(0x0031, C.OBJK_PARTICIPANT, REF, "participant", 255) == C.STATUS_OK
    assert [mw.participants[(client, p)] for p in (0x0011, 0x0021, 0x0031)] == [0, 7, 255]


def test_topic_and_endpoint_strings_are_the_names_routed_by(eprosima_ced_agent):
    agent, peer = _connected(eprosima_ced_agent)
    mw = agent.middleware
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, REF, "participant", 0) == C.STATUS_OK
    assert peer.create(0x0012, C.OBJK_TOPIC, REF, "helloworld_topic__t", 0x0011) == C.STATUS_OK
    assert peer.create(0x0022, C.OBJK_TOPIC, XML, TOPIC_XML, 0x0011) == C.STATUS_OK
    assert sorted(spec.name for _, spec in mw.topics.values()) == sorted(["helloworld_topic", TOPIC_XML])
    assert peer.create(0x0013, C.OBJK_PUBLISHER, XML, "", 0x0011) == C.STATUS_OK
    assert peer.create(0x0015, C.OBJK_DATAWRITER, REF, "helloworld_topic__dw", 0x0013) == C.STATUS_OK
    # An XML writer names the topic whose string is its own: eProsima's example XML names none.
    assert peer.create(0x0025, C.OBJK_DATAWRITER, XML, WRITER_XML, 0x0013) == C.STATUS_ERR_DDS_ERROR
    assert peer.create(0x0035, C.OBJK_DATAWRITER, XML, TOPIC_XML, 0x0013) == C.STATUS_OK
    assert peer.create(0x0045, C.OBJK_DATAWRITER, REF, "other__dw", 0x0013) == C.STATUS_ERR_DDS_ERROR
    assert peer.create(0x0014, C.OBJK_SUBSCRIBER, XML, "", 0x0011) == C.STATUS_OK
    assert peer.create(0x0016, C.OBJK_DATAREADER, REF, "helloworld_topic__dr", 0x0014) == C.STATUS_OK
    assert peer.create(0x0026, C.OBJK_DATAREADER, BIN,
                       DataReaderBin(0x0012, EndpointQos(C.QOS_KEEP_LAST | C.QOS_RELIABLE, 10)),
                       0x0014) == C.STATUS_OK
    topics = {key[1]: writer.topic for key, writer in mw.writers.items()}
    assert topics == {0x0015: "helloworld_topic", 0x0035: TOPIC_XML}
    # The writer by reference reaches both readers of the topic named by the references.
    peer.ack_all()
    for reader in (0x0016, 0x0026):
        peer.read(object_id=reader)
    peer.take()
    peer.write(b"\x05\x00\x00\x00hello\x00", object_id=0x0015)
    assert data_of(peer.take()) == [b"\x05\x00\x00\x00hello\x00"] * 2


def test_clients_meet_on_a_name_given_by_reference_and_in_binary(eprosima_ced_agent):
    agent, talker = _connected(eprosima_ced_agent)
    listener = Peer(agent, eprosima_ced_agent[1], ("h", 2), key=b"\x01\x02\x03\x04")
    assert listener.connect()[1] == C.STATUS_OK
    assert talker.create(0x0011, C.OBJK_PARTICIPANT, REF, "participant", 3) == C.STATUS_OK
    assert talker.create(0x0012, C.OBJK_TOPIC, REF, "shapes__t", 0x0011) == C.STATUS_OK
    assert talker.create(0x0013, C.OBJK_PUBLISHER, XML, "", 0x0011) == C.STATUS_OK
    assert talker.create(0x0015, C.OBJK_DATAWRITER, REF, "shapes__dw", 0x0013) == C.STATUS_OK
    listener.build_pubsub(topic="shapes", domain=3)
    listener.read()
    listener.take()
    talker.write(b"\x01\x00\x00\x00")
    assert data_of(listener.take()) == [b"\x01\x00\x00\x00"]


def test_reuse_compares_names_as_eprosima_ced(eprosima_ced_agent):
    agent, peer = _connected(eprosima_ced_agent)
    mw = agent.middleware
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, XML, PARTICIPANT_XML, 0) == C.STATUS_OK
    # A participant matches by its domain alone, whatever its string or representation.
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, REF, "anything", 0, flags=REUSE) == C.STATUS_OK_MATCHED
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, ParticipantBin("x"), 0, flags=REUSE) == \
        C.STATUS_OK_MATCHED
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, REF, "anything", 1, flags=REUSE) == C.STATUS_ERR_MISMATCH
    assert peer.create(0x0012, C.OBJK_TOPIC, BIN, TopicBin("chatter", "T"), 0x0011) == C.STATUS_OK
    # A topic matches by name: a reference's suffix dropped, the type not compared.
    assert peer.create(0x0012, C.OBJK_TOPIC, REF, "chatter__t", 0x0011, flags=REUSE) == C.STATUS_OK_MATCHED
    assert peer.create(0x0012, C.OBJK_TOPIC, BIN, TopicBin("chatter", "U"), 0x0011, flags=REUSE) == \
        C.STATUS_OK_MATCHED
    assert peer.create(0x0012, C.OBJK_TOPIC, XML, TOPIC_XML, 0x0011, flags=REUSE) == C.STATUS_ERR_MISMATCH
    assert peer.create(0x0013, C.OBJK_PUBLISHER, BIN, PubSubBin(), 0x0011) == C.STATUS_OK
    assert peer.create(0x0013, C.OBJK_PUBLISHER, XML, "<dds>", 0x0011, flags=REUSE) == C.STATUS_OK_MATCHED
    qos = EndpointQos(C.QOS_KEEP_LAST | C.QOS_RELIABLE, 10)
    assert peer.create(0x0015, C.OBJK_DATAWRITER, BIN, DataWriterBin(0x0012, qos), 0x0013) == C.STATUS_OK
    writer = mw.writers[(agent.clients[peer.key].key_int, 0x0015)]
    # A writer matches by its topic's name; its QoS is not compared.
    assert peer.create(0x0015, C.OBJK_DATAWRITER, REF, "chatter__dw", 0x0013, flags=REUSE) == \
        C.STATUS_OK_MATCHED
    assert peer.create(0x0015, C.OBJK_DATAWRITER, BIN,
                       DataWriterBin(0x0012, EndpointQos(C.QOS_KEEP_LAST, 3)), 0x0013, flags=REUSE) == \
        C.STATUS_OK_MATCHED
    assert mw.writers[(agent.clients[peer.key].key_int, 0x0015)] is writer
    assert peer.create(0x0015, C.OBJK_DATAWRITER, REF, "other__dw", 0x0013, flags=REUSE) == \
        C.STATUS_ERR_MISMATCH
    # REUSE|REPLACE: matched is kept; not matched is created anew, and fails where the topic is not.
    assert peer.create(0x0015, C.OBJK_DATAWRITER, REF, "chatter__dw", 0x0013, flags=REUSE | REPLACE) == \
        C.STATUS_OK_MATCHED
    assert peer.create(0x0015, C.OBJK_DATAWRITER, REF, "other__dw", 0x0013, flags=REUSE | REPLACE) == \
        C.STATUS_ERR_DDS_ERROR
    assert (agent.clients[peer.key].key_int, 0x0015) not in mw.writers
    peer.ack_all()  # the agent's STATUS stream holds 16 unacknowledged messages
    assert peer.create(0x0022, C.OBJK_TOPIC, REF, "other__t", 0x0011) == C.STATUS_OK
    assert peer.create(0x0015, C.OBJK_DATAWRITER, REF, "other__dw", 0x0013, flags=REPLACE) == C.STATUS_OK
    assert mw.writers[(agent.clients[peer.key].key_int, 0x0015)].topic == "other"
