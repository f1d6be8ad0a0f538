"""Stand-ins for ROS interface classes made from a package's C libraries, for rclpy to exchange
CDR bytes instead of Python messages (CPython agent only).

The agent never needs a Python message: samples, requests and replies cross as their CDR bytes.
rclpy only reads a class's type support and its conversion functions from its metaclass, so a
class that carries the C type support of ``lib<pkg>__rosidl_typesupport_c.so`` and conversions
of the compiled helper (``xrce.agent.middleware.ros._rostypes``, see ``compiled``) serves,
without importing the package's generated Python code (its classes, numpy for arrays,
rosidl_generator_py's libraries). Where the helper or a library is missing, the generated
classes serve (``types``).
"""

from __future__ import annotations

import types

from xrce.agent.middleware import UnknownTypeError
from xrce.agent.middleware.ros import compiled
from xrce.agent.middleware.ros.types import (
    _ACTION_MESSAGES, _ACTION_SERVICES, BUILD_HINT, _check_package, _import_module, _split_type,
    log, package_present, split_service_type,
)


class _RawTypeMeta(type):
    """What rclpy reads from a message class's metaclass to create a publisher or subscription."""

    _TYPE_SUPPORT = None
    _CREATE_ROS_MESSAGE = None
    _CONVERT_FROM_PY = None
    _CONVERT_TO_PY = None
    _DESTROY_ROS_MESSAGE = None


_raw_types: dict = {}  # dds type name -> raw type handle
_typesupport_names: dict = {}  # package -> {lower-case type name without "_": function suffix}


def _typesupport_c_library(package: str):
    """``lib<package>__rosidl_typesupport_c.so``'s path (``<prefix>/lib`` beside the package's
    Python code, or the agent's own build of it), the package's C libraries it needs loaded;
    None if there is none."""
    import importlib.util
    import os

    from xrce.agent.interfaces.registry import c_typesupport_library

    library = c_typesupport_library(package)  # a package the agent built
    if library is None:
        try:  # a top-level package's spec: its __init__ is not run
            spec = importlib.util.find_spec(package)
        except (ImportError, ValueError):
            return None
        locations = spec.submodule_search_locations if spec is not None else None
        if not locations:
            return None
        # <prefix>/lib/pythonX.Y/site-packages/<package> -> <prefix>/lib
        library = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(locations[0]))),
                               "lib%s__rosidl_typesupport_c.so" % package)
    return library if os.path.isfile(library) else None


def _library_type_support(package: str, type_name: str):
    """The metaclass attributes of a raw type: the C type support capsule of ``package``'s message
    ``type_name`` straight from ``lib<package>__rosidl_typesupport_c.so`` (``<prefix>/lib`` beside
    its Python code) through the agent's compiled helper (``_rostypes.message_type_support``), and
    conversions that refuse to run (``_rostypes.raw_type_conversions``). None when the helper or
    the library is missing or the name is not found: the package's Python type support module
    serves then. Raw publishers and subscriptions need only the type support; that module also
    loads the rosidl_generator_py libraries of the package and of each one it depends on, 2-3 ms
    of the ~3 ms a firmware's first topic of a package took to create (bench/microros/entity_creation.py)
    and about 0.12 MB resident per package."""
    helper = compiled.helper()
    if helper is None:
        return None
    load = helper.message_type_support
    conversions = helper.raw_type_conversions
    library = _typesupport_c_library(package)
    if library is None:
        return None
    try:
        type_support = load(library, "rosidl_typesupport_c__get_message_type_support_handle__"
                            "%s__msg__%s" % (package, type_name))
    except ImportError as exc:
        log.debug("%s/%s: no type support in %s (%s); the Python module's", package, type_name,
                  library, exc)
        return None
    create, from_py, to_py, destroy = conversions()
    return {"_TYPE_SUPPORT": type_support, "_CREATE_ROS_MESSAGE": create,
            "_CONVERT_FROM_PY": from_py, "_CONVERT_TO_PY": to_py, "_DESTROY_ROS_MESSAGE": destroy}


