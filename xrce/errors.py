"""The project's error types, importable on MicroPython."""


class XrceError(Exception):
    """Base class of every error raised by this package."""


class DecodeError(XrceError, ValueError):
    """Bytes that cannot be decoded: truncated, out of range or inconsistent.

    Every decoder in the wire core raises only this for hostile input, so a caller can drop and count
    a bad datagram with a single ``except DecodeError``.
    """


class EncodeError(XrceError, ValueError):
    """A value that cannot be put on the wire (out of range, too long, wrong type)."""
