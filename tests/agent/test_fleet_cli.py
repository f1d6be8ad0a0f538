"""``xrce-agent --fleet FILE`` as a real process: a fleet file that cannot be used stops the agent
before anything starts, with one line naming the file, the line and the key, and exit code 2 (as
every bad argument); the fleet file's rules are named in the agent's log at start."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from agent_process import AgentProcess

REPO = Path(__file__).resolve().parents[2]


def run_cli(*args, timeout=30):
    env = dict(os.environ, PYTHONUNBUFFERED="1",
               PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    done = subprocess.run([sys.executable, "-m", "xrce.agent", *args], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=timeout)
    return done.returncode, done.stdout, done.stderr


@pytest.mark.parametrize("text, mentions", [
    ('[[board]]\nkey = "aabbccdd"\nnamespace = /robot1\n', "line 3: key 'namespace': TOML syntax"),
    ('[[board]]\nkey = "aabbccdd"\nnamspace = "/robot1"\n', "line 3: key 'namspace': unknown"),
    ('[[board]]\nkey = "aabbccdd"\n\ndomain = 300\n', "line 4: key 'domain': 300 is not"),
    ('[[board]]\nkey = "aabbccdd"\nnamespace = ["/r"]\n', "line 3: key 'namespace': must be"),
    ('[[board]]\nkey = "aabbccdd"\nremaps = { "cmd vel" = "x" }\n',
     "line 3: key 'remaps': remap source 'cmd vel' is not a valid ROS name"),
])
def test_a_bad_fleet_file_is_one_line_and_exit_2(tmp_path, text, mentions):
    path = tmp_path / "fleet.toml"
    path.write_text(text)
    code, out, err = run_cli("udp4", "-p", "0", "--no-state", "--fleet", str(path))
    assert code == 2 and out == ""
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("xrce-agent: error: fleet file %s line " % path), lines[0]
    assert mentions in lines[0], lines[0]


def test_a_missing_fleet_file_and_a_fleet_without_ros(tmp_path):
    code, out, err = run_cli("udp4", "-p", "0", "--fleet", str(tmp_path / "none.toml"))
    assert code == 2 and len(err.splitlines()) == 1 and "cannot read fleet file" in err
    path = tmp_path / "fleet.toml"
    path.write_text('[[board]]\nkey = "aabbccdd"\nnamespace = "/robot1"\n')
    code, out, err = run_cli("udp4", "-p", "0", "-m", "ced", "--fleet", str(path))
    assert code == 2 and len(err.splitlines()) == 1 and "need -m dds" in err


def test_the_log_names_the_fleet_file_and_its_rules(tmp_path):
    path = tmp_path / "fleet.toml"
    path.write_text('[[board]]\nname = "robot1"\nkey = "aabbccdd"\nnamespace = "/robot1"\n\n'
                    '[[board]]\nname = "robot2"\naddress = "10.0.0.0/24"\nnamespace = "/robot2"\n'
                    'domain = 7\n')
    with AgentProcess("udp4", "-m", "dds", "--fleet", str(path), "-v", "5") as agent:
        pass
    log = "".join(agent.output)
    assert "fleet file %s: 2 rules: robot1, robot2" % path in log, log
    assert "fleet rule robot2 (from 10.0.0.0/24: namespace /robot2, domain 7)" in log, log


def test_the_rules_build_on_the_command_lines_names(tmp_path):
    """``--fleet`` with --namespace and --global-topics (in-process, as ``startup.check``
    parses): a board no rule matches gets the command line's names, a rule's board the rule's
    namespace over the command line's global names."""
    from xrce.agent.cli.startup import make_fleet, make_naming
    from xrce.agent.cli.subcommands import build_parser
    from xrce.agent.middleware import ClientOrigin

    path = tmp_path / "fleet.toml"
    path.write_text('[[board]]\nkey = "aabbccdd"\nnamespace = "/robot1"\n')
    argv = ["udp4", "-p", "0", "--global-topics", "/map", "--namespace", "yard",
            "--fleet", str(path)]
    args = build_parser(argv).parse_args(argv)
    args.ros_args = None
    args.naming = make_naming(args)
    fleet = make_fleet(args)
    given, rule = fleet.assign(ClientOrigin(bytes.fromhex("aabbccdd")))
    assert rule == "rule 1 (line 1)" and given.name("/odom") == "/robot1/odom"
    assert given.name("/map") == "/map" and given.name("/tf") == "/robot1/tf"
    other, rule = fleet.assign(ClientOrigin(bytes.fromhex("01020304")))
    assert rule is None and other.name("/odom") == "/yard/odom" and other.name("/map") == "/map"
    # --global-topics alone changes no name, yet a fleet's rules are built on it
    argv = ["udp4", "-p", "0", "--global-topics", "/map", "--fleet", str(path)]
    args = build_parser(argv).parse_args(argv)
    args.ros_args = None
    args.naming = make_naming(args)
    assert args.naming is not None and make_fleet(args).assign(
        ClientOrigin(bytes.fromhex("aabbccdd")))[0].name("/map") == "/map"
