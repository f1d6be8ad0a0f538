# A topic's type hash declared at creation, so that the agent names a board whose classes come
# from another .msg than its package before any sample (xrce/agent/engine/type_drift.py).
#
#     from xrce.client.type_hash import create_writer, create_reader
#     ticks = create_writer(session, node, "/wheel_ticks", WheelTicks, reliable=False)
#
# The same calls as Session.create_writer / create_reader, whose datawriter or datareader then
# carries ``typehash=RIHS01_<hex>;`` in its QoS's user data: rmw's USER_DATA form of the hash
# ROS 2 endpoints carry, in the optional user_data field of the binary representation's
# EndpointQos (DDS-XRCE). eProsima's agent 2.4.3 reads that field and leaves it unused, so a board
# doing this still works with it; rmw_microxrcedds sends no hash at all. The hash is the one
# rosidl computes from the .msg (`xrce-client gen-msgs` writes xrce/msgs/<package>/_hashes.py
# with rosidl's own code); it is read from there once per call and that module dropped again.
# Nothing imports this module unless the board does: a board that declares no hash pays nothing.
# Topics only: the binary representation of a requester or replier has no QoS to carry it.

import sys


def type_hash(msg_class):
    # The RIHS01 string of ``msg_class`` from its package's _hashes module; ValueError if none.
    package, _, name = msg_class.ROS_TYPE.split("/")
    module = "xrce.msgs.%s._hashes" % package
    try:
        hashes = __import__(module, None, None, ("HASHES",)).HASHES
    except ImportError:
        raise ValueError("%s has no type hashes: generate its classes with xrce-client gen-msgs on "
                         "a host with ROS's rosidl" % package)
    finally:
        sys.modules.pop(module, None)
    if name not in hashes:
        raise ValueError("no type hash for %s" % msg_class.ROS_TYPE)
    return hashes[name]


def endpoint_qos(msg_class, reliable=True, depth=10, transient_local=False):
    # The EndpointQos of Session.create_writer/create_reader's flags, with the hash as user data.
    from xrce.wire.constants import QOS_KEEP_LAST, QOS_RELIABLE, QOS_TRANSIENT_LOCAL
    from xrce.wire.objects import EndpointQos

    flags = QOS_KEEP_LAST | (QOS_RELIABLE if reliable else 0) | (QOS_TRANSIENT_LOCAL if transient_local else 0)
    return EndpointQos(flags, depth or None, user_data=b"typehash=" + type_hash(msg_class).encode() + b";")


def _dds_topic(topic):
    # As Session.create_writer names a ROS topic in DDS (rt/...); not imported from
    # xrce.client.entities, which the session loads and drops per call itself.
    return "rt" + (topic if topic.startswith("/") else "/" + topic)


def create_writer(session, node, topic, msg_class, reliable=True, depth=10, transient_local=False,
                  stream_id=None):
    qos = endpoint_qos(msg_class, reliable, depth, transient_local)
    topic_id = session.create_topic(node, _dds_topic(topic), msg_class.TYPE_NAME, stream_id=stream_id)
    publisher = session.create_publisher(node, stream_id=stream_id)
    return session.create_datawriter(publisher, topic_id, qos, stream_id=stream_id)


def create_reader(session, node, topic, msg_class, callback, reliable=True, depth=10,
                  transient_local=False, stream_id=None, data_stream_id=None, into=None):
    qos = endpoint_qos(msg_class, reliable, depth, transient_local)
    topic_id = session.create_topic(node, _dds_topic(topic), msg_class.TYPE_NAME, stream_id=stream_id)
    subscriber = session.create_subscriber(node, stream_id=stream_id)
    reader = session.create_datareader(subscriber, topic_id, qos, stream_id=stream_id)
    session.set_reader_callback(reader, callback, msg_class if into is None else into)
    if data_stream_id is None:
        data_stream_id = session.reliable if reliable else session.best_effort
    session.read_data(reader, data_stream_id, stream_id=stream_id)
    return reader
