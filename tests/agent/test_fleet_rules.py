"""The fleet file's rules (xrce.agent.middleware.ros.fleet), without ROS: which board a rule
matches (key, address or network, serial device through its symbolic links), first match wins,
the command line's names for the others, how a rule combines with them, and every kind of error
in the file as one line with the file, the line and the key."""

import ipaddress
import os

import pytest

from xrce.agent.middleware import ClientOrigin
from xrce.agent.middleware.ros.fleet import Fleet, FleetError
from xrce.agent.middleware.ros.naming import Naming


def fleet_file(tmp_path, text, name="fleet.toml"):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def origin(key="aabbccdd", address=None, device=None):
    return ClientOrigin(bytes.fromhex(key), ipaddress.ip_address(address) if address else None,
                        device)


RULES = """
[[board]]
name = "by key"
key = ["0xAABBCCDD", "11223344"]
namespace = "/robot1"

[[board]]
name = "by network"
address = ["10.0.0.0/24", "fd00::7"]
namespace = "/robot2"
domain = 7

[[board]]
name = "by key and address"
key = "0x55667788"
address = "192.168.1.9"
namespace = "/robot3"
"""


def test_matching_by_key_address_network_and_both(tmp_path):
    fleet = Fleet(fleet_file(tmp_path, RULES))
    assert fleet.assign(origin("aabbccdd"))[1] == "by key"
    assert fleet.assign(origin("11223344"))[0].namespace == "/robot1"
    naming, rule = fleet.assign(origin("99999999", "10.0.0.42"))
    assert rule == "by network" and naming.namespace == "/robot2" and naming.domain == 7
    assert fleet.assign(origin("99999999", "fd00::7"))[1] == "by network"
    assert fleet.assign(origin("99999999", "10.0.1.42"))[1] is None  # outside the /24
    # every key a rule names must match: the right key from the wrong address is not robot 3
    assert fleet.assign(origin("55667788", "192.168.1.9"))[1] == "by key and address"
    assert fleet.assign(origin("55667788", "192.168.1.10"))[1] is None
    assert fleet.assign(origin("55667788"))[1] is None  # a serial board has no address
    assert fleet.domains() == {7}


def test_first_match_wins_and_others_get_the_command_line_names(tmp_path):
    path = fleet_file(tmp_path, RULES + '\n[[board]]\nname = "late"\nkey = "aabbccdd"\n'
                                        'namespace = "/never"\n')
    base = Naming("/yard", [("chatter", "talk")], domain=3)
    fleet = Fleet(path, base)
    naming, rule = fleet.assign(origin("aabbccdd", "10.0.0.1"))  # rules 1, 2 and 4 match
    assert rule == "by key" and naming.namespace == "/robot1"
    naming, rule = fleet.assign(origin("01020304"))
    assert rule is None and naming is base
    assert naming.name("/cmd_vel") == "/yard/cmd_vel"


def test_a_rule_over_the_command_line(tmp_path):
    path = fleet_file(tmp_path, """
[[board]]
key = "aabbccdd"
remaps = { chatter = "news", cmd_vel = "/safety/cmd_vel" }

[[board]]
key = "11223344"
namespace = "/robot2"
domain = 9
remaps = ["odom:=wheel_odom"]
global_topics = ["/map"]
""")
    base = Naming("/yard", [("chatter", "talk"), ("scan", "laser")], ["/tf"], domain=3)
    fleet = Fleet(path, base)
    kept, rule = fleet.assign(origin("aabbccdd"))
    assert rule == "rule 1 (line 2)"  # no name: its number and line
    # namespace and domain the agent's; the agent's remaps plus the rule's, the rule's winning
    assert kept.namespace == "/yard" and kept.domain == 3
    assert kept.name("/chatter") == "/yard/news" and kept.name("/scan") == "/yard/laser"
    assert kept.name("/cmd_vel") == "/safety/cmd_vel" and kept.name("/tf") == "/tf"
    given, _ = fleet.assign(origin("11223344"))
    assert given.namespace == "/robot2" and given.domain == 9
    assert given.name("/odom") == "/robot2/wheel_odom" and given.name("/chatter") == "/robot2/talk"
    # the rule's global names replace the agent's
    assert given.name("/map") == "/map" and given.name("/tf") == "/robot2/tf"
    assert given.node_namespace("/") == "/robot2"


def test_device_glob_matches_through_symbolic_links(tmp_path):
    by_id = tmp_path / "by-id"
    by_id.mkdir()
    (tmp_path / "ttyACM0").write_text("")
    (tmp_path / "ttyACM1").write_text("")
    os.symlink(tmp_path / "ttyACM0", by_id / "usb-STM_Virtual_COM_Port_123-if00")
    os.symlink(tmp_path / "ttyACM1", by_id / "usb-FTDI_FT232R_456-if00")
    fleet = Fleet(fleet_file(tmp_path, """
[[board]]
name = "stm"
device = "%s/usb-STM*"
namespace = "/stm"

[[board]]
name = "second port"
device = ["%s/ttyUSB*", "%s/ttyACM1"]
namespace = "/ftdi"
""" % (by_id, tmp_path, tmp_path)))
    # opened as /dev/ttyACM0 by the agent: the by-id glob's match resolves to it
    assert fleet.assign(origin(device=str(tmp_path / "ttyACM0")))[1] == "stm"
    assert fleet.assign(origin(device=str(by_id / "usb-STM_Virtual_COM_Port_123-if00")))[1] == "stm"
    # opened through the FTDI's by-id link: the second rule's plain path is the same device
    assert fleet.assign(origin(device=str(by_id / "usb-FTDI_FT232R_456-if00")))[1] == "second port"
    assert fleet.assign(origin(device=str(tmp_path / "ttyACM7")))[1] is None
    assert fleet.assign(origin(address="10.0.0.1"))[1] is None  # no device at all


