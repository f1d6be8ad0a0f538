# Link supervision and automatic recovery of a client session.
#
# The agent never tells a client that it went away: a restarted agent simply does not know the
# session, and a vanished one answers nothing. ``LinkMonitor`` watches what the session hears: after
# ``liveliness_ms`` of silence it pings inside the session (GET_INFO), then every ``retry_ms`` while
# no answer comes, and it declares the link lost when the unanswered pings span ``max_missed`` times
# ``liveliness_ms`` or when an agent answers that it does not know the session (INFO with
# implementation status 0). Pinging every ``retry_ms`` is what notices a restarted agent soon: its
# first answer says the session is unknown. While lost it repeats CREATE_CLIENT every ``retry_ms``;
# once the agent accepts, the session re-creates every entity and READ_DATA it had (REUSE|REPLACE, so
# an agent that kept them reuses them; xrce.client.entities keeps that log, xrce.client.lifecycle
# replays it) and
# carries on. Nothing here blocks: ``poll`` is called from the session's run loops.

from xrce import const, ticks_add, ticks_diff

_LINK_CONNECTED = const(0)
_LINK_SILENT = const(1)  # the agent has been quiet for a while; pings are out
_LINK_LOST = const(2)  # re-creating the session
LINK_STATE_NAMES = ("connected", "silent", "lost")


class LinkMonitor:
    # No __slots__: see xrce.client.outbound._Output.

    def __init__(self, session, liveliness_ms=500, retry_ms=250, max_missed=3, on_state=None):
        self.session = session
        self.liveliness_ms = liveliness_ms
        self.retry_ms = retry_ms
        self.max_missed = max_missed
        self.on_state = on_state
        self.state = _LINK_CONNECTED
        self.missed = 0
        # Unanswered pings, ``retry_ms`` apart, that make the link lost: as long a silence as
        # ``max_missed`` pings ``liveliness_ms`` apart would be.
        self.max_pings = max(max_missed, max_missed * liveliness_ms // max(retry_ms, 1))
        self.next_ping = 0
        self.next_attempt = 0
        self.recoveries = 0

    def _set(self, state):
        if state != self.state:
            self.state = state
            if self.on_state is not None:
                self.on_state(self.session, LINK_STATE_NAMES[state])

    def lose(self, now):
        session = self.session
        session.connected = False
        session.create_status = None
        session._session_unknown = False
        # What the streams still hold can no longer arrive: a re-created session starts every
        # stream afresh. Kept until _restore, it went out as HEARTBEATs (and retransmissions)
        # between CREATE_CLIENT and the re-creations, and an agent that had just accepted the
        # session moved its new input stream past them, so it never created our entities.
        session._reset_streams()
        self.next_attempt = now
        self._set(_LINK_LOST)

    def poll(self, now):
        session = self.session
        if self.state == _LINK_LOST:
            if session.create_status == 0:  # STATUS_OK to our CREATE_CLIENT
                self.missed = 0
                self.recoveries += 1
                session._restore()  # xrce.client.lifecycle: re-creates what the session had
                self._set(_LINK_CONNECTED)
            elif ticks_diff(now, self.next_attempt) >= 0:
                session._send_create_client()
                self.next_attempt = ticks_add(now, self.retry_ms)
            return
        if not session.connected:
            return  # never created, or deleted by the application: nothing to supervise
        if session._session_unknown:
            self.lose(now)
            return
        if ticks_diff(now, session._last_heard) < self.liveliness_ms:
            self.missed = 0
            self._set(_LINK_CONNECTED)
            return
        if ticks_diff(now, self.next_ping) >= 0:
            if self.missed >= self.max_pings:
                self.lose(now)
                return
            if self.missed:
                self._set(_LINK_SILENT)
            self.missed += 1
            session._send_ping()
            # An answering agent resets ``missed`` above, and the next ping then waits for
            # ``liveliness_ms`` of silence again: the short period only applies to a silent link.
            self.next_ping = ticks_add(now, self.retry_ms)
