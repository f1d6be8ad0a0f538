"""Readable names for the wire numbers of ``xrce.wire.constants``, for logs, traces and tools.

Kept apart from the constants so that the MicroPython client does not carry these tables.
"""

SUBMESSAGE_NAMES = {
    0: "CREATE_CLIENT", 1: "CREATE", 2: "GET_INFO", 3: "DELETE", 4: "STATUS_AGENT", 5: "STATUS",
    6: "INFO", 7: "WRITE_DATA", 8: "READ_DATA", 9: "DATA", 10: "ACKNACK", 11: "HEARTBEAT",
    12: "RESET", 13: "FRAGMENT", 14: "TIMESTAMP", 15: "TIMESTAMP_REPLY",
}

OBJECT_KIND_NAMES = {
    0: "INVALID", 1: "PARTICIPANT", 2: "TOPIC", 3: "PUBLISHER", 4: "SUBSCRIBER", 5: "DATAWRITER",
    6: "DATAREADER", 7: "REQUESTER", 8: "REPLIER", 10: "TYPE", 11: "QOSPROFILE", 12: "APPLICATION",
    13: "AGENT", 14: "CLIENT", 15: "OTHER",
}

STATUS_NAMES = {
    0x00: "OK", 0x01: "OK_MATCHED", 0x80: "ERR_DDS_ERROR", 0x81: "ERR_MISMATCH",
    0x82: "ERR_ALREADY_EXISTS", 0x83: "ERR_DENIED", 0x84: "ERR_UNKNOWN_REFERENCE",
    0x85: "ERR_INVALID_DATA", 0x86: "ERR_INCOMPATIBLE", 0x87: "ERR_RESOURCES", 0xFF: "NONE",
}
