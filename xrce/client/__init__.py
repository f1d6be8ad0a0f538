# The constrained XRCE client (runs on MicroPython and CPython).

from xrce.client.session import Session, SessionError

__all__ = ["Session", "SessionError", "ping_agent"]


def __getattr__(name):
    # ping_agent lives in xrce.client.ping, loaded on first use.
    if name == "ping_agent":
        from xrce.client.ping import ping_agent
        return ping_agent
    raise AttributeError(name)
