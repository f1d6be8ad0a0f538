# The project's error types, importable on MicroPython.


class XrceError(Exception):
    # Base class of every error raised by this package.
    pass


try:
    class _ValueErrorBase(XrceError, ValueError):
        pass
except TypeError:
    # MicroPython cannot combine two built-in exception layouts; there the errors are XrceErrors only.
    _ValueErrorBase = XrceError


class DecodeError(_ValueErrorBase):
    # Bytes that cannot be decoded: truncated, out of range or inconsistent.
    #
    # Every decoder in the wire core raises only this for hostile input, so a caller can drop and count
    # a bad datagram with a single ``except DecodeError``.
    pass


class EncodeError(_ValueErrorBase):
    # A value that cannot be put on the wire (out of range, too long, wrong type).
    pass
