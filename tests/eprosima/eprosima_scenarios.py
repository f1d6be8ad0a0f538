"""The exchanges tests/eprosima/ drives eProsima's client through, and that record_eprosima.py captured
between eProsima's client and eProsima's agent into tests/golden/eprosima/.

Each creation scenario is a script for programs/script.c (its docstring: one CREATE a line); each
discovery scenario names the agent's transport. What eProsima's agent answered each line (its
STATUS codes, as the program printed them) is in the recording's first line; the live tests hold
our agent to it.
"""

PARTICIPANT_XML = "<dds><participant><rtps><name>default_xrce_participant</name></rtps></participant></dds>"
TOPIC_XML = "<dds><topic><name>HelloWorldTopic</name><dataType>HelloWorld</dataType></topic></dds>"
WRITER_XML = ("<dds><data_writer><topic><kind>NO_KEY</kind><name>HelloWorldTopic</name>"
              "<dataType>HelloWorld</dataType></topic></data_writer></dds>")
READER_XML = ("<dds><data_reader><topic><kind>NO_KEY</kind><name>HelloWorldTopic</name>"
              "<dataType>HelloWorld</dataType></topic></data_reader></dds>")

# CED by XML and by reference, as eProsima's examples send them (PublishHelloWorld and its
# profiles): the participant's strings mean nothing to CED, a topic's string is its name, an
# endpoint's string names its topic.
CED_XML_REF = [
    "participant xml 1 0 create " + PARTICIPANT_XML,
    "participant ref 2 0 create participant",
    "participant xml 3 0 create <dds><participant",
    "topic ref 1 1 create helloworld_topic__t",
    "topic xml 2 1 create " + TOPIC_XML,
    "publisher xml 1 1 create",
    "subscriber xml 1 1 create",
    "datawriter ref 1 1 create helloworld_topic__dw",
    "datareader ref 1 1 create helloworld_topic__dr",
    "datawriter xml 2 1 create " + WRITER_XML,
    "datareader xml 2 1 create " + READER_XML,
    "datawriter xml 3 1 create " + TOPIC_XML,
    "datawriter ref 4 1 create no_such_topic__dw",
]

# REUSE and REPLACE, each comparison eProsima's CED makes.
CED_REUSE_REPLACE = [
    "participant xml 1 0 create " + PARTICIPANT_XML,
    "participant ref 1 0 create participant",
    "participant ref 1 0 reuse other_participant",
    "participant ref 1 1 reuse participant",
    "participant ref 1 0 reuse+replace anything",
    "topic ref 1 1 create chatter__t",
    "topic ref 1 1 reuse chatter__t",
    "topic xml 1 1 reuse chatter",
    "topic ref 1 1 reuse other__t",
    "topic ref 1 1 reuse+replace chatter__t",
    "topic ref 1 1 replace chatter__t",
    "topic ref 2 1 create other__t",
    "publisher xml 1 1 create",
    "publisher xml 1 1 reuse <dds><publisher/></dds>",
    "publisher xml 1 1 create",
    "datawriter ref 1 1 create chatter__dw",
    "datawriter ref 1 1 reuse chatter__dw",
    "datawriter xml 1 1 reuse chatter",
    "datawriter ref 1 1 reuse other__dw",
    "datawriter ref 1 1 reuse+replace other__dw",
    "datawriter ref 1 1 reuse chatter__dw",
    "datawriter ref 1 1 reuse+replace missing__dw",
    "datawriter ref 1 1 replace chatter__dw",
]

# Nine and more reliable creations back to back: each next CREATE the moment its STATUS comes.
BACK_TO_BACK = ["participant ref 1 0 create participant"] + [
    "topic ref %d 1 create topic%d__t" % (n, n) for n in range(1, 15)]
# And sixteen buffered at once, with a history of 8: the client waits for room as its ACKNACKs
# come, never for an answer.
BATCH = ["participant ref 1 0 create participant", "batch 8"] + [
    "topic ref %d 1 create topic%d__t" % (n, n) for n in range(1, 9)]

CREATIONS = {
    "ced_xml_ref_udp4": ("udp4", CED_XML_REF),
    "ced_xml_ref_udp6": ("udp6", CED_XML_REF),
    "ced_reuse_replace_udp4": ("udp4", CED_REUSE_REPLACE),
    "back_to_back_udp4": ("udp4", BACK_TO_BACK),
    "back_to_back_udp6": ("udp6", BACK_TO_BACK),
    "batch_udp4": ("udp4", BATCH),
    "ced_xml_ref_tcp4": ("tcp4", CED_XML_REF),
    "ced_xml_ref_tcp6": ("tcp6", CED_XML_REF),
    "ced_xml_ref_serial": ("serial", CED_XML_REF),
    "ced_reuse_replace_tcp4": ("tcp4", CED_REUSE_REPLACE),
    "ced_reuse_replace_serial": ("serial", CED_REUSE_REPLACE),
    "back_to_back_tcp4": ("tcp4", BACK_TO_BACK),
    "back_to_back_tcp6": ("tcp6", BACK_TO_BACK),
    "back_to_back_serial": ("serial", BACK_TO_BACK),
}
DISCOVERY = {"discovery_udp4": "udp4", "discovery_udp6": "udp6"}

