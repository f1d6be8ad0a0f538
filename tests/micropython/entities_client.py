"""Set-up and teardown through xrce.client.entities and xrce.client.lifecycle, run by
tests/board/test_micropython_entities.py under MicroPython (run.mjs --stepped, from .py and from .mpy)
and under CPython, over a transport that records what the session sends and answers CREATE_CLIENT.

Prints "SENT <hex>" for each message sent (compared between the interpreters), "GONE <call> <bool>"
on MicroPython (xrce.client.entities and xrce.client.lifecycle are out of sys.modules and of their
package after the call),
"ATTR <name> <error type>" for names the session must refuse, "LINK <state>" (and on MicroPython
"LINK_ALLOC", what reading it ROUNDS more times allocated), and on MicroPython the heap
("live_setup", "peak_setup") and the time each call took ("TIME <call> <us>"; "CALL_US", "HELD_CALL_US",
"LOAD_US": means of a participant's creation through the session and through the module held by
the caller, and of a bare import of the module), "HELD_SAME"/"HELD_RELEASED" (hold_set_up keeps one
module until released; None on CPython) and on MicroPython "HELD_ALLOC" (see below).
"""

import sys

from xrce import IS_MICROPYTHON, ticks_diff, ticks_us

if IS_MICROPYTHON:
    import mpheap
else:  # no harness steps main() (tests/micropython/mpheap.py is importable from here, but unused)
    mpheap = None
from xrce.client.session import Session
from xrce.msgs.geometry_msgs import Twist
from xrce.msgs.std_msgs import String

# STATUS_AGENT, OK, to the keyless session 0x81: header, subheader (id 4, little-endian, 2 bytes).
ROUNDS = 20
STATUS_AGENT_OK = b"\x81\x00\x00\x00\x04\x01\x02\x00\x00\x00"


class Capture:
    mtu = 512

    def __init__(self):
        self.sent = []
        self.reply = None

    def send(self, data):
        data = bytes(data)
        self.sent.append(data)
        if data[4] == 0:  # CREATE_CLIENT
            self.reply = STATUS_AGENT_OK
        return True

    def recv(self, timeout_ms):
        reply, self.reply = self.reply, None
        return reply

    def close(self):
        pass


def _gone():
    package = sys.modules["xrce.client"].__dict__
    return all("xrce.client." + name not in sys.modules and name not in package
               for name in ("entities", "lifecycle"))


def _ignore(message):
    pass


def _drop_entities():
    sys.modules.pop("xrce.client.entities", None)


# What ``function()`` allocated (MicroPython: this port collects only between steps, so within one
# the difference is all of it; CPython: 0).
def _allocated(function):
    if not IS_MICROPYTHON:
        function()
        return 0
    import gc

    before = gc.mem_alloc()
    function()
    return gc.mem_alloc() - before


# The mean time of ROUNDS calls of ``function``, each after ``before()`` and in a step of its own.
def _mean_us(function, before):
    took = 0
    for _ in range(ROUNDS):
        before()
        began = ticks_us()
        function()
        took += ticks_diff(ticks_us(), began)
        yield
    return took // ROUNDS


def main():
    yield
    start = mpheap.live if mpheap else 0
    transport = Capture()
    calls = []

    def call(name, function, *args, **kwargs):
        began = ticks_us()
        result = function(*args, **kwargs)
        took = ticks_diff(ticks_us(), began)
        calls.append(name)
        if session is not None:
            session.flush()  # one message per call: a difference shows which call made it
        if IS_MICROPYTHON:
            print("GONE", name, _gone())
            print("TIME", name, took)
        return result

    session = None
    session = call("Session", Session, transport, key=b"\x01\x02\x03\x04", history=16)
    yield
    call("create", lambda: session.create(attempts=1, timeout_ms=100))
    yield
    node = call("create_participant", lambda: session.create_participant(name="mp_node"))
    yield
    writer = call("create_writer", lambda: session.create_writer(node, "/mp_chatter", String, reliable=False))
    yield
    reader = call("create_reader", lambda: session.create_reader(node, "/mp_cmd", Twist, _ignore))
    yield
    topic = call("create_topic", lambda: session.create_topic(node, "rt/raw", "std_msgs::msg::dds_::String_"))
    yield
    subscriber = call("create_subscriber", lambda: session.create_subscriber(node))
    yield
    raw = call("create_datareader", lambda: session.create_datareader(
        subscriber, topic, session.endpoint_qos(True, True, 5, True)))
    yield
    call("read_data", lambda: session.read_data(raw, session.best_effort, max_samples=3))
    yield
    call("flush", session.flush)
    session.write(writer, String(data="hello"), stream_id=session.best_effort)
    session.flush()
    yield
    if mpheap:
        # Live heap the set-up left, and the most any of its calls needed (with what was live
        # then), both above what the script had imported.
        print("live_setup", mpheap.live - start)
        print("peak_setup", mpheap.peak - start)
    # Held (hold_set_up): the creation code is loaded once for the calls in a row, not per call;
    # what is sent does not change. On MicroPython "HELD_ALLOC <held> <not held>" gives what a
    # writer's creation allocated each way.
    session.hold_set_up()
    yield
    held_module = session._held
    held = _allocated(lambda: session.create_writer(node, "/mp_held", String, reliable=False))
    session.flush()
    print("HELD_SAME", session._held is held_module)
    session.hold_set_up(False)
    print("HELD_RELEASED", session._held is None)
    yield
    not_held = _allocated(lambda: session.create_writer(node, "/mp_not_held", String, reliable=False))
    session.flush()
    if IS_MICROPYTHON:
        print("HELD_ALLOC", held, not_held)
    yield
    call("cancel_data", lambda: session.cancel_data(raw))
    yield
    call("delete_entity", lambda: session.delete_entity(reader))
    yield
    call("_restore", lambda: session._restore())  # what auto-recovery sends after the agent lost the session
    yield
    # After its first read link_state is a property of the class: a firmware that polls it on every
    # pass must not load xrce.client.entities each time (~7 KB of garbage a load).
    print("LINK", session.link_state)
    if IS_MICROPYTHON:
        import gc

        before = gc.mem_alloc()  # this port collects only between steps: the delta is all allocation
        for _ in range(ROUNDS):
            session.link_state
        print("LINK_ALLOC", gc.mem_alloc() - before)
    yield
    call("delete", lambda: session.delete(attempts=1, timeout_ms=0))
    yield
    for name in ("", " ", "create_writer create_reader", "__wrapped__", "_NAMES", "session_attr", "bind"):
        try:
            getattr(session, name)
            print("ATTR", repr(name), "none")
        except AttributeError:
            print("ATTR", repr(name), "AttributeError")
    if IS_MICROPYTHON:
        # Call time: the timer counts whole milliseconds here, so each figure is a mean of ROUNDS.
        # A participant created through the session (the module imported for the call) and through
        # the module held by the caller (what CPython's bound methods cost), and a bare import.
        timed = Session(Capture(), key=b"\x01\x02\x03\x05", auto_recover=False, history=16)
        mean = yield from _mean_us(lambda: timed.create_participant(name="t"), timed.flush)
        print("CALL_US", mean)
        import xrce.client.entities as held

        mean = yield from _mean_us(lambda: held.create_participant(timed, name="t"), timed.flush)
        print("HELD_CALL_US", mean)
        mean = yield from _mean_us(lambda: __import__("xrce.client.entities"), _drop_entities)
        print("LOAD_US", mean)
    for message in transport.sent:
        print("SENT", "".join("%02x" % byte for byte in message))


if not IS_MICROPYTHON:
    for _ in main():
        pass