def test_reload_applies_a_good_file_and_keeps_the_rules_on_a_bad_one(tmp_path, caplog):
    path = fleet_file(tmp_path, '[[board]]\nname = "one"\nkey = "aabbccdd"\nnamespace = "/a"\n')
    fleet = Fleet(path)
    assert fleet.describe() == "fleet file %s: 1 rule: one" % path
    fleet_file(tmp_path, '[[board]]\nname = "two"\nkey = "aabbccdd"\nnamespace = "/b"\n')
    assert fleet.reload()
    assert fleet.assign(origin())[0].namespace == "/b"
    fleet_file(tmp_path, '[[board]]\nname = "three"\nkey = "aabbccdd"\nnamespace = "b"\n')
    assert not fleet.reload()
    assert fleet.assign(origin())[1] == "two"
    warning = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warning) == 1 and "line 4" in warning[0] and "'namespace'" in warning[0] \
        and "stay" in warning[0]


@pytest.mark.parametrize("text, line, mentions", [
    # TOML syntax: tomllib's line, and the key on it
    ('[[board]]\nkey = "aabbccdd"\nnamespace = /robot1\n', 3, "key 'namespace': TOML syntax"),
    ('[[board]]\nkey = "aabbccdd"\n[[board]\nkey = "11223344"\n', 3, "TOML syntax"),
    # unknown keys, at the top and in a rule
    ('robots = 2\n[[board]]\nkey = "aabbccdd"\n', 1, "key 'robots': unknown"),
    ('[[board]]\nkey = "aabbccdd"\n\n[[board]]\nkey = "11223344"\nnamspace = "/r"\n', 6,
     "key 'namspace': unknown key"),
    # bad values
    ('[[board]]\nkey = "0xAABBCCDDEE"\n', 2, "key 'key': '0xAABBCCDDEE' is not a client key"),
    ('[[board]]\nkey = "0"\n', 2, "key 'key': client key 0 is invalid"),
    ('[[board]]\naddress = "10.0.0.300/24"\n', 2, "key 'address': '10.0.0.300/24' is not"),
    ('[[board]]\nkey = "aabbccdd"\n\n\nnamespace = "robot1"\n', 5,
     "key 'namespace': namespace 'robot1' is not absolute"),
    ('[[board]]\nkey = "aabbccdd"\nnamespace = "/bad//ns"\n', 3, "not a valid ROS name"),
    ('[[board]]\nkey = "aabbccdd"\ndomain = 300\n', 3, "key 'domain': 300 is not a ROS domain"),
    ('[[board]]\nkey = "aabbccdd"\nremaps = ["cmd_vel=x"]\n', 3, "key 'remaps': remap"),
    ('[[board]]\nkey = "aabbccdd"\n[board.remaps]\nchatter = "news"\n"cmd vel" = "x"\n', 5,
     "key 'remaps': remap source 'cmd vel' is not a valid ROS name"),
    ('[[board]]\nkey = "aabbccdd"\nglobal_topics = ["tf"]\n', 3, "key 'global_topics'"),
    ('[[board]]\nname = "a"\nkey = "aabbccdd"\n[[board]]\nname = "a"\nkey = "11223344"\n', 5,
     "key 'name': 'a' is already rule 1's"),
    ('[[board]]\nname = "nothing to match"\nnamespace = "/r"\n', 1, "matches no board"),
    # bad types
    ('[[board]]\nkey = 0xAABBCCDD\n', 2, "key 'key': key must be a string"),
    ('[[board]]\nkey = "aabbccdd"\ndomain = "7"\n', 3, "key 'domain': '7' is not a ROS domain"),
    ('[[board]]\nkey = "aabbccdd"\ndomain = true\n', 3, "key 'domain'"),
    ('[[board]]\nkey = "aabbccdd"\nnamespace = ["/a"]\n', 3, "key 'namespace': must be a string"),
    ('[[board]]\nkey = "aabbccdd"\nremaps = { chatter = 3 }\n', 3, "key 'remaps'"),
    ('[[board]]\nkey = "aabbccdd"\nname = 7\n', 3, "key 'name': must be a non-empty string"),
    ('board = 3\n', 1, "key 'board': must be [[board]] tables"),
    ('board = [3]\n', 1, "must be tables"),
])
def test_every_error_is_one_line_with_file_line_and_key(tmp_path, text, line, mentions):
    path = fleet_file(tmp_path, text)
    with pytest.raises(FleetError) as raised:
        Fleet(path)
    message = str(raised.value)
    assert "\n" not in message
    assert message.startswith("fleet file %s line %d:" % (path, line)), message
    assert mentions in message, message


def test_unreadable_and_binary_files(tmp_path):
    with pytest.raises(FleetError, match="cannot read fleet file .*missing.toml"):
        Fleet(str(tmp_path / "missing.toml"))
    path = tmp_path / "latin1.toml"
    path.write_bytes(b'[[board]]\nname = "caf\xe9"\n')
    with pytest.raises(FleetError, match="line 2: not UTF-8"):
        Fleet(str(path))
