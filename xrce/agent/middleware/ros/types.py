"""Map XRCE/DDS names onto ROS 2 names, interface classes and QoS profiles (CPython agent only).

micro-ROS names things the way the ROS 2 DDS mapping does (XRCE-WIRE.md §4): topics ``rt/<ros name>``,
service topics ``rq/<service>Request`` / ``rr/<service>Reply``, types ``pkg::msg::dds_::T_`` and
``pkg::srv::dds_::X_Request_``. rclpy wants the ROS spelling and an importable class, so these helpers
undo that mangling.

An action is no entity of its own on the wire: rmw_microxrcedds (like rcl_action over any RMW) makes
an rclc action server or client out of three services and two topics under ``<action>/_action/``,
typed ``pkg::action::dds_::X_SendGoal_Request_``, ``X_GetResult_Request_``, ``X_FeedbackMessage_``
plus ``action_msgs``' CancelGoal and GoalStatusArray. Those parts map onto the classes rclpy's
``ActionClient``/``ActionServer`` use for the same DDS types (``X.Impl.SendGoalService``, ...), so
each part is bridged as the plain service or topic it is.
"""

from __future__ import annotations

import importlib
import logging
import re
import sys
import types

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.validate_full_topic_name import validate_full_topic_name
from rclpy.exceptions import InvalidServiceNameException, InvalidTopicNameException

from xrce.agent.middleware.ros import deferred
from xrce.agent.middleware import EndpointQosSpec, MiddlewareError, TypeNotReady, UnknownTypeError



def _defer_rosidl_code_generator() -> None:
    """Let generated message classes import ``rosidl_generator_py`` without its code generator.

    Every generated class's ``__import_type_support__`` (run by rclpy for the first publisher of
    a type, e.g. each node's /parameter_events) does ``from rosidl_generator_py import
    import_type_support``, and that package's ``__init__`` also imports the code generator with
    lark, empy and hashlib/OpenSSL: 5 MB of resident memory and 35 ms of start-up the agent never
    uses. The package is registered with only ``import_type_support``; touching any other of its
    names runs its real ``__init__`` then (``xrce.agent.middleware.ros.deferred``).
    """
    def prepare(package) -> None:
        from rosidl_generator_py.import_type_support_impl import import_type_support
        package.import_type_support = import_type_support

    deferred.defer("rosidl_generator_py", prepare)


_defer_rosidl_code_generator()

BUILD_HINT = "run `xrce-agent build-interfaces`"

log = logging.getLogger("xrce.agent.rostypes")

_TOPIC_PREFIX = "rt/"
_REQUEST_PREFIX = "rq/"
_REPLY_PREFIX = "rr/"
_NODE_TOKEN_INVALID = re.compile(r"[^A-Za-z0-9_]")

# "pkg::msg::dds_::T_", "pkg::msg::T", "pkg/msg/T" all name the same interface.
_DDS_TYPE = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)(?:::|/)(msg|srv|action)(?:::|/)(?:dds_::)?([A-Za-z][A-Za-z0-9_]*?)_?$")


def _full_name(name: str) -> str:
    full = name if name.startswith("/") else "/" + name
    try:
        validate_full_topic_name(full)
    except (InvalidTopicNameException, InvalidServiceNameException) as exc:
        raise MiddlewareError("%r is not a valid ROS name: %s" % (name, exc)) from None
    return full


def dds_topic_to_ros(dds_name: str) -> tuple[str, str]:
    """Return (kind, fully qualified ROS name); kind is "topic", "request", "reply", or "dds".

    "dds": a name without a ROS prefix (micro-ROS' ``ros_to_microros_graph``, a plain XRCE
    client's ``HelloWorldTopic``) is a DDS-level topic, not a ROS one: eProsima's agents create it
    under that very name, where ROS graph tools do not list it. rclpy reaches such a topic only
    with ``avoid_ros_namespace_conventions`` (``qos_profile(..., dds_level=True)``), and rcl makes
    every name absolute first, so the DDS topic is ``/name``: still outside the ROS graph, and
    the same topic for every client of this agent, but not the exact DDS name eProsima's agent
    would use (rclpy has no way to create a DDS topic name without the leading slash).
    """
    if dds_name.startswith(_TOPIC_PREFIX):
        return "topic", _full_name(dds_name[len(_TOPIC_PREFIX):])
    if dds_name.startswith(_REQUEST_PREFIX) and dds_name.endswith("Request"):
        return "request", _full_name(dds_name[len(_REQUEST_PREFIX):-len("Request")])
    if dds_name.startswith(_REPLY_PREFIX) and dds_name.endswith("Reply"):
        return "reply", _full_name(dds_name[len(_REPLY_PREFIX):-len("Reply")])
    return "dds", _full_name(dds_name)


