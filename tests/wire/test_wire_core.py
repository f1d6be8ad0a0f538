"""The wire core reproduces XRCE-WIRE.md's verified bytes (§3, §7, §9, §10, §13) and decodes them back.

Hex in the reference marks padding the C client leaves uninitialised as ``xx``: those bytes are
masked, every other byte must match exactly.
"""

import json
from pathlib import Path

import pytest
from hypothesis import given, settings, strategies as st

from xrce.wire import cdr, constants as C
from xrce import DecodeError
from xrce.wire.message import decode_header, iter_submessages
from xrce.wire.objects import (
    DataReaderBin, DataWriterBin, EndpointQos, ParticipantBin, PubSubBin, RequesterBin, TopicBin,
    object_id,
)
from xrce.wire.streams import seq_add, seq_less
from xrce.wire.submessages import (
    AckNack, Create, CreateClient, Data, Delete, DeliveryControl, GetInfo, Heartbeat, Info, Locator,
    ReadData, Status, StatusAgent, Timestamp, TimestampReply, WriteData, decode_message,
    encode_message,
)

KEY = bytes.fromhex("AABBCCDD")
PARTICIPANT_XML = "<dds><participant><rtps><name>default_xrce_participant</name></rtps></participant></dds>"
STRING_TYPE = "std_msgs::msg::dds_::String_"


def hexmask(text):
    """'81 80 xx' → (bytes with 0 for xx, mask of significant bytes)."""
    tokens = text.split()
    data = bytes(0 if t == "xx" else int(t, 16) for t in tokens)
    return data, [t != "xx" for t in tokens]


def assert_bytes(encoded, reference):
    expected, mask = hexmask(reference)
    assert len(encoded) == len(expected), (encoded.hex(" "), reference)
    for i, (a, b, significant) in enumerate(zip(encoded, expected, mask)):
        assert not significant or a == b, "byte %d: %02X != %02X\n%s\n%s" % (i, a, b, encoded.hex(" "), reference)


def roundtrip(encoded, session_id, stream_id, seq, key, payloads):
    header, decoded = decode_message(encoded)
    assert (header.session_id, header.stream_id, header.seq, header.key) == (session_id, stream_id, seq, key)
    assert decoded == payloads


def check(reference, session_id, stream_id, seq, key, payloads, pad=False):
    encoded = encode_message(session_id, stream_id, seq, key, payloads, pad)
    assert_bytes(encoded, reference)
    roundtrip(hexmask(reference)[0], session_id, stream_id, seq, key, payloads)


TOPIC = TopicBin("rt/chatter", STRING_TYPE)
WRITER_QOS = EndpointQos(C.QOS_RELIABLE | C.QOS_KEEP_LAST, 5)


def test_create_client_and_status_agent_unkeyed_and_keyed():
    check("80 00 00 00 00 01 10 00 58 52 43 45 01 00 01 0F AA BB CC DD 81 00 FC 01",
          0x80, 0, 0, None, [CreateClient(KEY, 0x81, 508)])
    check("00 00 00 00 AA BB CC DD 00 01 10 00 58 52 43 45 01 00 01 0F AA BB CC DD 01 00 FC 01",
          0x00, 0, 0, KEY, [CreateClient(KEY, 0x01, 508)])
    check("81 00 00 00 04 01 0B 00 00 00 58 52 43 45 01 00 01 0F 00", 0x81, 0, 0, None, [StatusAgent()])
    check("01 00 00 00 AA BB CC DD 04 01 0B 00 00 00 58 52 43 45 01 00 01 0F 00", 0x01, 0, 0, KEY,
          [StatusAgent()])


def test_create_client_with_properties_keeps_length_16():
    payload = CreateClient(KEY, 0x81, 508, properties=[("uxr_hl", "010000")])
    encoded = encode_message(0x80, 0, 0, None, [payload])
    assert encoded[6:8] == b"\x10\x00"  # the C client's length, whatever follows
    _, decoded = decode_message(encoded)
    assert decoded == [payload]


