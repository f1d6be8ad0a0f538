"""Agent engine: objects (XRCE-WIRE.md §4, §5): CREATE with REUSE/REPLACE, the stream a STATUS
goes back on, DELETE of an object and its own children, REUSE by meaning (decoded binary, parsed XML
and references), XML and reference representations, and a CREATE that waits for its type to be
built."""

from engine_peer import BIN, REF, REPLACE, REUSE, XML, Clock, Link, Peer, data_of
from xrce.wire import constants as C
from xrce.agent.middleware.ced import CedMiddleware
from xrce.agent.engine.agent import Agent
from xrce.agent.engine.xmlrep import refs_from_profiles
from xrce.wire.objects import DataWriterBin, EndpointQos, ParticipantBin, PubSubBin, TopicBin
from xrce.wire.submessages import Create, Delete, WriteData, encode_message


def test_create_reuse_replace_table(ced_agent):
    agent, link = ced_agent
    peer = Peer(agent, link, ("h", 1))
    assert peer.connect()[1] == C.STATUS_OK
    mw = agent.middleware
    p1, p2 = ParticipantBin("one"), ParticipantBin("two")
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, p1) == C.STATUS_OK
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, p1) == C.STATUS_ERR_ALREADY_EXISTS
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, p1, flags=REUSE) == C.STATUS_OK_MATCHED
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, p2, flags=REUSE) == C.STATUS_ERR_MISMATCH
    # A different domain (tail) is a different representation too.
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, p1, 3, flags=REUSE) == C.STATUS_ERR_MISMATCH
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, p1, flags=REUSE | REPLACE) == \
        C.STATUS_OK_MATCHED
    assert peer.create(0x0012, C.OBJK_TOPIC, BIN, TopicBin("t", "T"), 0x0011) == C.STATUS_OK
    assert (agent.clients[peer.key].key_int, 0x0012) in mw.topics
    # REUSE|REPLACE with another representation re-creates the participant and drops its children.
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, p2, flags=REUSE | REPLACE) == C.STATUS_OK
    assert not mw.topics and len(mw.participants) == 1
    # REPLACE alone always re-creates, even when identical.
    assert peer.create(0x0012, C.OBJK_TOPIC, BIN, TopicBin("t", "T"), 0x0011) == C.STATUS_OK
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, BIN, p2, flags=REPLACE) == C.STATUS_OK
    assert not mw.topics
    # The parent must exist; its kind nibble is forced (0x0010 means participant 0x0011).
    assert peer.create(0x0022, C.OBJK_TOPIC, BIN, TopicBin("t", "T"), 0x0020) == \
        C.STATUS_ERR_UNKNOWN_REFERENCE
    assert peer.create(0x0020, C.OBJK_TOPIC, BIN, TopicBin("t", "T"), 0x0010) == C.STATUS_OK
    assert 0x0022 in agent.clients[peer.key].objects  # own nibble replaced by the kind too


def test_status_stream_follows_request_stream(ced_agent):
    agent, link = ced_agent
    peer = Peer(agent, link, ("h", 1))
    peer.connect()
    peer.send(0x01, Create(0x50, 0x0011, C.OBJK_PARTICIPANT, BIN, ParticipantBin("x"), 0))
    assert peer.statuses() == [(0x01, 0x50, C.STATUS_OK)]
    peer.send(0x80, Create(0x51, 0x0021, C.OBJK_PARTICIPANT, BIN, ParticipantBin("y"), 0))
    assert peer.statuses() == [(0x80, 0x51, C.STATUS_OK)]
    peer.send(0, Create(0x52, 0x0031, C.OBJK_PARTICIPANT, BIN, ParticipantBin("z"), 0))
    assert peer.statuses() == [(0x01, 0x52, C.STATUS_OK)]
    peer.send(0x80, Delete(0x53, 0x0011))
    assert peer.statuses() == [(0x80, 0x53, C.STATUS_OK)]
    peer.send(0x80, Delete(0x54, 0x0011))
    assert peer.statuses() == [(0x80, 0x54, C.STATUS_ERR_UNKNOWN_REFERENCE)]


def test_failing_submessage_stops_the_rest_of_the_message(ced_agent):
    agent, link = ced_agent
    peer = Peer(agent, link, ("h", 1))
    peer.connect()
    peer.send(0x80, WriteData(0x50, 0x0995, b"nobody"),
              Create(0x51, 0x0011, C.OBJK_PARTICIPANT, BIN, ParticipantBin("x"), 0))
    assert peer.statuses() == []
    assert not agent.clients[peer.key].objects


