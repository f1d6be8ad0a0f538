"""The UDP link's optional compiled receive path: the C of ``_fastpath`` (built by setup.py from
every .c and .h of this folder) and its Python side.

- ``fastpath``: ``FastPath``, one link's compiled read, given the engine's parts it works with
  (``EngineParts``) by ``attach``; ``client``: ``CompiledClient``, what C knows of one client;
  ``_fastpath.c`` the module, the read and the samples to ROS; ``_receive_thread.c`` the thread that reads the socket and hands Python the rest;
  ``_reader_out.c`` samples from ROS sent to a board; ``_replier_out.c`` ROS's service calls to a
  board's replier; ``_reliable_in.c`` fragments and HEARTBEATs; ``_reliable_out.c`` the agent's
  reliable output streams and the client's ACKNACKs; ``_receiver_tables.c`` what Python registers;
- ``fold``: ``CounterFold``, C's counters moved into the engine's, the link's, the clients' and
  the entries';
- ``streams``: the stream objects whose numbers C owns.

The middleware is reached only through what it declares for this path
(``xrce.agent.middleware.CompiledPathSupport``), the link through ``xrce.agent.engine.link.Link``.
"""