def test_participant_by_xml_m3():
    check("81 80 00 00 01 05 68 00 00 0A 00 11 01 02 00 00 59 00 00 00 "
          + PARTICIPANT_XML.encode().hex(" ") + " 00 xx 00 00",
          0x81, 0x80, 0, None,
          [Create(10, 0x0011, C.OBJK_PARTICIPANT, C.REPRESENTATION_AS_XML_STRING, PARTICIPANT_XML, 0,
                  C.FLAG_LITTLE_ENDIAN | C.FLAG_REPLACE)], pad=True)


def test_status_and_acknack_m4_m5():
    check("81 80 00 00 05 01 06 00 00 0A 00 11 00 00", 0x81, 0x80, 0, None, [Status(10, 0x0011)])
    check("81 00 00 00 0A 01 05 00 01 00 00 00 80", 0x81, 0, 0, None, [AckNack(1, 0, 0x80)])


def test_five_creates_in_one_message_m6():
    reference = (
        "81 80 01 00 "
        "01 05 43 00 00 0B 00 12 02 03 00 00 35 00 00 00 "
        "0B 00 00 00 72 74 2F 63 68 61 74 74 65 72 00 00 01 xx xx xx "
        "1D 00 00 00 " + STRING_TYPE.encode().hex(" ") + " 00 00 11 xx "
        "01 05 10 00 00 0C 00 13 03 03 00 00 02 00 00 00 00 00 00 11 "
        "01 05 1C 00 00 0D 00 15 05 03 00 00 0E 00 00 00 00 12 01 xx 03 00 01 xx 05 00 00 00 00 00 00 13 "
        "01 05 10 00 00 0E 00 14 04 03 00 00 02 00 00 00 00 00 00 11 "
        "01 05 1D 00 00 0F 00 16 06 03 00 00 0F 00 00 00 00 12 01 xx 03 00 01 xx 05 00 00 00 00 00 00 00 14 xx xx xx")
    flags = C.FLAG_LITTLE_ENDIAN | C.FLAG_REPLACE
    payloads = [
        Create(11, 0x0012, C.OBJK_TOPIC, 3, TOPIC, 0x0011, flags),
        Create(12, 0x0013, C.OBJK_PUBLISHER, 3, PubSubBin(), 0x0011, flags),
        Create(13, 0x0015, C.OBJK_DATAWRITER, 3, DataWriterBin(0x0012, WRITER_QOS), 0x0013, flags),
        Create(14, 0x0014, C.OBJK_SUBSCRIBER, 3, PubSubBin(), 0x0011, flags),
        Create(15, 0x0016, C.OBJK_DATAREADER, 3, DataReaderBin(0x0012, WRITER_QOS), 0x0014, flags),
    ]
    check(reference, 0x81, 0x80, 1, None, payloads, pad=True)
    assert len(hexmask(reference)[0]) == 184
    starts = [s - 4 for _, _, s, _ in iter_submessages(hexmask(reference)[0], 4)]
    assert starts == [4, 76, 96, 128, 148]


def test_read_write_data_m7_m8_m9():
    check("81 80 02 00 08 01 10 00 00 10 00 16 80 00 00 01 FF FF 00 00 00 00 00 00", 0x81, 0x80, 2, None,
          [ReadData(16, 0x0016, 0x80, DeliveryControl())])
    hi = bytes.fromhex("03000000686900")
    check("81 80 03 00 07 01 0B 00 00 11 00 15 03 00 00 00 68 69 00 xx", 0x81, 0x80, 3, None,
          [WriteData(17, 0x0015, hi)], pad=True)
    check("81 80 06 00 09 01 0B 00 00 10 00 16 03 00 00 00 68 69 00", 0x81, 0x80, 6, None,
          [Data(16, 0x0016, hi)])
    check("81 01 00 00 07 01 0B 00 00 12 00 15 03 00 00 00 68 69 00 xx", 0x81, 0x01, 0, None,
          [WriteData(18, 0x0015, hi)], pad=True)


def test_keyed_variant_m3():
    encoded = encode_message(0x01, 0x80, 0, KEY, [
        Create(10, 0x0011, C.OBJK_PARTICIPANT, 2, PARTICIPANT_XML, 0, 5)], pad=True)
    assert encoded[:12] == bytes.fromhex("01800000AABBCCDD01056800")