def _service_of_topic(topic: str | None, kind: str) -> str | None:
    """The service a well-formed request (``rq/<X>Request``) or reply (``rr/<X>Reply``) topic
    belongs to, ``/X``; None for no topic, another form, or an invalid ROS name."""
    if not topic:
        return None
    try:
        found, name = dds_topic_to_ros(topic)
    except MiddlewareError:
        return None
    return name if found == kind else None


def service_ros_name(service_name: str, request_topic: str | None = None,
                     reply_topic: str | None = None) -> str:
    """The ROS service name of a requester or replier.

    eProsima's agent (2.4 and 3.x, from binary, XML or a reference alike) makes its DDS request
    writer/reader on the request topic name and its reply one on the reply topic name, and uses
    the service name for nothing. ROS names a service's two topics ``rq/<service>Request`` and
    ``rr/<service>Reply``, so the service is the one those names spell: PX4's replier
    ``vehicle_command`` with ``rq/fmu/vehicle_commandRequest`` is ``/fmu/vehicle_command``,
    ``rq/px4_1/fmu/...`` is ``/px4_1/fmu/vehicle_command``. One well-formed topic alone (the other
    absent, or not in that form) names it too. Two well-formed topics of different services are
    refused: eProsima's agent would make DDS endpoints no ROS client pairs, and one rclpy service
    cannot have two names. With no well-formed topic (a plain DDS client's ``calc_Request``, or
    none given) the service name serves, as its ROS name. micro-ROS sends the service name and
    the topics consistently (``/add_two_ints``, ``rq/add_two_intsRequest``): its services,
    actions and parameters keep their names."""
    from_request = _service_of_topic(request_topic, "request")
    from_reply = _service_of_topic(reply_topic, "reply")
    if from_request and from_reply and from_request != from_reply:
        raise MiddlewareError("request topic %r and reply topic %r name two services (%s, %s): "
                              "a ROS 2 service has one" % (request_topic, reply_topic,
                                                            from_request, from_reply))
    if from_request or from_reply:
        return from_request or from_reply
    if service_name:
        return dds_topic_to_ros(service_name)[1]
    raise MiddlewareError("service has neither a name nor a request or reply topic")


def is_ros_type_name(dds_type: str) -> bool:
    """Whether ``dds_type`` names a ROS interface type (``pkg::msg::dds_::T_``, ``pkg/msg/T``):
    rclpy's to carry. Any other name is a plain DDS type (``xrce.agent.middleware.dds``)."""
    return _DDS_TYPE.match(dds_type) is not None


def _split_type(dds_type: str) -> tuple[str, str, str]:
    match = _DDS_TYPE.match(dds_type)
    if match is None:
        raise UnknownTypeError("%r is not a ROS interface type name (expected pkg::msg::dds_::T_)"
                               % dds_type)
    return match.group(1), match.group(2), match.group(3)


# -- which packages a type name may import -------------------------------------------------------
#
# Importing a package runs its code, and the type name comes from anyone who can send the agent a
# datagram: "this::msg::dds_::Foo_" used to print the Zen of Python, "numpy::msg::..." to load
# numpy (+16 MB). A package is imported only when it is an interface package of the ROS in use
# (its ament index lists it under rosidl_interfaces) or one the agent's interface registry holds
# a complete build of (xrce.agent.interfaces.registry). A package of the agent's interface
# directories gets one build attempt per agent run (xrce.agent.interfaces); any other name is
# refused (ERR_DDS_ERROR, logged with the type by the engine) without a child process.

_known_packages: dict = {}  # package -> True (an interface package of the ROS in use) / False


def _in_ament_index(package: str) -> bool:
    known = _known_packages.get(package)
    if known is None:
        import os

        from xrce.agent.interfaces import ros_install as rosenv

        known = any(os.path.isfile(os.path.join(prefix, "share", "ament_index", "resource_index",
                                                "rosidl_interfaces", package))
                    for prefix in rosenv.ament_prefixes())
        if len(_known_packages) < 4096:  # a flood of made-up names must not grow this forever
            _known_packages[package] = known
    return known


def _registered(package: str) -> bool:
    from xrce.agent.interfaces.registry import is_registered

    return is_registered(package)