def raw_message_type(dds_type: str):
    """A stand-in for the message class of ``dds_type`` that rclpy accepts for publishers and
    raw subscriptions, made from the package's C type support module alone.

    The agent never builds a Python message: samples cross as CDR bytes (``publish_raw``, raw
    subscriptions). The generated Python classes are only needed to convert messages, yet
    importing one (and calling its ``__import_type_support__``) imports numpy for any type with a
    fixed-size array (Imu, Odometry: +11 MB), every dependent package's Python classes, and
    rosidl_generator_py's code generator with lark and empy (+5 MB): measured 23 MB for Imu and
    Odometry this way, 2 MB through their C type support modules.
    """
    handle = _raw_types.get(dds_type)
    if handle is not None:
        return handle
    package, kind, type_name = _split_type(dds_type)
    if kind == "action":
        # An action's feedback (and goal/result) messages: "Fibonacci_FeedbackMessage".
        if type_name.partition("_")[2] not in _ACTION_MESSAGES:
            raise UnknownTypeError("%r is not a message of an action (one of %s)"
                                   % (dds_type, ", ".join("X_" + n for n in _ACTION_MESSAGES)))
    elif kind != "msg":
        raise UnknownTypeError("%r is not a message type" % dds_type)
    if not package_present(package, dds_type):
        return named_message_type(dds_type, package, kind, type_name)
    attributes = _library_type_support(package, type_name)
    if attributes is not None:
        meta = type("Metaclass_" + type_name, (_RawTypeMeta,), attributes)
        handle = _raw_types[dds_type] = meta(type_name, (), {"__module__": "%s.msg" % package,
                                                             "__slots__": ()})
        return handle
    module = _import_module(package, "%s.%s_s__rosidl_typesupport_c" % (package, package))
    names = _typesupport_names.get((package, kind))
    if names is None:
        # Functions are named after the type in snake case ("type_support_msg__msg__tf_message"
        # for TFMessage, "type_support_msg__action__fibonacci__feedback_message" for
        # Fibonacci_FeedbackMessage); CamelCase type names have no "_", so dropping it and the
        # case is unique.
        prefix = "type_support_msg__%s__" % kind
        names = {name[len(prefix):].replace("_", ""): name[len(prefix):]
                 for name in dir(module) if name.startswith(prefix)}
        _typesupport_names[(package, kind)] = names
    wanted = type_name.lower()
    if kind == "action":  # "Fibonacci_FeedbackMessage": the one "_" between action and part
        wanted = wanted.replace("_", "", 1)
    suffix = names.get(wanted)
    if suffix is None:
        raise UnknownTypeError("%s.%s has no interface %s: %s if it was added recently"
                               % (package, kind, type_name, BUILD_HINT))
    functions = {"_TYPE_SUPPORT": "type_support", "_CREATE_ROS_MESSAGE": "create_ros_message",
                 "_CONVERT_FROM_PY": "convert_from_py", "_CONVERT_TO_PY": "convert_to_py",
                 "_DESTROY_ROS_MESSAGE": "destroy_ros_message"}
    meta = type("Metaclass_" + type_name, (_RawTypeMeta,),
                {attribute: getattr(module, "%s_msg__%s__%s" % (function, kind, suffix))
                 for attribute, function in functions.items()})
    handle = meta(type_name, (), {"__module__": "%s.%s" % (package, kind), "__slots__": ()})
    _raw_types[dds_type] = handle
    return handle


class RawReply:
    """A service reply as its CDR bytes (``cdr``, encapsulation first) for rclpy's
    ``send_response``: the compiled helper's conversion (``_rostypes.raw_reply_conversion``)
    deserializes them straight into the C message rclpy sends."""

    __slots__ = ("cdr",)

    def __init__(self, cdr: bytes = b""):
        self.cdr = cdr


_raw_services: dict = {}  # service class -> its raw stand-in, or None where there is none


