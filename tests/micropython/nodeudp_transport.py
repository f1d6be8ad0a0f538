"""MicroPython side of a custom XRCE transport over run.mjs' ``nodeudp`` bridge.

The callbacks follow the shape of micro-ROS' ``rmw_uros_set_custom_transport`` as mirrored by
``xrce.transports.custom.CustomTransport``::

    open_cb(user) -> bool
    close_cb(user) -> bool
    write_cb(user, data) -> number of bytes written (0 on failure)
    read_cb(user, buf, size, timeout_ms) -> number of bytes copied into the bytearray ``buf``

``user`` is not needed: the socket handle lives in the closure. The bridge reports failures by
returning -1 (see README.md), which the callbacks turn into the micro-ROS failure values. Bytes
go through ``nodeudp.send_at``/``recv_into``, which read and write them in place on the heap
(``uctypes.addressof``): a send or a receive allocates nothing here, as a board's socket does not,
so a capped run (tests/board/test_turtlebot3_heap.py) counts the firmware's heap and not the bridge's.

Packet mode (``stream=False``, for ``framing=False``) hands over one datagram per read and, like
``recvfrom`` on a short buffer, drops whatever does not fit in ``size``. Stream mode (``stream=True``,
for HDLC ``framing=True``) treats the datagrams as one byte stream: the bridge keeps the unread
tail for the next read.
"""

from uctypes import addressof

import nodeudp


def make_callbacks(host, port, stream=False):
    state = {"handle": None}

    def open_cb(user):
        if state["handle"] is not None:
            return True
        handle = nodeudp.open(host, port)
        if handle < 0:
            return False
        state["handle"] = handle
        return True

    def close_cb(user):
        handle = state["handle"]
        state["handle"] = None
        if handle is None:
            return True
        return nodeudp.close(handle) > 0

    def write_cb(user, data):
        handle = state["handle"]
        if handle is None:
            return 0
        written = nodeudp.send_at(handle, addressof(data), len(data))
        return written if written > 0 else 0

    def read_cb(user, buf, size, timeout_ms):
        handle = state["handle"]
        if handle is None or size <= 0:
            return 0
        if size > len(buf):  # the bridge writes where it is told: never past the buffer
            size = len(buf)
        count = nodeudp.recv_into(handle, addressof(buf), size, timeout_ms, stream)
        if count is None or count < 0:  # timeout, or -1 on a bridge error
            return 0
        return count

    return open_cb, close_cb, write_cb, read_cb
