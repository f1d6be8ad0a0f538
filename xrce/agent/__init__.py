"""The XRCE agent (CPython), laid out along its data path:

- ``links``: UDP (and discovery), TCP, serial and pseudoterminal links; each hands whole XRCE
  messages to the engine and sends its replies;
- ``engine``: the protocol engine (dispatch, sessions, objects, data path, liveliness, recovery
  timelines, admission, the compiled UDP receive path);
- ``middleware``: what XRCE objects map onto: the interface, ``ced`` (no ROS) and ``ros`` (rclpy);
- ``interfaces``: finding and building ROS 2 interface packages for the types clients name;
- ``observe``: stats, ``xrce-agent stats``, ``/diagnostics`` and capture files;
- ``cli`` (``xrce-agent``), started through ``launcher``; ``demo`` (``xrce-agent demo``);
- ``c_sources``: whether one of the optional compiled extensions (the engine's receive path,
  the ROS middleware's type supports) is built from the C sources beside it;
- ``heap`` (over the tiny ``_heap`` extension): malloc_trim; ``allow_lists``: parsing of
  --allow-keys and --allow-from.
"""
