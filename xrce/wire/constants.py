"""Numbers of the XRCE wire (XRCE-WIRE.md §1, §2, §4, §5, §10)."""

from xrce import const

# Session ids (§1)
SESSION_ID_NONE_WITH_KEY = const(0x00)
SESSION_ID_NONE_WITHOUT_KEY = const(0x80)
SESSION_ID_WITHOUT_KEY_MASK = const(0x80)
DEFAULT_SESSION_ID = const(0x81)

# Stream ids (§1)
STREAM_NONE = const(0x00)
BUILTIN_BEST_EFFORT = const(0x01)
BUILTIN_RELIABLE = const(0x80)

# Submessage ids (§2)
CREATE_CLIENT = const(0)
CREATE = const(1)
GET_INFO = const(2)
DELETE = const(3)
STATUS_AGENT = const(4)
STATUS = const(5)
INFO = const(6)
WRITE_DATA = const(7)
READ_DATA = const(8)
DATA = const(9)
ACKNACK = const(10)
HEARTBEAT = const(11)
RESET = const(12)
FRAGMENT = const(13)
TIMESTAMP = const(14)
TIMESTAMP_REPLY = const(15)


# Submessage flags (§2)
FLAG_LITTLE_ENDIAN = const(0x01)
FLAG_REUSE = const(0x02)
FLAG_REPLACE = const(0x04)
FLAG_LAST_FRAGMENT = const(0x02)
FLAG_FORMAT_MASK = const(0x0E)
FORMAT_DATA = const(0x00)

# Object kinds (§4)
OBJK_INVALID = const(0x00)
OBJK_PARTICIPANT = const(0x01)
OBJK_TOPIC = const(0x02)
OBJK_PUBLISHER = const(0x03)
OBJK_SUBSCRIBER = const(0x04)
OBJK_DATAWRITER = const(0x05)
OBJK_DATAREADER = const(0x06)
OBJK_REQUESTER = const(0x07)
OBJK_REPLIER = const(0x08)
OBJK_TYPE = const(0x0A)
OBJK_QOSPROFILE = const(0x0B)
OBJK_APPLICATION = const(0x0C)
OBJK_AGENT = const(0x0D)
OBJK_CLIENT = const(0x0E)
OBJK_OTHER = const(0x0F)


# Predefined object ids (§4)
OBJECTID_INVALID = const(0x0000)
OBJECTID_AGENT = const(0xFFFD)
OBJECTID_CLIENT = const(0xFFFE)
OBJECTID_SESSION = const(0xFFFF)

# Representation formats (§4)
REPRESENTATION_BY_REFERENCE = const(0x01)
REPRESENTATION_AS_XML_STRING = const(0x02)
REPRESENTATION_IN_BINARY = const(0x03)

# Status codes (§5)
STATUS_OK = const(0x00)
STATUS_OK_MATCHED = const(0x01)
STATUS_ERR_DDS_ERROR = const(0x80)
STATUS_ERR_MISMATCH = const(0x81)
STATUS_ERR_ALREADY_EXISTS = const(0x82)
STATUS_ERR_DENIED = const(0x83)
STATUS_ERR_UNKNOWN_REFERENCE = const(0x84)
STATUS_ERR_INVALID_DATA = const(0x85)
STATUS_ERR_INCOMPATIBLE = const(0x86)
STATUS_ERR_RESOURCES = const(0x87)
STATUS_NONE = const(0xFF)  # local only: "no reply yet"


# Request ids with a fixed meaning (§2)
REQUEST_ID_INVALID = const(0x0000)
REQUEST_ID_LOGIN = const(0x0001)
REQUEST_ID_LOGOUT = const(0x0002)
REQUEST_ID_DISCOVERY = const(0x0009)
REQUEST_ID_PING = const(0x000A)
FIRST_REQUEST_ID = const(0x000A)

# GET_INFO mask (§2)
INFO_CONFIGURATION = const(0x01)
INFO_ACTIVITY = const(0x02)

# TransportLocator formats (§10)
LOCATOR_SMALL = const(0)
LOCATOR_MEDIUM = const(1)
LOCATOR_LARGE = const(2)
LOCATOR_STRING = const(3)

# CLIENT_Representation constants (§3)
XRCE_COOKIE = b"XRCE"
XRCE_VERSION = b"\x01\x00"
XRCE_VERSION_MAJOR = const(0x01)
XRCE_VENDOR_EPROSIMA = b"\x01\x0F"

# Endpoint QoS flags (§4)
QOS_RELIABLE = const(0x0001)
QOS_KEEP_LAST = const(0x0002)
QOS_OWNERSHIP_EXCLUSIVE = const(0x0004)
QOS_TRANSIENT_LOCAL = const(0x0008)
QOS_TRANSIENT = const(0x0010)
QOS_PERSISTENT = const(0x0020)

# DataDeliveryControl max_samples meaning "no limit" (§6)
MAX_SAMPLES_UNLIMITED = const(0xFFFF)
