# Session methods that load on first use: services (xrce.client.services), deleting entities or
# the session and waiting for delivery (xrce.client.teardown), time sync (xrce.client.timesync),
# the ping inside the session (xrce.client.ping) and the link state. Session.__getattr__ hands
# every name it does not have to ``session_attr``; the table of names lives here, not in the
# session module, because on a board its strings and code would cost every firmware heap (0.7 KB),
# used or not.

# Each module's names as one space-separated string, looked up as " name ": on a board every string
# of a tuple would be an object of its own (the tuples cost 0.3 KB more).
_SERVICES = (" create_requester create_replier create_service_client create_service_server"
             " send_request send_reply ")
_TEARDOWN = " delete delete_entity cancel_data run_until_confirm_delivery "


def session_attr(session, name):
    # Modules are imported by full name: on MicroPython `from xrce.client import teardown` looks the
    # module up as an attribute of the package first, and the package's __getattr__ (the session
    # module's, for ping_agent) raises AttributeError instead of letting the import go on.
    word = " %s " % name
    if word in _SERVICES:
        import xrce.client.services as module
    elif word in _TEARDOWN:
        import xrce.client.teardown as module
    elif name == "sync_time":
        import xrce.client.timesync as module
    elif name == "ping":
        import xrce.client.ping as module
    elif name == "link_state":
        # 'connected', 'silent' (the agent is quiet, pings are out) or 'lost' (re-creating).
        link = session.link
        if link is None:
            return "connected" if session.connected else "lost"
        from xrce.client.recovery import LINK_STATE_NAMES

        return LINK_STATE_NAMES[link.state]
    else:
        raise AttributeError(name)
    function = getattr(module, name)

    def method(*args, **kwargs):
        return function(session, *args, **kwargs)

    # Kept on the instance: later calls find it there and allocate nothing (send_request and
    # send_reply run at message rate).
    setattr(session, name, method)
    return method
