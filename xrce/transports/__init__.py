# Client transports and the pure byte framers they share with the agent.
#
# - ``crc``: CRC-16/ARC (the XRCE serial CRC) and CRC-16/X.25.
# - ``framing``: HDLC-like serial frames (``encode_frame``, ``FrameDecoder``) and the TCP 2-byte
#   length prefix (``encode_length_prefixed``, ``LengthPrefixDecoder``). No I/O: bytes in, messages out.
# - ``udp``, ``tcp``, ``serial``, ``custom``: synchronous client transports with one interface:
#   the constructor opens the link (``open()`` re-opens it after ``close()``), ``send(msg) -> bool``
#   hands one complete XRCE message to the link, ``recv(timeout_ms)`` returns one XRCE message as
#   bytes or None once ``timeout_ms`` has passed, ``close()`` releases it, ``mtu`` is the largest
#   message accepted either way.
#
# Submodules are not imported here so that a MicroPython build loads only the transport it uses.

from xrce import XrceError


class TransportError(XrceError):
    # The link failed in a way the caller must see: open failed, peer closed, stream desynced.
    pass


try:
    _TIMEOUT_ERRORS = (TimeoutError, BlockingIOError)  # CPython: settimeout(t) / settimeout(0)
except NameError:  # MicroPython: a plain OSError carrying the errno
    _TIMEOUT_ERRORS = ()

# EAGAIN, ETIMEDOUT (Linux), ETIMEDOUT (lwIP, as MicroPython ports number it)
_TIMEOUT_ERRNOS = (11, 110, 116)


def is_timeout_error(error):
    # Whether an OSError from a socket with a timeout means "nothing arrived in time".
    if isinstance(error, _TIMEOUT_ERRORS):
        return True
    return bool(error.args) and error.args[0] in _TIMEOUT_ERRNOS
