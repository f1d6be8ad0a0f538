"""Entity creation time as micro-ROS firmware sees it: the set-up of tests/golden/microros/main.jsonl
(rclc + rmw_microxrcedds: node, /sensor_state topic + publisher + writer, /cmd_vel topic + subscriber
+ reader, /add_two_ints replier, /big_string topic + publisher + writer; binary, REUSE|REPLACE, each
CREATE waiting for its STATUS) replayed against ``xrce-agent -m dds`` over UDP, each run on a fresh
agent (the first topic of each type is first for it). Beside each figure, eProsima's
MicroXRCEAgent 2.4.3 answering the same CREATEs, from the capture's timestamps.

    .venv/bin/python bench/microros/entity_creation.py [--runs N] [--reference DIR] [--agent-cmd CMD]

Figures: node + 4 entities (participant CREATE sent -> STATUS of the 5th CREATE, the /cmd_vel
topic), the replier, the first TOPIC of a type (SensorState, Twist; median of both), and the
whole set-up. Needs turtlebot3_msgs and example_interfaces (tests/interfaces), built here first
(a cache hit after the first time).
"""

import os
import statistics
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from agent_process import AgentProcess  # noqa: E402
from microros_replay import Capture, Replayer, UdpChannel  # noqa: E402

from bench.common.figures import record  # noqa: E402
from bench.common.peer_agent import CommandAgent  # noqa: E402
from xrce.wire import constants as C  # noqa: E402

INTERFACES = REPO / "tests" / "interfaces"
# The agent of another checkout (--reference): an editable install's .pth imports this checkout's
# xrce before sys.path applies, so those modules are dropped first (as bench/agent/cost.py does),
# and the venv's built interface packages registered again with the other tree's registry (the
# .pth hook of build-interfaces), or its agent would look for them on first use (~0.1 s).
_TREE_BOOTSTRAP = ("import os, runpy, site, sys\n"
                   "for name in [m for m in sys.modules if m == 'xrce' or m.startswith('xrce.')]:\n"
                   "    del sys.modules[name]\n"
                   "sys.path.insert(0, %r)\n"
                   "for folder in site.getsitepackages():\n"
                   "    hook = os.path.join(folder, 'xrce_interfaces.pth')\n"
                   "    if os.path.exists(hook):\n"
                   "        exec(open(hook).read())\n"
                   "sys.argv[0] = 'xrce-agent'\n"
                   "runpy.run_module('xrce.agent', run_name='__main__', alter_sys=True)\n")
PARTICIPANT, FIFTH, REPLIER = 0x000A, 0x000E, 0x0012
FIRST_TOPICS = (0x000B, 0x000E)  # SensorState, Twist


def _set_up(capture):
    """(steps up to the first sample, request ids of the set-up's CREATEs)."""
    for index, (_boot, data) in enumerate(capture.steps):
        if data[0] > 0x80 and len(data) > 4 and data[4] in (C.WRITE_DATA, C.FRAGMENT):
            return index, [rid for _b, rid, sub in capture.requests() if sub == C.CREATE]
    raise RuntimeError("no data in the capture")


def _eprosima(capture):
    """Seconds from each CREATE's message to its STATUS, as recorded against eProsima's agent."""
    sent, answered = {}, {}
    for record_ in capture.records:
        data = bytes.fromhex(record_["hex"])
        if data[0] <= 0x80:
            continue
        offset = 4
        while offset + 4 <= len(data):
            sub_id, length = data[offset], data[offset + 2] | (data[offset + 3] << 8)
            body = data[offset + 4:offset + 4 + length]
            rid = (body[0] << 8) | body[1] if len(body) >= 2 else None
            if record_["dir"] == "c2a" and sub_id == C.CREATE:
                sent.setdefault(rid, record_["t"])
            elif record_["dir"] == "a2c" and sub_id == C.STATUS:
                answered.setdefault(rid, record_["t"])
            offset = (offset + 4 + length + 3) & ~3
    return sent, answered


def figures_of(sent, answered):
    return {
        "node + 4 entities": answered[FIFTH] - sent[PARTICIPANT],
        "replier": answered[REPLIER] - sent[REPLIER],
        "first topic of a type": statistics.median(answered[t] - sent[t] for t in FIRST_TOPICS),
        "participant (node)": answered[PARTICIPANT] - sent[PARTICIPANT],
    }


def _replay_set_up(agent, capture, until, creates, domain_id=None):
    """(seconds each CREATE was sent at, seconds each was answered at) against ``agent``, the
    firmware's participant in ``domain_id`` (None: the capture's, 0)."""
    channel = UdpChannel(agent.port)
    try:
        replay = Replayer(capture, channel, domain_id=domain_id)
        answers = replay.run(until_step=until)
    finally:
        channel.close()
    bad = {hex(rid): answers.statuses.get((0, rid)) for rid in creates
           if answers.statuses.get((0, rid), (0, None))[1] not in (C.STATUS_OK,
                                                                   C.STATUS_OK_MATCHED)}
    if bad:
        raise RuntimeError("set-up CREATEs not answered OK: %r" % bad)
    return ({rid: t for (_b, rid), t in replay.sent_at.items()},
            {rid: t for (_b, rid), t in replay.answered_at.items()})