def _raw_class(message_class, name: str, conversions, bases: tuple):
    """A class standing in for ``message_class`` whose conversions are ``conversions`` (to
    Python, from Python) and whose C message, created and destroyed by the real type's
    functions, is the real one's."""
    real = type(message_class)
    if real._TYPE_SUPPORT is None:
        real.__import_type_support__()
    return _raw_message_class(name, message_class.__module__, real._TYPE_SUPPORT,
                              real._CREATE_ROS_MESSAGE, real._DESTROY_ROS_MESSAGE, conversions,
                              bases)


def _raw_message_class(name: str, module: str, type_support, create, destroy, conversions,
                       bases: tuple):
    to_py, from_py = conversions
    meta = type("Metaclass_" + name, (_RawTypeMeta,), {
        "_TYPE_SUPPORT": type_support, "_CREATE_ROS_MESSAGE": create,
        "_DESTROY_ROS_MESSAGE": destroy, "_CONVERT_TO_PY": to_py, "_CONVERT_FROM_PY": from_py})
    return meta(name, bases, {"__module__": module, "__slots__": ()})


class _RawServiceMeta(type):
    """What rclpy reads from a service class's metaclass to create a service."""

    _TYPE_SUPPORT = None

    @classmethod
    def __import_type_support__(cls):
        pass  # set at creation (library_service_type)


# dds request type -> stand-in. Only types that exist are kept: a client's made-up names are
# looked up again each time rather than fill this.
_library_services: dict = {}


def library_service_type(request_type: str):
    """A replier's raw service type (as ``raw_service_type`` gives) made from the package's C
    libraries alone, without importing its Python package: the service's and its request's and
    reply's type supports from ``lib<pkg>__rosidl_typesupport_c.so``, the request's C create and
    destroy functions from ``lib<pkg>__rosidl_generator_c.so``. None for an action's services,
    without the compiled helper or rmw, or where a library or name is missing: the Python classes
    (``service_class``, ``raw_service_type``) serve then.

    A replier's creation spent most of its time importing the package's Python ``srv`` module
    (every service class of the package, their type support module and the rosidl_generator_py
    libraries): 3-7 ms of the 7-10 ms (bench/microros/entity_creation.py), against rclpy's
    ``create_service`` itself, 0.5 ms."""
    stand_in = _library_services.get(request_type)
    if stand_in is not None:
        return stand_in
    package, kind, type_name = split_service_type(request_type)
    if kind != "srv":
        return None
    _check_package(package, request_type)
    stand_in = None
    helper = compiled.helper()
    library = _typesupport_c_library(package)
    if library is not None and helper is not None:
        import os

        generator = os.path.join(os.path.dirname(library),
                                 "lib%s__rosidl_generator_c.so" % package)
        prefix = "%s__srv__%s" % (package, type_name)
        try:
            service_support = helper.message_type_support(
                library, "rosidl_typesupport_c__get_service_type_support_handle__" + prefix)
            parts = {}
            for part in ("Request", "Response"):
                parts[part] = (
                    helper.message_type_support(
                        library, "rosidl_typesupport_c__get_message_type_support_handle__%s_%s"
                        % (prefix, part)),
                    helper.library_function(generator, "%s_%s__create" % (prefix, part)),
                    helper.library_function(generator, "%s_%s__destroy" % (prefix, part)))
        except ImportError as exc:
            log.debug("%s: no service type in %s's C libraries (%s); its Python classes serve",
                      request_type, package, exc)
            parts = None
        if parts is not None:
            to_request = helper.raw_request_conversion(parts["Request"][0])
            to_reply = helper.raw_reply_conversion()
            if to_request is not None and to_reply is not None:
                module = "%s.srv" % package
                meta = type("Metaclass_" + type_name, (_RawServiceMeta,),
                            {"_TYPE_SUPPORT": service_support})
                stand_in = meta(type_name, (), {
                    "__module__": module, "__slots__": (),
                    "Request": _raw_message_class(type_name + "_Request", module,
                                                  *parts["Request"], to_request, ()),
                    "Response": _raw_message_class(type_name + "_Response", module,
                                                   *parts["Response"], to_reply, (RawReply,))})
    if stand_in is not None:
        _library_services[request_type] = stand_in
    return stand_in