def test_micro_ros_flavoured_sequence():
    flags = C.FLAG_LITTLE_ENDIAN | C.FLAG_REUSE | C.FLAG_REPLACE
    check("81 80 00 00 01 07 1E 00 00 0A 00 01 01 03 00 00 0F 00 00 00 00 01 00 00 07 00 00 00 "
          "74 61 6C 6B 65 72 00 00 00 00 xx xx", 0x81, 0x80, 0, None,
          [Create(10, 0x0001, C.OBJK_PARTICIPANT, 3, ParticipantBin("talker"), 0, flags)], pad=True)
    check("81 80 02 00 01 07 10 00 00 0C 00 03 03 03 00 00 02 00 00 00 00 00 00 01", 0x81, 0x80, 2, None,
          [Create(12, 0x0003, C.OBJK_PUBLISHER, 3, PubSubBin(), 0x0001, flags)], pad=True)
    check("81 80 03 00 01 07 1C 00 00 0D 00 05 05 03 00 00 0E 00 00 00 00 02 01 xx 03 00 01 xx 0A 00 00 00 00 00 00 03",
          0x81, 0x80, 3, None,
          [Create(13, 0x0005, C.OBJK_DATAWRITER, 3, DataWriterBin(0x0002, EndpointQos(3, 10)), 0x0003, flags)],
          pad=True)
    check("81 80 07 00 08 01 10 00 00 11 00 06 80 00 00 01 FF FF 00 00 00 00 00 00 "
          "07 01 0B 00 00 12 00 05 03 00 00 00 68 69 00 xx", 0x81, 0x80, 7, None,
          [ReadData(17, 0x0006, 0x80, DeliveryControl()), WriteData(18, 0x0005, bytes.fromhex("03000000686900"))],
          pad=True)


def test_delete_client_ping_and_info():
    check("81 00 00 00 03 01 04 00 00 02 FF FE", 0x81, 0, 0, None, [Delete(2, C.OBJECTID_CLIENT)])
    check("81 00 00 00 05 01 06 00 00 02 FF FE 00 00", 0x81, 0, 0, None, [Status(2, C.OBJECTID_CLIENT)])
    check("80 00 00 00 02 01 08 00 00 0A FF FD 02 00 00 00", 0x80, 0, 0, None, [GetInfo()])
    check("80 00 00 00 06 01 1C 00 00 0A FF FD 00 00 01 0D 58 52 43 45 01 00 01 0F 00 01 0D 00 01 00 00 00 00 00 00 00",
          0x80, 0, 0, None, [Info(10)])
    check("80 00 00 00 06 01 2C 00 00 09 FF FD 00 00 01 0D 58 52 43 45 01 00 01 0F 00 01 0D 00 01 00 00 00 "
          "02 00 00 00 01 7F 00 00 01 xx E6 07 01 C0 00 02 02 xx E6 07", 0x80, 0, 0, None,
          [Info(9, locators=[Locator(1, bytes([127, 0, 0, 1]), 2022), Locator(1, bytes([192, 0, 2, 2]), 2022)])])


def test_timestamp_exchange_and_offset():
    t0 = 1795341880 * 10**9 + 706827427
    check("81 00 00 00 0E 01 08 00 38 BE 02 6B A3 54 21 2A", 0x81, 0, 0, None, [Timestamp.from_ns(t0)])
    reply = TimestampReply(1795341880 * 10**9 + 707130879, 1795341880 * 10**9 + 707129967, t0)
    check("81 00 00 00 0F 01 18 00 38 BE 02 6B FF F5 25 2A 38 BE 02 6B 6F F2 25 2A 38 BE 02 6B A3 54 21 2A",
          0x81, 0, 0, None, [reply])
    t3 = t0 + 1000000
    assert ((t0 + t3) - (reply.receive_ns + reply.transmit_ns)) // 2 == 197004  # the reference's figure


def test_heartbeat_and_nack_of_the_loss_example():
    check("81 00 00 00 0B 01 05 00 01 00 01 00 80", 0x81, 0, 0, None, [Heartbeat(1, 1, 0x80)])
    check("81 00 00 00 0A 01 05 00 01 00 00 01 80", 0x81, 0, 0, None, [AckNack(1, 0x0001, 0x80)])


