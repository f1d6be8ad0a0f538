"""Set-up and teardown (xrce.client.entities, xrce.client.lifecycle) under real MicroPython 1.27,
from .py and from .mpy: each module is imported for a call and dropped again, the bytes the session
sends for the session, its entities, their READ_DATAs, deletions and the re-creation after a lost
session are CPython's, and names the session does not serve raise AttributeError (no recursion
through the on-demand hook).

With -s the test prints what a board pays per call (the module's import) and the set-up's heap."""

import subprocess
import sys
from pathlib import Path

import pytest

from mp_harness import REPO_ROOT, run_micropython
from xrce.tools import mpy

SCRIPT = Path(__file__).resolve().parents[1] / "micropython" / "entities_client.py"
CALLS = ("Session", "create", "create_participant", "create_writer", "create_reader", "create_topic",
         "create_subscriber", "create_datareader", "read_data", "flush", "cancel_data", "delete_entity",
         "_restore", "delete")
REFUSED = ("''", "' '", "'create_writer create_reader'", "'__wrapped__'", "'_NAMES'", "'session_attr'",
           "'bind'")


def _parse(stdout):
    sent, gone, attrs, times, figures = [], {}, {}, {}, {}
    for line in stdout.splitlines():
        key, _, rest = line.partition(" ")
        if key == "SENT":
            sent.append(rest)
        elif key == "GONE":
            name, value = rest.split()
            gone[name] = value
        elif key == "ATTR":
            name, value = rest.rsplit(" ", 1)
            attrs[name] = value
        elif key == "TIME":
            name, value = rest.split()
            times[name] = int(value)
        elif rest:
            figures[key] = rest
    return sent, gone, attrs, times, figures


@pytest.fixture(scope="module")
def cpython_run():
    result = subprocess.run([sys.executable, str(SCRIPT)], capture_output=True, text=True, timeout=60,
                            cwd=REPO_ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
    return _parse(result.stdout)


@pytest.mark.parametrize("form", ["py", "mpy"])
def test_entities_module_is_dropped_after_each_call_and_sends_cpythons_bytes(form, cpython_run, tmp_path):
    if form == "mpy":
        mpy.build_mpy(tmp_path)
        mounts, default_mount = [(tmp_path, "/lib")], False
    else:
        mounts, default_mount = [], True
    result = run_micropython(SCRIPT, mounts=mounts, default_mount=default_mount, stepped=True,
                             heap=256 * 1024, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    sent, gone, attrs, times, figures = _parse(result.stdout)
    expected_sent, _, expected_attrs, _, _ = cpython_run
    assert len(sent) >= 12
    assert sent == expected_sent
    assert gone == {name: "True" for name in CALLS}
    assert attrs == expected_attrs == {name: "AttributeError" for name in REFUSED}
    assert figures["LINK"] == cpython_run[4]["LINK"] == "connected"
    # Twenty reads of link_state: no load of the entities module (~7 KB each) among them.
    assert int(figures["LINK_ALLOC"]) < 1024, figures["LINK_ALLOC"]
    # hold_set_up: one module for the calls in a row, released after; a held creation does not load
    # the module's code (~3.6 KB from .mpy, more compiled from .py) and what it sends is unchanged.
    assert figures["HELD_SAME"] == figures["HELD_RELEASED"] == "True"
    assert cpython_run[4]["HELD_SAME"] == cpython_run[4]["HELD_RELEASED"] == "True"
    held, not_held = map(int, figures["HELD_ALLOC"].split())
    assert held + 3000 < not_held, figures["HELD_ALLOC"]
    print("\n%s: per call (us, whole ms) %s;\n  a participant through the session %s us, through the module "
          "held %s us, one import of the module %s us; set-up: live heap %s B, peak %s B; a writer's "
          "creation allocates %s B held, %s B not held" % (
              form, times, figures["CALL_US"], figures["HELD_CALL_US"], figures["LOAD_US"],
              figures["live_setup"], figures["peak_setup"], held, not_held))
