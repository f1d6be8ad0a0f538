"""The protocol engine: what the agent does with each XRCE message between a link and the middleware.

- ``agent``: ``Agent``, which builds and wires the parts below (each an object that owns its
  state and gets its collaborators in its constructor) and keeps the lifecycle;
- ``inbound``: ``Inbound``, every message in: the message header, stream admission, submessage
  dispatch and the parking of clients whose types build;
- ``client``: per-client state (``ClientProxy``); ``clients``: the client table and the memory
  budget; ``sessions``: ``Sessions`` (CREATE_CLIENT, GET_INFO, dead time, retirement,
  deletion); ``admission``: who may open one; ``limits``: the quotas' defaults and timings;
  ``link``: a transport server as the engine sees it; ``stats``: the agent-wide counters;
- ``objects``: ``ObjectRegistry``, CREATE/DELETE of XRCE objects and the middleware entities
  behind them, with ``reuse`` (REUSE/REPLACE) and ``xmlrep`` (XML representations);
- ``datapath``: ``DataPath``, the per-sample path, WRITE_DATA/FRAGMENT in, READ_DATA/DATA out;
  ``stream_output``: ``StreamOutput``, output on a client's streams (numbering, the reliable
  window, FRAGMENTs out); ``output``: whole messages out (counted, traced, tapped);
- ``liveliness``: ``Acknowledgments`` and ``Liveliness``, ACKNACK/HEARTBEAT and the timed work
  per client; ``scheduler``: the loop and the one timer of that work; ``mismatch_report``: endpoints
  that cannot reach their peers, named once; ``timeline``: where the time goes when a client
  comes back;
- ``compiled``: the UDP link's optional compiled receive path, its C and its Python side (the ROS
  type supports and conversions are the middleware's own extension: ``middleware.ros.compiled``).
"""
