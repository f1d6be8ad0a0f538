"""The constrained XRCE client (runs on MicroPython and CPython)."""

from xrce.client.session import Session, SessionError, ping_agent  # noqa: F401