def test_object_ids_and_sequence_numbers():
    assert object_id(1, C.OBJK_PARTICIPANT) == 0x0011
    assert object_id(1, C.OBJK_DATAREADER) == 0x0016
    assert object_id(0, C.OBJK_PARTICIPANT) == 0x0001
    assert seq_less(65535, 0) and not seq_less(0, 65535) and seq_add(65535, 1) == 0
    assert seq_less(1, 32768) and not seq_less(1, 32770)


def test_requester_blob_roundtrip_and_padding_fill_is_only_padding():
    blob = RequesterBin("add_two_ints", "example_interfaces::srv::dds_::AddTwoInts_Request_",
                        "example_interfaces::srv::dds_::AddTwoInts_Response_", "rq/add_two_intsRequest",
                        "rr/add_two_intsReply")
    assert RequesterBin.from_blob(blob.to_blob()) == blob
    try:
        cdr.PAD_FILL = 0xAA
        padded = encode_message(0x81, 0x80, 1, None, [Create(11, 0x0012, 2, 3, TOPIC, 0x11, 5)], True)
    finally:
        cdr.PAD_FILL = 0
    _, decoded = decode_message(padded)
    assert decoded[0].representation == TOPIC


GOLDEN = json.loads((Path(__file__).parents[1] / "golden" / "wire_captures.json").read_text())
GOLDEN_DATAGRAMS = [bytes.fromhex(d["hex"]) for ds in GOLDEN["scenarios"].values() for d in ds]


def _masked_equal(original, session_id, stream_id, seq, key, payloads, pad):
    """Encode twice with different padding fills: bytes that change are padding, the rest must match."""
    try:
        cdr.PAD_FILL = 0x00
        a = encode_message(session_id, stream_id, seq, key, payloads, pad)
        cdr.PAD_FILL = 0xFF
        b = encode_message(session_id, stream_id, seq, key, payloads, pad)
    finally:
        cdr.PAD_FILL = 0
    return len(a) == len(original) and all(x == y or x != z for x, y, z in zip(a, original, b))


@pytest.mark.parametrize("datagram", GOLDEN_DATAGRAMS, ids=lambda d: d[:12].hex())
def test_every_golden_datagram_decodes_and_reencodes(datagram):
    header, payloads = decode_message(datagram)
    pads = (False, True) if header.stream_id else (False,)
    assert any(_masked_equal(datagram, header.session_id, header.stream_id, header.seq, header.key,
                             payloads, pad) for pad in pads)


@settings(max_examples=3000, deadline=None)
@given(st.binary(max_size=300))
def test_random_bytes_raise_only_decode_error(data):
    try:
        decode_message(data)
    except DecodeError:
        pass


@settings(max_examples=3000, deadline=None)
@given(st.sampled_from(GOLDEN_DATAGRAMS), st.data())
def test_mutated_golden_datagrams_raise_only_decode_error(datagram, data):
    mutated = bytearray(datagram)
    for _ in range(data.draw(st.integers(1, 6))):
        op = data.draw(st.sampled_from(["flip", "truncate", "insert"]))
        if op == "flip" and mutated:
            i = data.draw(st.integers(0, len(mutated) - 1))
            mutated[i] ^= 1 << data.draw(st.integers(0, 7))
        elif op == "truncate" and mutated:
            del mutated[data.draw(st.integers(0, len(mutated) - 1)):]
        else:
            mutated.insert(data.draw(st.integers(0, len(mutated))), data.draw(st.integers(0, 255)))
    try:
        decode_message(bytes(mutated))
    except DecodeError:
        pass


@settings(max_examples=1000, deadline=None)
@given(st.sampled_from([ParticipantBin, TopicBin, PubSubBin, DataWriterBin, DataReaderBin, RequesterBin]),
       st.binary(max_size=80))
def test_blob_decoders_raise_only_decode_error(blob_class, data):
    try:
        blob_class.from_blob(data)
    except DecodeError:
        pass


def test_header_needs_its_key():
    with pytest.raises(DecodeError):
        decode_header(b"\x01\x80\x00\x00\xAA")