def test_delete_cascades_to_children(ced_agent):
    agent, link = ced_agent
    peer = Peer(agent, link, ("h", 1))
    peer.connect()
    peer.build_pubsub()
    peer.send(0x80, Delete(0x70, 0x0011))
    assert peer.statuses() == [(0x80, 0x70, C.STATUS_OK)]
    mw = agent.middleware
    assert not (mw.participants or mw.topics or mw.groups or mw.writers or mw.readers)


def test_delete_topic_leaves_the_writers_and_readers_that_use_it(ced_agent):
    """rmw_microxrcedds' publisher and subscription fini: DELETE TOPIC, then DELETE DATAWRITER and
    DELETE PUBLISHER in one message. eProsima answers every one OK; the writer and reader keep
    working until they are deleted themselves."""
    agent, link = ced_agent
    peer = Peer(agent, link, ("h", 1))
    peer.connect()
    peer.build_pubsub()
    peer.send(0x80, Delete(0x70, 0x0012))
    assert peer.statuses() == [(0x80, 0x70, C.STATUS_OK)]
    objects = agent.clients[peer.key].objects
    assert 0x0012 not in objects and {0x0015, 0x0016} <= set(objects)
    peer.read(0x01)
    peer.write(b"still delivered")
    assert data_of(peer.take()) == [b"still delivered"]
    peer.send(0x80, Delete(0x71, 0x0015), Delete(0x72, 0x0013))
    assert peer.statuses() == [(0x80, 0x71, C.STATUS_OK), (0x80, 0x72, C.STATUS_OK)]
    peer.send(0x80, Delete(0x73, 0x0016), Delete(0x74, 0x0014), Delete(0x75, 0x0011))
    assert [s[2] for s in peer.statuses()] == [C.STATUS_OK] * 3
    mw = agent.middleware
    assert not (mw.participants or mw.topics or mw.groups or mw.writers or mw.readers)


def _create_with_padding(peer, request_id, object_id, kind, blob_object, tail, pad_at, pad):
    """A binary CREATE (REUSE|REPLACE) whose blob carries ``pad`` in the alignment byte at
    ``pad_at``, as rmw_microxrcedds leaves it uninitialised."""
    blob = blob_object.to_blob()
    assert blob[pad_at] == 0
    message = encode_message(peer.session_id, 0x80, peer.seqs.get(0x80, 0), peer.header_key,
                             [Create(request_id, object_id, kind, BIN, blob_object, tail,
                                     REUSE | REPLACE)])
    patched = blob[:pad_at] + bytes([pad]) + blob[pad_at + 1:]
    assert message.count(blob) == 1
    peer.seqs[0x80] = peer.seqs.get(0x80, 0) + 1
    peer.raw(message.replace(blob, patched))
    return [s[2] for s in peer.statuses() if s[1] == request_id]


def test_reuse_compares_decoded_binary_not_bytes(ced_agent):
    agent, link = ced_agent
    peer = Peer(agent, link, ("h", 1))
    peer.connect()
    peer.build_pubsub()
    writer = agent.middleware.writers[(agent.clients[peer.key].key_int, 0x0015)]
    qos = EndpointQos(C.QOS_KEEP_LAST | C.QOS_RELIABLE, 10)
    # The byte before the history depth aligns it: 0x1d in one boot, 0x0a in the next.
    for pad in (0x1D, 0x0A):
        assert _create_with_padding(peer, 0x90 + pad, 0x0015, C.OBJK_DATAWRITER,
                                    DataWriterBin(0x0012, qos), 0x0013, 7, pad) == \
            [C.STATUS_OK_MATCHED]
    assert agent.middleware.writers[(agent.clients[peer.key].key_int, 0x0015)] is writer
    # A field that is present (even equal to a default) or different is another representation.
    for changed in (DataWriterBin(0x0012, qos, ownership_strength=0),
                    DataWriterBin(0x0012, EndpointQos(C.QOS_KEEP_LAST | C.QOS_RELIABLE, 11)),
                    DataWriterBin(0x0012, EndpointQos(C.QOS_KEEP_LAST, 10))):
        assert peer.create(0x0015, C.OBJK_DATAWRITER, BIN, changed, 0x0013, flags=REUSE) == \
            C.STATUS_ERR_MISMATCH
    assert peer.create(0x0015, C.OBJK_DATAWRITER, BIN, DataWriterBin(0x0012, qos), 0x0013,
                       flags=REUSE) == C.STATUS_OK_MATCHED