def measure(env, runs, agent_cmd=None, domain_id=None, reference=None):
    """(each run's figures, each run's whole set-up) for this agent, the ``reference`` tree's
    (another checkout, e.g. main before a change) and the other one (live with ``agent_cmd``,
    else once from the capture), taking turns in each run; the capture, the set-up's request
    ids. The firmware's participant asks for ``domain_id`` (None: the capture's domain 0)."""
    capture = Capture("main")
    until, creates = _set_up(capture)

    options = ("-m", "dds", "-v", "0", "--interfaces", str(INTERFACES))
    starts = [("xrce", lambda: AgentProcess("udp4", *options, env=env))]
    if reference:
        tree = str(Path(reference).resolve())
        starts.append(("reference", lambda: CommandAgent(
            [sys.executable, "-c", _TREE_BOOTSTRAP % tree], env, options=options, cwd=tree)))
    if agent_cmd:
        starts.append(("other", lambda: CommandAgent(agent_cmd, env)))
    results = {name: ([], []) for name, _ in starts}
    for _ in range(runs):
        for name, start in starts:
            with start() as agent:
                sent, answered = _replay_set_up(agent, capture, until, creates, domain_id)
            results[name][0].append(figures_of(sent, answered))
            results[name][1].append(answered[creates[-1]] - sent[creates[0]])
    if not agent_cmd:
        sent, answered = _eprosima(capture)
        results["other"] = ([figures_of(sent, answered)],
                            [answered[creates[-1]] - sent[creates[0]]])
    return results, creates


def report(record_, env, runs=5, agent_cmd=None, domain_id=None, reference=None):
    results, creates = measure(env, runs, agent_cmd, domain_id, reference)
    (runs_figures, whole), (other_figures, other_whole) = results["xrce"], results["other"]
    reference_figures, reference_whole = results.get("reference", ([], []))

    def reference_note(values):
        if not values:
            return ""
        return "; reference %s: median %.1f, runs %s" % (
            reference, statistics.median(values), ", ".join("%.1f" % v for v in values))
    baseline_name = ("%s, same CREATEs, live, median of %d" % (agent_cmd, runs) if agent_cmd
                     else "eProsima MicroXRCEAgent 2.4.3, same CREATEs (capture)")
    for name in runs_figures[0]:
        values = [figures[name] * 1000 for figures in runs_figures]
        others = [figures[name] * 1000 for figures in other_figures]
        record_("entity creation: %s (median of %d fresh agents)" % (name, runs),
                statistics.median(values), "ms", statistics.median(others), baseline_name,
                "<= 2x eProsima" if name != "participant (node)" else "",
                "runs: %s; other: %s" % (", ".join("%.1f" % v for v in values),
                                         ", ".join("%.1f" % v for v in others))
                + reference_note([figures[name] * 1000 for figures in reference_figures]))
    record_("entity creation: the firmware's whole set-up, %d CREATEs (median)" % len(creates),
            statistics.median(whole) * 1000, "ms", statistics.median(other_whole) * 1000,
            baseline_name, "",
            "runs: %s; other: %s" % (", ".join("%.1f" % (v * 1000) for v in whole),
                                     ", ".join("%.1f" % (v * 1000) for v in other_whole))
            + reference_note([v * 1000 for v in reference_whole]))


def build_interfaces(reference=None):
    """Here and in the ``reference`` tree, whose agent finds its shipped packages' builds apart."""
    trees = [None] + ([str(Path(reference).resolve())] if reference else [])
    for tree in trees:
        start = [sys.executable] + (["-c", _TREE_BOOTSTRAP % tree] if tree else
                                    ["-m", "xrce.agent"])
        for args in ([str(INTERFACES)], []):  # example_interfaces; turtlebot3_msgs shipped
            subprocess.run(start + ["build-interfaces", *args], cwd=tree or REPO, check=True,
                           stdout=subprocess.DEVNULL)


def main(argv=None):
    import argparse

    from ros_helpers import DomainLease

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--other-domain", action="store_true",
                        help="the firmware's node in the capture's domain 0, not the agent's own "
                        "(ROS_DOMAIN_ID): the agent then starts a DDS participant for it")
    parser.add_argument("--agent-cmd", metavar="CMD",
                        help="another agent (e.g. $PEERS/agent.sh, eProsima's agent built outside this repository), measured in the same run")
    parser.add_argument("--reference", metavar="DIR",
                        help="another checkout of this repository (e.g. main before a change) "
                        "whose agent takes turns with this one in each run")
    args = parser.parse_args(argv)
    build_interfaces(args.reference)
    lease = DomainLease()
    env = dict(os.environ, ROS_DOMAIN_ID=str(lease.domain_id),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    try:
        report(record, env, args.runs, args.agent_cmd,
               None if args.other_domain else lease.domain_id, args.reference)
    finally:
        lease.release()
    from bench.common.figures import print_table
    print_table()
    return 0


if __name__ == "__main__":
    sys.exit(main())