def package_present(package: str, dds_type: str) -> bool:
    """Whether ``package`` may be imported for ``dds_type``: True for an interface package of the
    ROS in use or of the agent's registry (built now from its interface directories if one has
    it); False where no package of that name is anywhere, the type is then known by its name
    only (``raw_types.named_message_type``). Raises TypeNotReady while the interface directories
    are listed or the package is built, UnknownTypeError when its build failed."""
    if _in_ament_index(package) or _registered(package):
        return True
    from xrce.agent import interfaces

    listing = interfaces.search_index()
    if not listing.done():
        raise TypeNotReady("looking for %s in the interface directories" % package, listing)
    if package not in listing.result():
        return False
    future = interfaces.start_package_build(package)
    if not future.done():
        log.info("building interface package %s for type %s; its CREATE waits", package, dds_type)
        raise TypeNotReady("interface package %s is being built" % package, future)
    error = future.exception()
    if error is not None:
        raise UnknownTypeError("type %s: building %s failed in this agent run (not retried "
                               "before a restart): %s" % (dds_type, package, error)) from None
    if not future.result():
        return False
    if not _registered(package):
        raise UnknownTypeError("type %s: %s was built but is not registered" % (dds_type, package))
    return True


def _check_package(package: str, dds_type: str) -> None:
    """Return if ``package`` may be imported for ``dds_type``; else raise UnknownTypeError, or
    TypeNotReady while the interface directories are listed or the package is built."""
    if not package_present(package, dds_type):
        raise UnknownTypeError("type %s: %s is not installed: no interface package of the ROS in "
                               "use (ament index) nor of the agent's interface directories has "
                               "that name (--interfaces DIR, then %s)"
                               % (dds_type, package, BUILD_HINT))


def _import_module(package: str, module_name: str):
    """Import ``module_name`` of interface ``package`` (``_check_package`` allowed it)."""
    try:
        return importlib.import_module(module_name)
    except ImportError as exc:
        # ImportError of the package itself means it was never built; anything deeper is a broken
        # install, which a rebuild fixes.
        raise UnknownTypeError("%s is not installed: %s (%s)" % (package, BUILD_HINT, exc)) from None


def _import_interface(package: str, kind: str, type_name: str):
    module_name = "%s.%s" % (package, kind)
    module = _import_module(package, module_name)
    try:
        return getattr(module, type_name)
    except AttributeError:
        raise UnknownTypeError("%s has no interface %s: %s if it was added recently"
                               % (module_name, type_name, BUILD_HINT)) from None


def message_class(dds_type: str):
    """``std_msgs::msg::dds_::String_`` -> ``std_msgs.msg.String``."""
    package, kind, type_name = _split_type(dds_type)
    if kind == "action":
        _check_package(package, dds_type)
        return _action_part(package, type_name, _ACTION_MESSAGES, dds_type)
    if kind != "msg":
        raise UnknownTypeError("%r is not a message type" % dds_type)
    _check_package(package, dds_type)
    return _import_interface(package, kind, type_name)


# The parts of action X that travel as messages / as services, by the suffix of their DDS type
# name ("X_FeedbackMessage", "X_SendGoal"), and where rclpy's generated action class keeps them.
_ACTION_MESSAGES = {"FeedbackMessage": ("Impl", "FeedbackMessage"), "Goal": ("Goal",),
                    "Result": ("Result",), "Feedback": ("Feedback",)}
_ACTION_SERVICES = {"SendGoal": ("Impl", "SendGoalService"),
                    "GetResult": ("Impl", "GetResultService")}


def _action_part(package: str, type_name: str, parts: dict, dds_type: str):
    """``Fibonacci_FeedbackMessage`` of ``test_msgs`` -> ``test_msgs.action.Fibonacci.Impl.
    FeedbackMessage`` (``parts``: which suffixes may be asked for here)."""
    # Action names are PascalCase (no "_"): the first "_" separates the action from its part.
    action_name, _, part = type_name.partition("_")
    path = parts.get(part)
    if path is None:
        raise UnknownTypeError("%r is not a %s of an action (one of %s)"
                               % (dds_type, "message" if parts is _ACTION_MESSAGES else "service",
                                  ", ".join("X_" + name for name in parts)))
    found = _import_interface(package, "action", action_name)
    try:
        for attribute in path:
            found = getattr(found, attribute)
    except AttributeError:  # a name of the module that is no generated action class
        raise UnknownTypeError("%s.action.%s is not an action" % (package, action_name)) from None
    return found


class _NumpyOnFirstUse(types.ModuleType):
    """What ``service_msgs.msg`` gets for ``numpy`` (see ``_import_service_event_info``)."""

    def __getattr__(self, name):
        import numpy  # the real one: this stand-in is in sys.modules only while it is bound

        return getattr(numpy, name)