def test_reuse_compares_xml_and_references_by_meaning(ced_agent):
    agent, link = ced_agent
    agent.refs = refs_from_profiles("""<dds><profiles>
      <participant profile_name="node"><rtps><name>n</name></rtps></participant>
      <topic profile_name="chatter"><name>rt/chatter</name><dataType>T</dataType></topic>
      <data_writer profile_name="writer"><topic><name>rt/chatter</name></topic>
        <qos><reliability><kind>BEST_EFFORT</kind></reliability></qos></data_writer>
    </profiles></dds>""")
    peer = Peer(agent, link, ("h", 1))
    peer.connect()
    participant = "<dds><participant><rtps><name>n</name></rtps></participant></dds>"
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, XML, participant, 0) == C.STATUS_OK
    spaced = "<dds>\n  <participant>\n    <rtps><name> n </name></rtps>\n  </participant>\n</dds>"
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, XML, spaced, 0, flags=REUSE) == \
        C.STATUS_OK_MATCHED
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, REF, "node", 0, flags=REUSE) == \
        C.STATUS_OK_MATCHED  # the profile describes the same participant
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, XML, participant.replace(">n<", ">m<"), 0,
                       flags=REUSE) == C.STATUS_ERR_MISMATCH
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, XML, "<dds><participant", 0,
                       flags=REUSE) == C.STATUS_ERR_MISMATCH  # does not parse: matches nothing
    assert peer.create(0x0012, C.OBJK_TOPIC, REF, "chatter", 0x0011) == C.STATUS_OK
    assert peer.create(0x0012, C.OBJK_TOPIC, XML, "<dds><topic><dataType>T</dataType>"
                       "<name>rt/chatter</name></topic></dds>", 0x0011, flags=REUSE) == \
        C.STATUS_OK_MATCHED
    assert peer.create(0x0012, C.OBJK_TOPIC, XML, "<dds><topic><dataType>U</dataType>"
                       "<name>rt/chatter</name></topic></dds>", 0x0011, flags=REUSE) == \
        C.STATUS_ERR_MISMATCH
    # Groups always match, as eProsima's do.
    assert peer.create(0x0013, C.OBJK_PUBLISHER, XML, "", 0x0011) == C.STATUS_OK
    assert peer.create(0x0013, C.OBJK_PUBLISHER, XML, "<dds><publisher/></dds>", 0x0011,
                       flags=REUSE) == C.STATUS_OK_MATCHED
    assert peer.create(0x0015, C.OBJK_DATAWRITER, REF, "writer", 0x0013) == C.STATUS_OK
    same_writer = ("<dds><data_writer><qos><reliability><kind>BEST_EFFORT</kind></reliability>"
                   "</qos><topic><name>rt/chatter</name></topic></data_writer></dds>")
    assert peer.create(0x0015, C.OBJK_DATAWRITER, XML, same_writer, 0x0013, flags=REUSE) == \
        C.STATUS_OK_MATCHED
    assert peer.create(0x0015, C.OBJK_DATAWRITER, XML, same_writer.replace("BEST_EFFORT",
                       "RELIABLE"), 0x0013, flags=REUSE) == C.STATUS_ERR_MISMATCH
    agent.refs.pop("writer")
    assert peer.create(0x0015, C.OBJK_DATAWRITER, REF, "writer", 0x0013, flags=REUSE) == \
        C.STATUS_ERR_MISMATCH  # the profile is gone


def test_xml_and_reference_representations(ced_agent, monkeypatch):
    agent, link = ced_agent
    profiles = """<?xml version="1.0"?>
    <dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"><profiles>
      <participant profile_name="node"><domainId>7</domainId><rtps><name>ref_node</name></rtps></participant>
      <topic profile_name="chatter"><name>rt/chatter</name><dataType>std_msgs::msg::dds_::String_</dataType></topic>
      <data_writer profile_name="writer"><topic><name>rt/chatter</name><dataType>std_msgs::msg::dds_::String_</dataType>
        <historyQos><kind>KEEP_LAST</kind><depth>3</depth></historyQos></topic>
        <qos><reliability><kind>BEST_EFFORT</kind></reliability></qos></data_writer>
    </profiles></dds>"""
    agent.refs = refs_from_profiles(profiles)
    assert set(agent.refs) == {"node", "chatter", "writer"}
    peer = Peer(agent, link, ("h", 1))
    peer.connect()
    assert peer.create(0x0011, C.OBJK_PARTICIPANT, REF, "node", 255) == C.STATUS_OK
    assert agent.middleware.participants[(peer.agent.clients[peer.key].key_int, 0x0011)] == 7
    assert peer.create(0x0012, C.OBJK_TOPIC, REF, "chatter", 0x0011) == C.STATUS_OK
    assert peer.create(0x0013, C.OBJK_PUBLISHER, XML, "", 0x0011) == C.STATUS_OK
    assert peer.create(0x0015, C.OBJK_DATAWRITER, REF, "writer", 0x0013) == C.STATUS_OK
    (writer,) = agent.middleware.writers.values()
    assert (writer.topic, writer.qos.reliable, writer.qos.depth) == ("rt/chatter", False, 3)
    assert peer.create(0x0025, C.OBJK_DATAWRITER, REF, "missing", 0x0013) == C.STATUS_ERR_DDS_ERROR
    assert peer.create(0x0035, C.OBJK_DATAWRITER, XML,
                       "<dds><data_writer><topic><name>rt/other</name></topic></data_writer></dds>",
                       0x0013) == C.STATUS_ERR_DDS_ERROR  # no such topic in the participant
    assert peer.create(0x0045, C.OBJK_DATAWRITER, XML, "<dds><data_wr", 0x0013) == \
        C.STATUS_ERR_DDS_ERROR
    assert peer.create(0x0023, C.OBJK_PUBLISHER, REF, "node", 0x0011) == C.STATUS_ERR_INVALID_DATA
    monkeypatch.setenv("XRCE_DOMAIN_ID_OVERRIDE", "42")
    assert peer.create(0x0021, C.OBJK_PARTICIPANT, XML,
                       "<dds><participant><rtps><name>n</name></rtps></participant></dds>", 255) == 0
    assert agent.middleware.participants[(agent.clients[peer.key].key_int, 0x0021)] == 42


