"""The agent's rclpy node: rclpy's ``Node`` without what an agent's nodes must not have or keep."""

from __future__ import annotations

import weakref

from rclpy.node import Node


class _NoParameterEvents:
    """What an ``AgentNode`` has instead of rclpy's /parameter_events publisher."""

    handle = None

    def publish(self, message) -> None:
        pass

    def destroy(self) -> None:
        pass


class AgentNode(Node):
    """An rclpy node without the /parameter_events publisher that ``Node.__init__`` creates
    unconditionally (rclcpp has ``start_parameter_event_publisher`` for this; rclpy has no such
    option). Nothing can change an agent node's parameters (no parameter services), so the only
    events it would publish are the declarations of its construction. Measured: the agent under
    the TurtleBot3 load holds 0.3 MB less than when it destroyed the publisher after construction
    (49.9 -> 49.6 MB; in a bare rclpy process the first node costs 5.2 instead of 13.4 MB, much of
    which the agent allocates for other entities anyway). Recognised by its call:
    ``Node.__init__`` asks for the publisher before it has the attribute; a client's own writer on
    /parameter_events, made later, is a real publisher."""

    def create_publisher(self, msg_type, topic, *args, **kwargs):
        if topic == "/parameter_events" and "_parameter_event_publisher" not in self.__dict__:
            return _NoParameterEvents()
        return super().create_publisher(msg_type, topic, *args, **kwargs)

    # rclpy's callback groups keep a weak reference to every entity and event handler added to
    # them, and Node.destroy_* never takes it out: on a node that outlives many of its entities
    # (the anchor hosting the wake-up while a serial board comes and goes, a board that keeps
    # deleting and creating writers) the dead references piled up, ~5 a board life, for the
    # agent's lifetime (bench/churn/churn.py --serial). Each destroy_* below takes its entity's out.

    def destroy_publisher(self, publisher) -> bool:
        _leave_callback_groups(publisher)
        return super().destroy_publisher(publisher)

    def destroy_subscription(self, subscription) -> bool:
        _leave_callback_groups(subscription)
        return super().destroy_subscription(subscription)

    def destroy_client(self, client) -> bool:
        _leave_callback_groups(client)
        return super().destroy_client(client)

    def destroy_service(self, service) -> bool:
        _leave_callback_groups(service)
        return super().destroy_service(service)

    def destroy_guard_condition(self, guard) -> bool:
        _leave_callback_groups(guard)
        return super().destroy_guard_condition(guard)

    def destroy_timer(self, timer) -> bool:
        _leave_callback_groups(timer)
        return super().destroy_timer(timer)


def _leave_callback_groups(entity) -> None:
    for item in (entity, *getattr(entity, "event_handlers", ())):
        group = getattr(item, "callback_group", None)
        entities = getattr(group, "entities", None)
        if isinstance(entities, set):
            entities.discard(weakref.ref(item))
