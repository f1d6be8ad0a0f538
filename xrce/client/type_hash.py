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
    finally:  # dropped again, from the package's namespace too (where the import put it)
        sys.modules.pop(module, None)
        parent = sys.modules.get("xrce.msgs." + package)
        if parent is not None:
            parent.__dict__.pop("_hashes", None)
    if name not in hashes:
        raise ValueError("no type hash for %s" % msg_class.ROS_TYPE)
    return hashes[name]


def user_data(msg_class):
    # rmw's USER_DATA form of the hash: b"typehash=RIHS01_<hex>;".
    return b"typehash=" + type_hash(msg_class).encode() + b";"


def _dds_topic(topic):
    # As Session.create_writer names a ROS topic in DDS (rt/...): xrce.client.entities'
    # ros_topic_name, which importing here would keep loaded.
    return "rt" + (topic if topic.startswith("/") else "/" + topic)


def _endpoint(session, kind, tail_id, topic_id, msg_class, reliable, depth, transient_local, stream_id):
    # The session's own creation (xrce.client.entities, loaded for the call as the session loads
    # it, or the one hold_set_up() holds), given the blob with the hash.
    from xrce.client.session import _set_up_module

    flags = 0x0002 | (0x0001 if reliable else 0) | (0x0008 if transient_local else 0)  # keep last
    entities = session._held or _set_up_module("entities")
    blob = entities.endpoint_blob(topic_id, flags, depth or None, kind == 0x06, user_data(msg_class))
    return entities._create(session, kind, blob, tail_id, None, stream_id, 0x06)  # reuse | replace


def create_writer(session, node, topic, msg_class, reliable=True, depth=10, transient_local=False,
                  stream_id=None):
    topic_id = session.create_topic(node, _dds_topic(topic), msg_class.TYPE_NAME, stream_id=stream_id)
    publisher = session.create_publisher(node, stream_id=stream_id)
    return _endpoint(session, 0x05, publisher, topic_id, msg_class, reliable, depth, transient_local,
                     stream_id)


def create_reader(session, node, topic, msg_class, callback, reliable=True, depth=10,
                  transient_local=False, stream_id=None, data_stream_id=None, into=None):
    topic_id = session.create_topic(node, _dds_topic(topic), msg_class.TYPE_NAME, stream_id=stream_id)
    subscriber = session.create_subscriber(node, stream_id=stream_id)
    reader = _endpoint(session, 0x06, subscriber, topic_id, msg_class, reliable, depth, transient_local,
                       stream_id)
    session.set_reader_callback(reader, callback, msg_class if into is None else into)
    if data_stream_id is None:
        data_stream_id = session.reliable if reliable else session.best_effort
    session.read_data(reader, data_stream_id, stream_id=stream_id)
    return reader