class SlowTypeMiddleware(CedMiddleware):
    """CED, except that topics of type ``slow::...`` need a build that finishes when told to."""

    def __init__(self):
        super().__init__()
        import concurrent.futures
        self.build = concurrent.futures.Future()

    def create_topic(self, key, participant, topic):
        if topic.type_name.startswith("slow::") and not self.build.done():
            from xrce.agent.middleware import TypeNotReady
            raise TypeNotReady("slow is being built", self.build)
        return super().create_topic(key, participant, topic)


def test_a_create_waiting_for_its_type_parks_only_its_client():
    link = Link()
    middleware = SlowTypeMiddleware()
    agent = Agent(middleware)
    agent.clock = Clock()
    waiting, other = Peer(agent, link, "waiting"), Peer(agent, link, "other", key=b"\x01\x02\x03\x04")
    assert waiting.connect()[1] == 0 and other.connect()[1] == 0
    assert waiting.create(0x0011, C.OBJK_PARTICIPANT, BIN, ParticipantBin("p"), 0) == 0
    # The topic and, in a later message, its writer's publisher: neither is answered yet.
    topic_request = waiting.next_request()
    waiting.send(0x80, Create(topic_request, 0x0012, C.OBJK_TOPIC, BIN,
                              TopicBin("rt/slow", "slow::msg::dds_::Thing_"), 0x0011, 1))
    publisher_request = waiting.next_request()
    waiting.send(0x80, Create(publisher_request, 0x0013, C.OBJK_PUBLISHER, BIN, PubSubBin(), 0x0011, 1))
    assert waiting.statuses() == []
    # Meanwhile another client is served as usual.
    other.build_pubsub("rt/fast")
    other.read()
    other.write(b"\x02\x00\x00\x00a\x00")
    assert data_of(other.take()) == [b"\x02\x00\x00\x00a\x00"]
    # The build finishes: the parked CREATE and everything queued behind it run, in order.
    middleware.build.set_result(None)
    agent.tick()
    assert waiting.statuses() == [(0x80, topic_request, 0), (0x80, publisher_request, 0)]


class RefusingMiddleware(CedMiddleware):
    """CED whose publish fails for one topic, as rcl's publish can (a context shut down, a
    serialization error): the engine counts what was not published instead of only logging."""

    def write(self, writer, sample):
        if self.writers[writer].topic == "rt/refused":
            return False
        return super().write(writer, sample)


def test_samples_the_middleware_does_not_publish_are_counted_and_shown_in_stats():
    from xrce.agent.observe.observability import Observer
    from xrce.agent.observe.stats_view import format_snapshot

    link = Link()
    agent = Agent(RefusingMiddleware())
    agent.clock = Clock()
    refused, fine = Peer(agent, link, "refused"), Peer(agent, link, "fine", key=b"\x01\x02\x03\x04")
    for peer, topic in ((refused, "rt/refused"), (fine, "rt/fine")):
        assert peer.connect()[1] == 0
        peer.build_pubsub(topic, reliable=False)
    for _ in range(3):
        refused.write(b"\x02\x00\x00\x00a\x00", stream_id=0x01)
        fine.write(b"\x02\x00\x00\x00b\x00", stream_id=0x01)
    assert agent.stats.publish_errors == 3
    snapshot = Observer(agent).snapshot()
    assert snapshot["agent"]["publish_errors"] == 3
    assert "not published 3," in format_snapshot(snapshot)
