"""The agent's event loop (xrce.agent.cli.event_loop): uvloop by default, the standard
library's asyncio loop with ``XRCE_AGENT_LOOP=asyncio``. Every other test's agent process runs on
uvloop and the in-process engine tests on asyncio; here the same real scenarios (tests/
test_fastpath.py: a board's best-effort and reliable streams through a real agent process, real
sockets and rclpy) run on both loops and must deliver, acknowledge and count the same."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import uvloop  # a dependency of xrce: its absence is a failure here, not a skip

from ros_helpers import ros_domain, ros_peer  # noqa: F401
from test_fastpath import needs_extension, run_reliable_scenario, run_scenario
from xrce.agent.cli.arguments import CliError
from xrce.agent.cli.event_loop import event_loop

AGENT = str(Path(sys.executable).parent / "xrce-agent")


def _agent(*args, **env):
    return subprocess.run([AGENT, *args], env=dict(os.environ, **env), capture_output=True,
                          text=True, timeout=60)


def test_uvloop_by_default_asyncio_when_asked():
    assert event_loop({})[0] == event_loop({"XRCE_AGENT_LOOP": "uvloop"})[0] \
        == "uvloop %s" % uvloop.__version__
    assert event_loop({})[1] is uvloop.new_event_loop
    assert event_loop({"XRCE_AGENT_LOOP": "asyncio"}) == ("asyncio", None)
    with pytest.raises(CliError, match="XRCE_AGENT_LOOP must be uvloop or asyncio, not 'trio'"):
        event_loop({"XRCE_AGENT_LOOP": "trio"})


_IMPORT_AS_THE_AGENT_DOES = """
import sys
from xrce.agent import launcher
launcher._import_asyncio_without_tls()
from xrce.agent.cli import event_loop as chosen
if sys.argv[1] == "refuse":  # a uvloop that needs more of ssl at import than the stand-in gives
    def refuse(self, name):
        raise AttributeError(name)
    chosen._NoTls.__getattr__ = refuse
import asyncio
description, factory = chosen.event_loop({})
loop = factory()
print(description, type(loop).__module__, loop.run_until_complete(asyncio.sleep(0.01, "ran")),
      type(sys.modules.get("ssl")).__name__)
"""


@pytest.mark.parametrize("stand_in", ["names", "refuse"])
def test_uvloop_is_imported_without_ssl_or_else_with_the_real_one(stand_in):
    """The agent's uvloop reads ssl's names from a stand-in (the real ssl is 1.2 MB resident);
    should a uvloop need more, it is imported again with the real ssl, and runs."""
    done = subprocess.run([sys.executable, "-c", _IMPORT_AS_THE_AGENT_DOES, stand_in],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    expected_ssl = "NoneType" if stand_in == "names" else "module"
    assert done.stdout.split() == ["uvloop", uvloop.__version__, "uvloop", "ran", expected_ssl]


def test_version_names_the_loop_and_a_bad_choice_is_one_line_and_exit_2():
    assert "Python %d.%d.%d, uvloop %s)" % (sys.version_info[:3] + (uvloop.__version__,)) \
        in _agent("--version").stdout.splitlines()[0]
    assert ", asyncio)" in _agent("--version", XRCE_AGENT_LOOP="asyncio").stdout.splitlines()[0]
    done = _agent("udp4", "-p", "0", XRCE_AGENT_LOOP="trio")
    assert done.returncode == 2 and done.stdout == "", done
    assert done.stderr == "xrce-agent: error: XRCE_AGENT_LOOP must be uvloop or asyncio, not 'trio'\n"


@needs_extension
def test_both_loops_deliver_and_count_the_same_best_effort_stream(ros_peer, ros_domain):  # noqa: F811
    runs = {loop: run_scenario(ros_peer, ros_domain, "/loop_be_" + loop, {"XRCE_AGENT_LOOP": loop})
            for loop in ("uvloop", "asyncio")}
    assert "event loop: uvloop %s" % uvloop.__version__ in runs["uvloop"][2]
    assert "event loop: asyncio" in runs["asyncio"][2]
    expected = [1.0, 2.0, 3.0, 4.0, 5.0, 11.0, 12.0, 14.0] + [15.0] * 17
    assert runs["uvloop"][0] == runs["asyncio"][0] == expected
    counted = ("messages_in", "client_messages_in", "samples_in", "topic_samples", "dropped",
               "decode_errors", "bytes_in")
    assert {k: runs["uvloop"][1][k] for k in counted} == {k: runs["asyncio"][1][k] for k in counted}
    assert runs["uvloop"][1]["samples_in"] == 25


@needs_extension
def test_both_loops_deliver_acknowledge_and_count_the_same_reliable_stream(ros_peer, ros_domain):  # noqa: F811
    runs = {loop: run_reliable_scenario(ros_peer, ros_domain, "/loop_rel_" + loop,
                                        {"XRCE_AGENT_LOOP": loop})
            for loop in ("uvloop", "asyncio")}
    assert "event loop: uvloop" in runs["uvloop"][3] and "event loop: asyncio" in runs["asyncio"][3]
    assert runs["uvloop"][0] == runs["asyncio"][0] == [float(v) for v in range(1, 11)]
    assert runs["uvloop"][1] == runs["asyncio"][1]  # every ACKNACK, step by step
    assert runs["uvloop"][2] == runs["asyncio"][2]
