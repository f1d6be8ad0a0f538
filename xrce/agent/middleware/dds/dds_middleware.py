"""``-m dds``: ``DdsMiddleware``, the ROS middleware (``RosMiddleware``, unchanged) with one more
part, ``PlainDds`` (``xrce.agent.middleware.dds.plain_dds``), for every topic whose type name is
not a ROS one: such a topic, and the datawriters and datareaders on it, go to that part; the
rest to the ROS middleware."""

from __future__ import annotations

from xrce.agent.middleware import DataCallback, EndpointQosSpec, EntityKey, TopicSpec
from xrce.agent.middleware.dds.plain_dds import PlainDds
from xrce.agent.middleware.ros.ros_middleware import RosMiddleware
from xrce.agent.middleware.ros.types import is_ros_type_name


class DdsMiddleware(RosMiddleware):
    """ROS type names through rclpy (``RosMiddleware``), any other type name as a plain DDS topic
    (``self.plain``): each method below takes what is plain and hands the rest on (``super()``)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.plain = PlainDds(self.run, self.records)

    # -- creation -----------------------------------------------------------------------------

    def create_topic(self, key: EntityKey, participant: EntityKey, topic: TopicSpec) -> None:
        if is_ros_type_name(topic.type_name):
            super().create_topic(key, participant, topic)
        else:
            self.plain.create_topic(key, participant, topic)

    def create_datawriter(self, key: EntityKey, publisher: EntityKey, topic: EntityKey,
                          qos: EndpointQosSpec) -> None:
        if topic in self.plain:
            self.plain.create_datawriter(key, publisher, topic, qos)
        else:
            super().create_datawriter(key, publisher, topic, qos)

    def create_datareader(self, key: EntityKey, subscriber: EntityKey, topic: EntityKey,
                          qos: EndpointQosSpec, on_data: DataCallback) -> None:
        if topic in self.plain:
            self.plain.create_datareader(key, subscriber, topic, qos, on_data,
                                         self.handoff_depth)
        else:
            super().create_datareader(key, subscriber, topic, qos, on_data)

    # -- data ---------------------------------------------------------------------------------

    def write(self, writer: EntityKey, sample: bytes) -> bool:
        if writer in self.plain:
            return self.plain.write(writer, sample)
        return super().write(writer, sample)

    def writer(self, writer: EntityKey):
        if writer in self.plain:
            return self.plain.writer(writer)
        return super().writer(writer)

    def reader_stats(self, reader: EntityKey) -> tuple[int, int]:
        if reader in self.plain:
            return self.plain.reader_stats(reader)
        return super().reader_stats(reader)

    def plain_matched(self, writer: EntityKey) -> int:
        """How many DDS readers a plain datawriter has matched (tests, diagnostics)."""
        return self.plain.matched(writer)

    def ros_entity(self, key: EntityKey) -> str | None:
        if key in self.plain:
            return self.plain.ros_entity(key)
        return super().ros_entity(key)

    # -- deletion -----------------------------------------------------------------------------

    def delete(self, key: EntityKey) -> None:
        if key in self.plain:
            self.plain.delete(key)
            return
        self.plain.delete_children(key)
        super().delete(key)

    async def close(self) -> None:
        self.plain.close()
        await super().close()
