"""The protocol engine: what the agent does with each XRCE message between a link and the middleware.

- ``dispatch``: ``Agent``, the message header, stream admission, submessage dispatch, parking of
  clients whose types build, and the agent's lifecycle;
- ``session``: per-client state, CREATE_CLIENT, GET_INFO, deletion; ``admission``: who may open one;
- ``objects``: CREATE/DELETE of XRCE objects and the middleware entities behind them, with
  ``reuse`` (REUSE/REPLACE) and ``xmlrep`` (XML representations);
- ``datapath``: the per-sample path, WRITE_DATA/FRAGMENT in, READ_DATA/DATA out;
- ``liveliness``: ACKNACK/HEARTBEAT and the timed work per client; ``timeline``: where the time
  goes when a client comes back;
- ``fastpath`` and ``_fastpath.c``: the UDP link's optional compiled receive path (the ROS type
  supports and conversions are the middleware's own extension: ``middleware.ros.compiled``).
"""
