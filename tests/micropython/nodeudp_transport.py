"""MicroPython side of a custom XRCE transport over run.mjs' ``nodeudp`` bridge.

The callbacks follow the shape of micro-ROS' ``rmw_uros_set_custom_transport`` as mirrored by
``xrce.transports.custom.CustomTransport``::

    open_cb(user) -> bool
    close_cb(user) -> bool
    write_cb(user, data) -> number of bytes written (0 on failure)
    read_cb(user, buf, size, timeout_ms) -> number of bytes copied into the bytearray ``buf``

``user`` is not needed: the socket handle lives in the closure. The bridge reports failures by
returning -1 (see README.md), which the callbacks turn into the micro-ROS failure values.

Packet mode (``stream=False``, for ``framing=False``) hands over one datagram per read and, like
``recvfrom`` on a short buffer, drops whatever does not fit in ``size``. Stream mode (``stream=True``,
for HDLC ``framing=True``) treats the datagrams as one byte stream and keeps the unread tail for
the next read.
"""

from binascii import hexlify, unhexlify

import nodeudp


def make_callbacks(host, port, stream=False):
    state = {"handle": None, "pending": b"", "pending_at": 0}

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
        state["pending"] = b""
        state["pending_at"] = 0
        if handle is None:
            return True
        return nodeudp.close(handle) > 0

    def write_cb(user, data):
        handle = state["handle"]
        if handle is None:
            return 0
        # Hex strs cross the bridge without a PyProxy, which would pin the bytes on the heap.
        written = nodeudp.send_hex(handle, hexlify(data).decode())
        return written if written > 0 else 0

    def read_cb(user, buf, size, timeout_ms):
        handle = state["handle"]
        if handle is None or size <= 0:
            return 0
        data = state["pending"]
        start = state["pending_at"]
        if start >= len(data):
            data = nodeudp.recv_hex(handle, timeout_ms)
            if data is None or isinstance(data, int):  # timeout, or -1 on a bridge error
                return 0
            data = unhexlify(data)
            start = 0
        count = len(data) - start
        if count > size:
            count = size
        memoryview(buf)[0:count] = memoryview(data)[start : start + count]
        if stream and start + count < len(data):
            state["pending"] = data
            state["pending_at"] = start + count
        else:
            state["pending"] = b""
            state["pending_at"] = 0
        return count

    return open_cb, close_cb, write_cb, read_cb