# Two clients (programs/exchange.c: a writer and a reader of one topic of a type name that is no
# ROS one) exchanging samples through the agent, over each transport, with the program's own
# transport dropping a share of the messages both ways (seeded: the same datagrams each run, as
# long as the exchange itself goes the same way). (stream, count, body bytes, drop %, format):
# 768 body bytes are 1.5 x the MTU of 512, fragmented by the library; a best-effort stream cannot
# carry a fragmented sample (XRCE fragments only on reliable streams), so that cell does not exist.
# Binary entities on the reliable stream, references on the best-effort one (CED has both).
FRAGMENTED = 768
EXCHANGE_CELLS = {
    "reliable_1": ("reliable", 1, 64, 0, "bin"),
    "reliable_10": ("reliable", 10, 64, 0, "bin"),
    "reliable_10_drop5": ("reliable", 10, 64, 5, "bin"),
    "reliable_10_drop10": ("reliable", 10, 64, 10, "bin"),
    "reliable_frag": ("reliable", 4, FRAGMENTED, 0, "bin"),
    "reliable_frag_drop5": ("reliable", 4, FRAGMENTED, 5, "bin"),
    "reliable_frag_drop10": ("reliable", 4, FRAGMENTED, 10, "bin"),
    "best_effort_1": ("best-effort", 1, 64, 0, "ref"),
    "best_effort_10": ("best-effort", 10, 64, 0, "ref"),
    "best_effort_10_drop5": ("best-effort", 10, 64, 5, "ref"),
    "best_effort_10_drop10": ("best-effort", 10, 64, 10, "ref"),
}
EXCHANGE_TRANSPORTS = ("udp4", "tcp4", "tcp6", "serial", "udp6")
EXCHANGE_SEED = 50
EXCHANGES = {"exchange_%s_%s" % (cell, transport): (transport, args)
             for transport in EXCHANGE_TRANSPORTS for cell, args in EXCHANGE_CELLS.items()}


def exchange_argv(args, settle_ms=0):
    """The arguments after the transport's own for programs/exchange.c."""
    stream, count, size, drop, fmt = args
    return [stream, str(count), str(size), str(drop), str(EXCHANGE_SEED), fmt, str(settle_ms)]


# By reference in -m dds: both agents read the references from a Fast DDS profiles file (-r), the
# same one, written where the test runs. The names are those programs/exchange.c asks for with
# FORMAT ref; the endpoints' reliability is the cell's stream's.
def exchange_profiles(stream):
    kind = "RELIABLE" if stream == "reliable" else "BEST_EFFORT"
    endpoint = ("<%(e)s profile_name=\"ExchangeTopic__%(s)s\"><topic><kind>NO_KEY</kind>"
                "<name>ExchangeTopic</name><dataType>Exchange</dataType></topic>"
                "<qos><reliability><kind>%(k)s</kind></reliability></qos></%(e)s>")
    return ("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
            "<dds xmlns=\"http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles\"><profiles>\n"
            "<participant profile_name=\"participant\"><rtps><name>exchange</name></rtps></participant>\n"
            "<topic profile_name=\"ExchangeTopic__t\"><name>ExchangeTopic</name>"
            "<dataType>Exchange</dataType></topic>\n"
            + endpoint % {"e": "data_writer", "s": "dw", "k": kind} + "\n"
            + endpoint % {"e": "data_reader", "s": "dr", "k": kind} + "\n"
            "</profiles></dds>\n")


# The same exchange in -m dds, once per creation kind, recorded between eProsima's client and
# eProsima's agent (started with -m dds and, by reference, -r the profiles above) over UDP4 and
# replayed against a real ``xrce-agent -m dds``. The writer waits DDS_SETTLE_MS after its creations
# so both agents' readers have matched its writer before the first sample. The recording's
# participants are in DDS_RECORDED_DOMAIN; a replay moves them to its own leased domain.
DDS_SETTLE_MS = 1500
DDS_RECORDED_DOMAIN = 0
DDS_EXCHANGES = {"dds_exchange_reliable_10_%s_udp4" % fmt: ("udp4", ("reliable", 10, 64, 0, fmt))
                 for fmt in ("bin", "xml", "ref")}