def _import_service_event_info() -> None:
    """Import ``service_msgs.msg`` with ``numpy`` bound to a stand-in that imports it on first use.

    Every generated service class's ``__import_type_support__`` (rclpy calls it for the first
    service or client of a type) imports ``service_msgs.msg.ServiceEventInfo``, for the service
    introspection events the agent never enables, and that module imports numpy at its top for
    one array field its instances would use. numpy took 150-340 ms of a replier's creation on the
    2-core dev machine (bench/microros/entity_creation.py) and 11 MB. The stand-in is only that module's:
    anything else importing numpy gets the real one, and so does that module if it ever builds an
    instance."""
    if "service_msgs.msg" in sys.modules or "numpy" in sys.modules:
        return
    stand_in = _NumpyOnFirstUse("numpy")
    sys.modules["numpy"] = stand_in
    try:
        import service_msgs.msg  # noqa: F401
    except ImportError:
        pass  # a ROS without service introspection (before Jazzy): nothing to defer
    finally:
        if sys.modules.get("numpy") is stand_in:
            del sys.modules["numpy"]


def split_service_type(request_or_reply_type: str) -> tuple[str, str, str]:
    """``pkg::srv::dds_::X_Request_`` (or ``X_Response_``) -> ("pkg", "srv", "X")."""
    package, kind, type_name = _split_type(request_or_reply_type)
    for suffix in ("_Request", "_Response"):
        if type_name.endswith(suffix):
            return package, kind, type_name[:-len(suffix)]
    return package, kind, type_name


def service_class(request_or_reply_type: str):
    """``pkg::srv::dds_::X_Request_`` (or ``X_Response_``) -> ``pkg.srv.X``; an action's
    ``pkg::action::dds_::X_SendGoal_Request_`` -> ``pkg.action.X.Impl.SendGoalService`` (and
    ``X_GetResult_`` -> ``GetResultService``)."""
    _import_service_event_info()
    package, kind, type_name = split_service_type(request_or_reply_type)
    if kind == "action":
        if type_name.partition("_")[2] not in _ACTION_SERVICES:
            raise UnknownTypeError("%r is not a service of an action (one of %s)"
                                   % (request_or_reply_type,
                                      ", ".join("X_%s_Request_" % n for n in _ACTION_SERVICES)))
        _check_package(package, request_or_reply_type)
        return _action_part(package, type_name, _ACTION_SERVICES, request_or_reply_type)
    if kind != "srv":
        raise UnknownTypeError("%r is not a service type" % request_or_reply_type)
    _check_package(package, request_or_reply_type)
    return _import_interface(package, kind, type_name)


def _node_token(token: str) -> str:
    token = _NODE_TOKEN_INVALID.sub("_", token)
    if not token or token[0].isdigit():
        token = "n" + token
    return token


def node_name_and_namespace(participant_name: str, fallback: str) -> tuple[str, str]:
    """Split "ns/sub/name" into ("name", "/ns/sub") and make every token a valid ROS token.

    ``fallback`` is used when the client gave no usable name (empty or eProsima's "default").
    """
    parts = [p for p in participant_name.strip().split("/") if p]
    if not parts or parts == ["default"]:
        return fallback, "/"
    name = _node_token(parts[-1])
    namespace = "/" + "/".join(_node_token(p) for p in parts[:-1]) if len(parts) > 1 else "/"
    return name, namespace


_DURABILITY = {
    "volatile": DurabilityPolicy.VOLATILE,
    # rclpy only offers volatile and transient-local; the stronger DDS kinds degrade to the closest.
    "transient_local": DurabilityPolicy.TRANSIENT_LOCAL,
    "transient": DurabilityPolicy.TRANSIENT_LOCAL,
    "persistent": DurabilityPolicy.TRANSIENT_LOCAL,
}


def qos_profile(qos: EndpointQosSpec, dds_level: bool = False) -> QoSProfile:
    """The rclpy profile of an XRCE endpoint; ``dds_level`` for a topic without a ROS prefix
    (``dds_topic_to_ros`` kind "dds"): rmw then adds no ``rt/``, and ROS graph tools leave it
    out as they do the DDS-level topics eProsima's agents create."""
    durability = _DURABILITY.get(qos.durability)
    if durability is None:
        raise MiddlewareError("unknown durability %r" % (qos.durability,))
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST if qos.keep_last else HistoryPolicy.KEEP_ALL,
        depth=max(1, int(qos.depth)),
        reliability=ReliabilityPolicy.RELIABLE if qos.reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=durability,
        avoid_ros_namespace_conventions=dds_level,
    )
