# Entity creation beyond the binary representations a firmware uses: XML and reference
# representations, and datawriters/datareaders with a full ``xrce.wire.objects.EndpointQos``. Loaded by
# Session on first use; a board that creates its entities in binary never pays for it.

from xrce import const

_OBJK_DATAREADER = const(0x06)
_REPRESENTATION_BY_REFERENCE = const(0x01)
_REPRESENTATION_AS_XML_STRING = const(0x02)


def textual(xml, ref):
    # ``(format, text)`` of an entity given by ``xml`` or by ``ref`` (which wins, as it always has).
    if ref is not None:
        return _REPRESENTATION_BY_REFERENCE, ref
    return _REPRESENTATION_AS_XML_STRING, xml


def endpoint_blob(kind, topic_id, qos):
    # The binary representation of a datawriter or datareader with QoS beyond (flags, depth).
    from xrce.wire.objects import DataReaderBin, DataWriterBin

    return (DataReaderBin if kind == _OBJK_DATAREADER else DataWriterBin)(topic_id, qos).to_blob()