def raw_service_type(srv):
    """What a replier's rclpy ``Service`` takes as its ``srv_type`` to exchange CDR bytes
    instead of Python messages: ``Request`` makes rclpy's ``service_take_request`` give the
    request's CDR bytes behind the encapsulation, as ``serialize_message(request)[4:]`` would;
    ``Response`` is a ``RawReply`` that ``send_response`` deserializes in C. None where the
    compiled helper or rmw is missing, or its table of request types is full: the Python
    messages serve then.

    Saves a replier two conversions through Python objects per request (taking the request,
    then serializing it; deserializing the reply, then converting it for rcl), measured with
    bench/microros/service_roundtrip.py."""
    if srv in _raw_services:
        return _raw_services[srv]
    stand_in = None
    helper = compiled.helper()
    if helper is not None:
        request_meta = type(srv.Request)
        if request_meta._TYPE_SUPPORT is None:
            request_meta.__import_type_support__()
        to_request = helper.raw_request_conversion(request_meta._TYPE_SUPPORT)
        to_reply = helper.raw_reply_conversion()
        if to_request is not None and to_reply is not None:
            stand_in = types.SimpleNamespace(
                __name__=srv.__name__,
                Request=_raw_class(srv.Request, srv.Request.__name__, to_request, ()),
                Response=_raw_class(srv.Response, srv.Response.__name__, to_reply, (RawReply,)))
    _raw_services[srv] = stand_in
    return stand_in


# -- types known only by name ----------------------------------------------------------------------
#
# A client may name a type of a package the agent has nowhere (PX4's px4_msgs): as eProsima's
# agent does, its samples cross as the CDR bytes they are, under the DDS type name the client
# gave, and a ROS node that has the package reads and writes them. The type support is made from
# the name alone by the compiled helper (_named_types.c); nothing is imported for such a name.
# The helper keeps at most 1024 such types per process; these dicts hold the ones made.

_named_messages: dict = {}  # dds type name -> raw message class
_named_services: dict = {}  # dds request type name -> raw service class
_NAME_MAX = 255  # a DDS type name's limit in ROS' type descriptions


def _named_helper(dds_type: str, package: str):
    """The compiled helper, or UnknownTypeError saying what is missing."""
    helper = compiled.helper()
    if helper is None and compiled.missing != "not built":
        raise UnknownTypeError(
            "type %s: %s is not installed, and carrying a type known only by its name needs the "
            "agent's compiled helper (%s), which is %s here: `pip install -e .` rebuilds it; or "
            "build %s for the agent (--interfaces DIR, then %s)"
            % (dds_type, package, compiled.MODULE, compiled.missing, package, BUILD_HINT))
    if helper is None:
        raise UnknownTypeError(
            "type %s: %s is not installed, and carrying a type known only by its name needs the "
            "agent's compiled helper (%s), which this install lacks: a platform-independent wheel "
            "has none, an install from source with a C compiler (gcc, python3-dev) builds it; or "
            "build %s for the agent (--interfaces DIR, then %s)"
            % (dds_type, package, compiled.MODULE, package, BUILD_HINT))
    if len(dds_type) > _NAME_MAX:
        raise UnknownTypeError("type name of %d characters: at most %d" % (len(dds_type),
                                                                           _NAME_MAX))
    return helper


_fastdds_major = None  # of the RMW loaded: read from /proc/self/maps once


def _described() -> bool:
    """Whether a type known by name gives rmw an introspection description (a struct without
    fields): Fast DDS 2's rmw_fastrtps (Jazzy) needs one to create an endpoint and does not
    announce it; Fast DDS 3's (Kilted) announces it as the endpoint's XTypes type information,
    which would not match the real type's (``_named_types.c``)."""
    global _fastdds_major
    if _fastdds_major is None:
        from xrce.agent.interfaces import ros_install as rosenv

        _fastdds_major = rosenv.fastdds_major()
    return _fastdds_major < 3


