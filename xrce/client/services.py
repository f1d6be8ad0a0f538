# ROS services on a client session: requesters and repliers (micro-ROS' ``rq/…Request`` /
# ``rr/…Reply`` naming), their requests and replies.
#
# ``Session`` forwards ``create_requester``, ``create_replier``, ``create_service_client``,
# ``create_service_server``, ``send_request`` and ``send_reply`` here on first use, so a board that
# uses no service never loads this module.

from xrce import DecodeError, const
from xrce.wire.cdr import CdrWriter
from xrce.client.session import _decode_sample

_OBJK_REQUESTER = const(0x07)
_OBJK_REPLIER = const(0x08)
_REUSE_REPLACE = const(0x06)
_SAMPLE_IDENTITY_SIZE = const(24)


def _blob(service_name, request_type, reply_type, request_topic, reply_topic):
    # Requester and replier share one binary representation (XRCE-WIRE.md §4).
    w = CdrWriter(bytearray(128))
    w.string(service_name)
    w.string(request_type)
    w.string(reply_type)
    for topic in (request_topic, reply_topic):
        w.u8(topic is not None)
        if topic is not None:
            w.string(topic)
    return w.getvalue()


def _endpoint(session, kind, participant_id, service_name, request_type, reply_type, request_topic,
              reply_topic, xml, ref, object_id, stream_id, flags):
    blob = None
    if xml is None and ref is None:
        blob = _blob(service_name, request_type, reply_type, request_topic, reply_topic)
    return session._create(kind, blob, participant_id, object_id, stream_id, flags, xml, ref)


def create_requester(session, participant_id, service_name=None, request_type=None, reply_type=None,
                     request_topic=None, reply_topic=None, xml=None, ref=None, object_id=None,
                     stream_id=None, flags=_REUSE_REPLACE):
    return _endpoint(session, _OBJK_REQUESTER, participant_id, service_name, request_type, reply_type,
                     request_topic, reply_topic, xml, ref, object_id, stream_id, flags)


def create_replier(session, participant_id, service_name=None, request_type=None, reply_type=None,
                   request_topic=None, reply_topic=None, xml=None, ref=None, object_id=None,
                   stream_id=None, flags=_REUSE_REPLACE):
    return _endpoint(session, _OBJK_REPLIER, participant_id, service_name, request_type, reply_type,
                     request_topic, reply_topic, xml, ref, object_id, stream_id, flags)


def create_service_client(session, participant_id, service, srv, callback, stream_id=None,
                          data_stream_id=None):
    """A client of the ROS service ``service`` ('/add_two_ints'), named as micro-ROS names it.

    ``srv`` is a generated service descriptor (``from xrce.msgs.example_interfaces import
    AddTwoInts``: ``Request``, ``Response``, ``TYPE_NAME_*``). Returns the requester's id for
    ``session.send_request(requester_id, srv.Request(...))``, which returns a request id;
    ``callback(request_id, response)`` gets each reply with that id while the session spins.
    """
    return _service_endpoint(session, create_requester, participant_id, service, srv, callback,
                             srv.Response, stream_id, data_stream_id)


def create_service_server(session, participant_id, service, srv, callback, stream_id=None,
                          data_stream_id=None):
    """A server of the ROS service ``service`` ('/set_led'); returns the replier's id.

    ``callback(sample_identity, request)`` gets each request (a ``srv.Request``) while the session
    spins and answers with ``session.send_reply(replier_id, sample_identity, srv.Response(...))``,
    then or later (keep ``sample_identity``, 24 bytes, to answer after the callback returns).
    """
    return _service_endpoint(session, create_replier, participant_id, service, srv, callback,
                             srv.Request, stream_id, data_stream_id)


def _service_endpoint(session, create, participant_id, service, srv, callback, msg_class, stream_id,
                      data_stream_id):
    name = service if service.startswith("/") else "/" + service
    object_id = create(session, participant_id, name, srv.TYPE_NAME_REQUEST, srv.TYPE_NAME_RESPONSE,
                       "rq" + name + "Request", "rr" + name + "Reply", stream_id=stream_id)
    session.set_reader_callback(object_id, callback, msg_class)
    session.read_data(object_id, session.reliable if data_stream_id is None else data_stream_id,
                      stream_id=stream_id)
    return object_id


def send_request(session, requester_id, data, stream_id=None):
    """Send a request (a ``srv.Request``); its reply reaches the client's callback with the
    request id returned here."""
    return session._write_sample(requester_id, data, None, stream_id)


def send_reply(session, replier_id, sample_identity, data, stream_id=None):
    """Answer the request ``sample_identity`` (as given to the server's callback) with ``data``
    (a ``srv.Response``)."""
    return session._write_sample(replier_id, data, sample_identity, stream_id)


def deliver(kind, callback, msg_class, data):
    # DATA for a requester (a reply after its request id) or a replier (a request after its
    # sample identity), handed to the endpoint's callback.
    if kind == _OBJK_REQUESTER:
        if len(data) < 4:
            raise DecodeError("reply without its request id")
        callback((data[0] << 8) | data[1], _decode_sample(msg_class, data[4:]))
    else:
        if len(data) < _SAMPLE_IDENTITY_SIZE:
            raise DecodeError("request without its sample identity")
        callback(bytes(data[:_SAMPLE_IDENTITY_SIZE]), _decode_sample(msg_class, data[_SAMPLE_IDENTITY_SIZE:]))
