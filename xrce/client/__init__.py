# The constrained XRCE client (runs on MicroPython and CPython).

# The session module's __getattr__ loads ping_agent (and discover_agents) on first use, for this
# package too: `from xrce.client import ping_agent` costs a board nothing until it runs.
from xrce.client.session import Session, SessionError, __getattr__  # noqa: F401

__all__ = ["Session", "SessionError", "ping_agent"]