_packages_by_name: set = set()  # packages whose types are known by name (bounded as the types)


def _note_by_name(package: str, dds_type: str) -> None:
    """One line per package at -v 4 (PX4 names some 50 types of one package), one per type at
    -v 5 and above."""
    if package not in _packages_by_name:
        _packages_by_name.add(package)
        log.info("no package %s on the agent's side: its types are carried by name, their CDR "
                 "bytes as they are (first: %s)", package, dds_type)
    log.debug("type %s carried by name", dds_type)


def _refused_by_name(dds_type: str, package: str, why: str) -> UnknownTypeError:
    return UnknownTypeError("type %s: %s is not installed, and the type cannot be carried by name: "
                            "%s" % (dds_type, package, why))


def named_message_type(dds_type: str, package: str, kind: str, type_name: str):
    """The raw message class of ``dds_type``, a type of a package the agent does not have,
    made from its name alone: publishers and raw subscriptions of it carry the client's CDR
    bytes."""
    handle = _named_messages.get(dds_type)
    if handle is not None:
        return handle
    helper = _named_helper(dds_type, package)
    type_support = helper.named_message_type(package, kind, type_name, _described())
    if isinstance(type_support, str):
        raise _refused_by_name(dds_type, package, type_support)
    create, from_py, to_py, destroy = helper.raw_type_conversions()
    meta = type("Metaclass_" + type_name, (_RawTypeMeta,), {
        "_TYPE_SUPPORT": type_support, "_CREATE_ROS_MESSAGE": create,
        "_CONVERT_FROM_PY": from_py, "_CONVERT_TO_PY": to_py, "_DESTROY_ROS_MESSAGE": destroy})
    handle = _named_messages[dds_type] = meta(type_name, (), {
        "__module__": "%s.%s" % (package, kind), "__slots__": ()})
    _note_by_name(package, dds_type)
    return handle


def named_service_type(request_type: str):
    """The raw service class of ``request_type`` (``pkg::srv::dds_::X_Request_``, or an action's
    ``X_SendGoal_Request_``/``X_GetResult_Request_``) where its package is nowhere on the agent's
    side, made from the name alone; None where the package is there. Requests and replies cross
    as CDR bytes both ways: ``Request`` and ``Response`` are ``RawReply`` classes (made with the
    sample's CDR, encapsulation first) that rclpy takes as the bytes behind the encapsulation."""
    stand_in = _named_services.get(request_type)
    if stand_in is not None:
        return stand_in
    package, kind, type_name = split_service_type(request_type)
    if kind == "action":
        if type_name.partition("_")[2] not in _ACTION_SERVICES:
            return None  # service_class says what is wrong with the name
    elif kind != "srv":
        return None
    if package_present(package, request_type):
        return None
    helper = _named_helper(request_type, package)
    supports = helper.named_service_type(package, kind, type_name, _described())
    if isinstance(supports, str):
        raise _refused_by_name(request_type, package, supports)
    service_support, request_support, response_support = supports
    create, destroy, to_py, from_py = helper.named_conversions()
    module = "%s.%s" % (package, kind)
    meta = type("Metaclass_" + type_name, (_RawServiceMeta,), {"_TYPE_SUPPORT": service_support})
    stand_in = meta(type_name, (), {
        "__module__": module, "__slots__": (),
        "Request": _raw_message_class(type_name + "_Request", module, request_support, create,
                                      destroy, (to_py, from_py), (RawReply,)),
        "Response": _raw_message_class(type_name + "_Response", module, response_support, create,
                                       destroy, (to_py, from_py), (RawReply,))})
    _named_services[request_type] = stand_in
    _note_by_name(package, request_type)
    return stand_in


def carries_cdr(srv) -> bool:
    """Whether a service class's requests and replies are CDR bytes (``RawReply`` objects to
    send, bytes taken): a replier's raw types and the types known by name."""
    return isinstance(srv.Response, type) and issubclass(srv.Response, RawReply)
