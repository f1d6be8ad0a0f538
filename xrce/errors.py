# The project's error types, defined in the package itself (xrce/__init__.py) so that a board loads
# no module for them; this name stays for code that imports them from here.

from xrce import DecodeError, EncodeError, XrceError  # noqa: F401
