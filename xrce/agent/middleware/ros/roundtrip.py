"""Names the agent gave, translated back where a board reads them (issue 53, "round trip").

The agent gives a board's entities other names than the board asked for (``naming``); unmodified
firmware must still find its own names in what it reads. Names reach a board in samples, so the
translation is per sample, on the few topics that carry names, and with the ``Naming`` of the
board's own participant (boards of one agent may be named apart):

- micro-ROS' graph topic (``graph.board_graph_reader``): node namespaces, topics, services;
- ``/parameter_events``: the ``node`` of each ``rcl_interfaces/msg/ParameterEvent`` a board's
  parameter server writes becomes its node's fully qualified ROS name (``/robot1/tb3_params``,
  as rclpy and rclcpp nodes name themselves there). rclc writes the node's base name
  (``tb3_params``), which would say nothing of which robot changed a parameter. What a board reads
  there names the nodes of its namespace as the board does (``/robot1/tuner`` -> ``/tuner``).
  Only a namespace moves nodes; remaps do not, and without one the samples go as they are.

A reader or writer with a translation takes Python's path for every sample (the compiled UDP path
would carry the bytes as they are: ``RosCompiledPathSupport.subscription_address`` and
``publisher_address``).
Everything else a board reads is listed in docs/ARCHITECTURE.md ("Names back to the board").
"""

from __future__ import annotations

from xrce.agent.middleware.ros.domain import ENCAPSULATION_LE, log
from xrce.agent.middleware.ros.graph import GRAPH_SPEC, board_graph_reader
from xrce.agent.middleware.ros.naming import Naming

PARAMETER_EVENTS_TOPIC = "rt/parameter_events"
PARAMETER_EVENT_TYPE = "rcl_interfaces::msg::dds_::ParameterEvent_"


def _is_parameter_events(spec) -> bool:
    return spec is not None and spec.name == PARAMETER_EVENTS_TOPIC and \
        spec.type_name == PARAMETER_EVENT_TYPE


def _parameter_event_node(sample: bytes, rename) -> bytes:
    """A ParameterEvent's CDR body (no encapsulation) with ``node`` renamed. Serialized again in
    full: a longer or shorter name moves the 8-byte-aligned values after it."""
    from rcl_interfaces.msg import ParameterEvent
    from rclpy.serialization import deserialize_message, serialize_message

    event = deserialize_message(ENCAPSULATION_LE + sample, ParameterEvent)
    renamed = rename(event.node)
    if renamed == event.node:
        return sample
    event.node = renamed
    return serialize_message(event)[len(ENCAPSULATION_LE):]


def _safely(rewrite, what: str):
    def apply(sample: bytes) -> bytes:
        try:
            return rewrite(sample)
        except Exception:  # not deserializable: as it came, as a sample of another topic would
            log.debug("%s: sample not translated", what, exc_info=True)
            return sample
    return apply


def writer_rewrite(spec, naming: Naming, node):
    """``rewrite(sample) -> sample`` for the writer of ``spec`` of a board under ``naming`` whose
    participant is the rclpy ``node``, on its way to ROS; None where the samples go as they are."""
    if not (naming.moves_nodes and _is_parameter_events(spec)):
        return None
    ros_node = node.get_fully_qualified_name()
    own = (node.get_name(), naming.board_node(ros_node))  # rclc's base name, or the board's FQN

    def to_ros(name: str) -> str:
        if name in own:
            return ros_node
        return naming.ros_node(name) if name.startswith("/") else name

    return _safely(lambda sample: _parameter_event_node(sample, to_ros), "parameter event to ROS")


def reader_delivery(spec, naming: Naming, on_data):
    """``on_data`` of a board's reader of ``spec`` under ``naming``, translated back where the
    samples carry names; None where they are delivered as they are."""
    if spec == GRAPH_SPEC and naming.changes_names:
        return board_graph_reader(on_data, naming)
    if naming.moves_nodes and _is_parameter_events(spec):
        rewrite = _safely(lambda sample: _parameter_event_node(
            sample, lambda name: naming.board_node(name) if name.startswith("/") else name),
            "parameter event to a board")
        return lambda sample: on_data(rewrite(sample))
    return None
