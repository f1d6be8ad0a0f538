"""``help(Session)`` and ``inspect.signature`` on CPython (issue 52): every public method a session
serves is the class's own at import, including those a board loads on first use
(xrce.client.on_demand: time sync, ping, services, link state), so a user reading the API from a
shell sees each one with its arguments before having created anything.
"""

import inspect
import pydoc
import subprocess
import sys

from xrce.client import entities, on_demand, session as session_module
from xrce.client.session import Session


def _served_names():
    """Every public name Session's __getattr__ can hand out on a board, from the tables it reads."""
    tables = (entities._NAMES, session_module._LIFECYCLE, session_module._ON_DEMAND, on_demand._SERVICES)
    return sorted(set(name for table in tables for name in table.split() if not name.startswith("_")))


def test_every_served_name_is_on_the_class_before_first_use():
    # A fresh interpreter: no instance has looked any name up yet (the first look-up would set it).
    code = ("import inspect; from xrce.client.session import Session; import sys\n"
            "names = sys.argv[1:]\n"
            "missing = [n for n in names if n not in vars(Session)]\n"
            "print('missing', missing)\n"
            "for n in names:\n"
            "    attribute = vars(Session).get(n)\n"
            "    if callable(attribute):\n"
            "        print(n, inspect.signature(getattr(Session, n)))\n")
    result = subprocess.run([sys.executable, "-c", code] + _served_names(), capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0] == "missing []", result.stdout
    signatures = dict(line.split(" ", 1) for line in lines[1:])
    assert signatures["create_service_server"] == (
        "(session, participant_id, service, srv, callback, stream_id=None, data_stream_id=None)")
    assert signatures["send_reply"] == "(session, replier_id, sample_identity, data, stream_id=None)"
    assert signatures["sync_time"].startswith("(session, timeout_ms=1000")


def test_help_shows_each_public_method_and_how_a_service_is_answered():
    text = pydoc.render_doc(Session, renderer=pydoc.plaintext)
    for name in _served_names():
        assert "\n |  %s" % name in text, name
    server = pydoc.render_doc(Session.create_service_server, renderer=pydoc.plaintext)
    assert "callback(sample_identity, request)" in server and "send_reply(replier_id, sample_identity" in server
    client = inspect.getdoc(Session.create_service_client)
    assert "callback(request_id, response)" in client and "send_request(requester_id" in client


def test_link_state_and_time_offset_are_properties_a_new_session_reads():
    assert isinstance(vars(Session)["link_state"], property)
    assert isinstance(vars(Session)["time_offset_ns"], property)
