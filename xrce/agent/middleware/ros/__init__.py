"""``-m dds``: the middleware that maps XRCE objects onto rclpy, and the ROS 2 it runs on.

- ``ros_middleware``: ``RosMiddleware``, XRCE entities as rclpy nodes, publishers and
  subscriptions, composed of parts: ``records`` (what it keeps per entity); ``creation`` (entity
  creation parked while a type builds); ``services`` and ``service_records`` (requesters and
  repliers); ``membership`` (the domains joined and left, the agent's own publishers there,
  micro-ROS' graph feed, ``graph``, where a client reads it); ``endpoint_watch`` (the peers a
  board's endpoint cannot match); ``collisions``; ``shown``; ``compiled_path_support``;
  ``run_context`` (the loop and what the engine sets);
- ``domain``: one rclpy context and executor thread per ROS domain, and the hand-off to the loop;
  ``wake``: what wakes that thread for a job (a private wake topic, or a guard condition);
- ``types``: XRCE/DDS names, interface classes and QoS as ROS 2 spells them;
- ``compiled``: the optional ``_rostypes`` extension built from this folder's C (``_rostypes.c``,
  ``_services.c``, ``_named_types.c``): the raw types of ``raw_types`` (CDR bytes through rclpy,
  types known only by their DDS name) and ``participant``'s participant made without the GIL;
- ``fastdds_profile`` (and its ``.xml``): the Fast DDS profile used when the user has none
  (which ROS 2 the agent runs on: xrce.agent.interfaces.ros_install);
- ``deferred`` and ``rclpy_services``: what rclpy imports and starts that the agent never uses,
  kept from loading.

Nothing here is imported by a ``-m ced`` agent: this package imports nothing itself, so the
command line reads its defaults here without loading rclpy.
"""

# Seconds a ROS domain stays joined after its last client participant has gone (``membership``;
# ``--domain-linger``). Why this long: docs/PERFORMANCE.md, "Agent restart and discovery".
DOMAIN_LINGER_S = 10.0
# Seconds a service request waits for its reply before it is forgotten (``services``;
# ``--request-timeout``); an action's get_result waits however long its goal takes.
REQUEST_TIMEOUT_S = 10.0
