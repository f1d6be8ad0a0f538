"""How what others can read names a client and where it sends from: the stats port, the
``-v 5`` summary, ``/diagnostics``, capture files and the ROS node names of unnamed participants.

Only the standard library: the engine (session log lines, admission) and the middleware name
clients this way too, and the capture writer without the rest of observability.
"""

import os

try:  # the BLAKE2 core alone: hashlib would load OpenSSL for nothing
    from _blake2 import blake2b
except ImportError:
    from hashlib import blake2b

# A client key is the only credential of an XRCE session: with it, anyone who can send a
# datagram to the agent can delete or take over that session. What others can read (/diagnostics:
# the whole ROS domain; the stats port: any local user; capture files, which travel with bug
# reports) names a client by a tag instead: the first 4 bytes of BLAKE2b keyed with a secret drawn
# at agent start. Keyed, because a key has only 2**32 values: a plain hash prefix is undone by
# hashing them all, in minutes. Per run, because the secret is never stored: the same client has
# the same tag for the agent's whole run (and its capture files), a new one after a restart. The
# operator's log names the key with its tag when the session is created, as a lookup table.
_TAG_SECRET = os.urandom(16)


def client_pseudonym(key: bytes) -> bytes:
    """4 bytes that stand for client ``key`` in what others can read (see above)."""
    return blake2b(bytes(key), digest_size=4, key=_TAG_SECRET).digest()


def client_tag(key: bytes) -> str:
    """``client_pseudonym`` as 8 hex digits: how stats, /diagnostics and node names show a key."""
    return client_pseudonym(key).hex()


def endpoint_text(endpoint) -> str:
    """A link endpoint as one word (capture files split on spaces). An IPv6 address goes in
    brackets, as in a URL: its own colons would run into the port's otherwise (a link-local
    one keeps its ``%scope``, which the socket puts in the host)."""
    if isinstance(endpoint, tuple) and len(endpoint) >= 2:
        host = endpoint[0]
        return ("[%s]:%s" if ":" in str(host) else "%s:%s") % (host, endpoint[1])
    return str(endpoint).replace(" ", "")


def address_text(link_name: str, endpoint) -> str:
    """Where a client talks from, as a user would look for it: ``udp4 192.168.1.7:41234``,
    ``serial /dev/ttyACM0`` (a serial endpoint is the device and the frame's source address,
    which boards leave at 0: named only when it is not)."""
    if isinstance(endpoint, tuple) and len(endpoint) == 2 and str(endpoint[0]).startswith("/"):
        device, source = endpoint
        return "%s %s" % (link_name, device) if not source else \
            "%s %s (frame address %s)" % (link_name, device, source)
    return "%s %s" % (link_name, endpoint_text(endpoint))


# The ROS 2 DDS mapping's prefixes (XRCE-WIRE.md §4): what ROS tools call the topic. Standard
# library only, unlike xrce.agent.middleware.ros.types: stats and logs of a -m ced agent use it.
_ROS_PREFIXES = {"rt/": "", "rq/": "Request", "rr/": "Reply"}


def ros_topic_name(dds_name: str) -> str:
    """``rt/chatter`` -> ``/chatter``, ``rq/add_two_intsRequest`` -> ``/add_two_ints``; a name
    without a ROS prefix is a DDS-level topic and stays as it is."""
    prefix = dds_name[:3]
    suffix = _ROS_PREFIXES.get(prefix)
    if suffix is None or not dds_name.endswith(suffix):
        return dds_name
    name = dds_name[3:len(dds_name) - len(suffix)]
    return name if name.startswith("/") else "/" + name


def ros_type_name(dds_type: str) -> str:
    """``std_msgs::msg::dds_::String_`` -> ``std_msgs/msg/String``; other spellings unchanged."""
    parts = dds_type.split("::")
    if len(parts) == 4 and parts[2] == "dds_" and parts[3].endswith("_"):
        return "%s/%s/%s" % (parts[0], parts[1], parts[3][:-1])
    return dds_type


def object_id_text(object_id: int) -> str:
    """An XRCE object id as eProsima's agent logs it: ``0x001(5)`` is id 1 of kind 5."""
    return "0x%03X(%d)" % (object_id >> 4, object_id & 0x0F)


def qos_text(qos) -> str:
    """An endpoint's QoS (``xrce.agent.middleware.EndpointQosSpec``) in the words of ROS:
    ``reliable, volatile, keep_last 10``."""
    return "%s, %s, %s" % ("reliable" if qos.reliable else "best_effort", qos.durability,
                           "keep_last %d" % qos.depth if qos.keep_last else "keep_all")
