# The constrained XRCE client (runs on MicroPython and CPython).

from xrce.client.session import Session, SessionError, ping_agent

__all__ = ["Session", "SessionError", "ping_agent"]
