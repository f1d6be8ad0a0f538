"""The fleet file (``--fleet FILE``, issue 53 item 2): names and a domain per board, by who it is.

``--ros-args -r __ns:=/robot3`` names every board of an agent alike; a fleet file gives each board
its own, chosen by what the agent knows of it when it creates its participant
(``xrce.agent.middleware.ClientOrigin``)::

    # fleet.toml
    [[board]]
    name = "robot1"                 # shown to operators (default "rule N (line L)")
    key = "0xAABBCCDD"              # client key(s), hex as --allow-keys: one or a list
    namespace = "/robot1"

    [[board]]
    name = "robot2"
    address = ["10.0.0.0/24"]       # source address or CIDR network, as --allow-from
    device = "/dev/serial/by-id/usb-STM*"   # serial device glob
    namespace = "/robot2"
    domain = 7
    remaps = { cmd_vel = "cmd_vel_safe" }   # or ["cmd_vel:=cmd_vel_safe"]
    global_topics = ["/tf", "/tf_static"]

Matching: a rule names at least one of ``key``, ``address``, ``device``; every one it names must
match (a list matches when any of its items does). A ``device`` glob matches the path the agent
opened or, through symbolic links, the same device: ``/dev/serial/by-id/usb-STM*`` matches a board
the agent opened as ``/dev/ttyACM0`` when one of the glob's matches resolves to it (checked when
the board arrives, so a board plugged in later is found). The first rule that matches wins; a
board no rule matches gets the command line's names (``--ros-args``, ``--namespace``,
``--domain``, ``--global-topics``).

How a rule combines with the command line's names: a rule's ``namespace`` and ``domain`` replace
the agent's; its ``remaps`` are added to the agent's, the rule's winning for the same name; its
``global_topics`` replace the agent's; what a rule does not set is the agent's.

Names are decided once per participant, when a board creates it: ``Fleet.reload`` (the agent's
SIGHUP) changes what boards created afterwards get, and entities that exist keep their names. A
file that does not load leaves the rules as they were.

Every error in the file is one line naming the file, the line and the key (``FleetError``); the
values are checked as the command line's are (``naming``). Like ``naming``, this module imports
nothing of ROS, so a bad file is refused before rclpy loads.
"""

from __future__ import annotations

import fnmatch
import glob
import logging
import os
import re
import tomllib

from xrce.agent.middleware import MAX_DOMAIN_ID
from xrce.agent.middleware.ros.naming import GLOBAL_NAMES, Naming, NamingError

log = logging.getLogger("xrce.agent.fleet")

MATCH_KEYS = ("key", "address", "device")
RULE_KEYS = ("name", "key", "address", "device", "namespace", "domain", "remaps", "global_topics")
TABLE = "board"


class FleetError(ValueError):
    """A fleet file that cannot be used: one line with the file, the line and the key."""


# ----------------------------------------------------------------------------- where a key is

_HEADER = re.compile(r"^\s*\[\[?\s*([^\]]+?)\s*\]\]?")


def _bare(key: str) -> str:
    return key.strip().strip("\"'")


class _Lines:
    """Where keys are in the text: tomllib gives lines for syntax errors only, and an error a
    user cannot find in a long file is half an error."""

    def __init__(self, text: str):
        self.lines = text.splitlines()
        self.rule_starts = [i for i, line in enumerate(self.lines)
                            if (m := _HEADER.match(line)) and line.lstrip().startswith("[[")
                            and _bare(m.group(1)) == TABLE]

    def _section(self, rule: int | None) -> range:
        if rule is None or rule >= len(self.rule_starts):
            return range(len(self.lines))
        start = self.rule_starts[rule]
        end = self.rule_starts[rule + 1] if rule + 1 < len(self.rule_starts) else len(self.lines)
        return range(start, end)

    def find(self, rule: int | None, key: str | None = None, inner: str | None = None) -> int:
        """The 1-based line of ``key`` in rule ``rule``'s part of the file (the whole file for
        None), or of ``inner`` (a remap's FROM) at or after it; the rule's header line, or 1,
        when the key is not found."""
        section = self._section(rule)
        fallback = self.rule_starts[rule] + 1 if rule is not None and \
            rule < len(self.rule_starts) else 1
        if key is None:
            return fallback
        own = re.compile(r"^\s*(?:%s\.)?[\"']?%s[\"']?\s*=|^\s*\[\s*(?:%s\.)?%s\s*\]"
                         % (TABLE, re.escape(key), TABLE, re.escape(key)))
        found = next((i for i in section if own.search(self._code(i))), None)
        if found is None:
            return fallback
        if inner is not None:
            nested = re.compile(r"(?:^|[{,\s])[\"']?%s[\"']?\s*=" % re.escape(inner))
            for i in range(found, section.stop):
                code = self._code(i)
                if i == found:  # ``remaps = { FROM = "TO" }``: what follows the key itself
                    code = code.split("=", 1)[1] if "=" in code else ""
                if nested.search(code):
                    found = i
                    break
        return found + 1

    def _code(self, index: int) -> str:
        return self.lines[index].split("#", 1)[0]


# ----------------------------------------------------------------------------- one rule

def _items(value, what: str) -> list:
    """One value or a list of them, as a list of strings."""
    values = value if isinstance(value, list) else [value]
    if not values or not all(isinstance(v, str) for v in values):
        raise ValueError("%s must be a string or a list of strings" % what)
    return values


def _parse_keys(value) -> frozenset:
    from xrce.agent.allow_lists import parse_keys  # the same words as --allow-keys

    keys = set()
    for item in _items(value, "key"):
        keys |= parse_keys(item)
    return frozenset(keys)


def _parse_networks(value) -> tuple:
    from xrce.agent.allow_lists import parse_networks  # the same words as --allow-from

    networks = []
    for item in _items(value, "address"):
        networks.extend(parse_networks(item))
    return tuple(networks)


def _parse_devices(value) -> list:
    return _items(value, "device")


def _parse_namespace(value) -> str:
    if not isinstance(value, str):
        raise ValueError("must be a string (an absolute ROS namespace)")
    if not value.startswith("/"):
        raise ValueError("namespace %r is not absolute (/%s)" % (value, value))
    Naming(value)  # the command line's checks
    return value


def _parse_domain(value) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_DOMAIN_ID:
        raise ValueError("%r is not a ROS domain id (0..%d)" % (value, MAX_DOMAIN_ID))
    return value


def _parse_remaps(value) -> list:
    """``{FROM = "TO"}`` or ``["FROM:=TO", ...]`` -> [(FROM, TO)], in the file's order."""
    if isinstance(value, dict):
        pairs = []
        for source, target in value.items():
            if not isinstance(target, str):
                raise _KeyValueError(source, "remap %s must name a string target" % source)
            try:
                Naming(remaps=[(source, target)])
            except NamingError as exc:
                raise _KeyValueError(source, str(exc)) from None
            pairs.append((source, target))
        return pairs
    pairs = []
    for rule in _items(value, "remaps"):
        source, sep, target = rule.partition(":=")
        if not sep or not source or not target:
            raise ValueError("remap %r is not FROM:=TO" % rule)
        Naming(remaps=[(source, target)])
        pairs.append((source, target))
    return pairs


def _parse_global_topics(value) -> list:
    names = _items(value, "global_topics")
    for name in names:
        if not name.startswith("/"):
            raise ValueError("%r is not an absolute name" % name)
    Naming(global_names=names)
    return names


# What each key of a rule is read with; ValueError (NamingError too) for a bad value.
PARSERS = {"key": _parse_keys, "address": _parse_networks, "device": _parse_devices,
           "namespace": _parse_namespace, "domain": _parse_domain, "remaps": _parse_remaps,
           "global_topics": _parse_global_topics}


class _KeyValueError(ValueError):
    """A bad value under a key inside the rule's key (a remap's FROM): its line is that one's."""

    def __init__(self, inner: str, message: str):
        super().__init__(message)
        self.inner = inner


class Rule:
    """One ``[[board]]``: what it matches and the ``Naming`` it gives."""

    def __init__(self, name: str, naming: Naming, keys=None, networks=None, devices=None):
        self.name = name
        self.naming = naming
        self.keys = keys
        self.networks = networks
        self.devices = devices

    def matches(self, origin) -> bool:
        if self.keys is not None and bytes(origin.client_key) not in self.keys:
            return False
        if self.networks is not None:
            address = origin.address
            if address is None or not any(address.version == n.version and address in n
                                          for n in self.networks):
                return False
        if self.devices is not None:
            if origin.device is None or not any(_same_device(pattern, origin.device)
                                                for pattern in self.devices):
                return False
        return True

    def describe(self) -> str:
        """``robot1 (key 0xaabbccdd: namespace /robot1, domain 7)``: the log's words."""
        matched = []
        if self.keys is not None:
            matched.append("key " + ",".join("0x" + k.hex() for k in sorted(self.keys)))
        if self.networks is not None:
            matched.append("from " + ",".join(str(n) for n in self.networks))
        if self.devices is not None:
            matched.append("device " + ",".join(self.devices))
        given = self.naming.describe() or "the agent's names"
        return "%s (%s: %s)" % (self.name, " ".join(matched), given)


def _same_device(pattern: str, device: str) -> bool:
    if fnmatch.fnmatchcase(device, pattern):
        return True
    try:
        target = os.path.realpath(device)
        return any(os.path.realpath(found) == target for found in glob.glob(pattern))
    except OSError:
        return False


def _merged(base: Naming, entries: dict) -> Naming:
    """The rule's naming over the command line's (module docstring)."""
    namespace = entries.get("namespace", base.namespace)
    remaps = list(base.remaps.items()) + list(entries.get("remaps", ()))
    global_names = entries.get("global_topics", sorted(base.global_names))
    domain = entries.get("domain", base.domain)
    return Naming(namespace, remaps, global_names, domain)


def _rule(index: int, table, base: Naming, lines: _Lines, path: str) -> Rule:
    def error(key, message, *inner):
        line = lines.find(index, key, *inner)
        where = " key %r:" % key if key else ""
        return FleetError("fleet file %s line %d:%s %s" % (path, line, where, message))

    if not isinstance(table, dict):
        raise error(None, "%s must be tables ([[%s]])" % (TABLE, TABLE))
    for key in table:
        if key not in RULE_KEYS:
            raise error(key, "unknown key (a rule takes %s)" % ", ".join(RULE_KEYS))
    name = table.get("name", "rule %d (line %d)" % (index + 1, lines.find(index)))
    if not isinstance(name, str) or not name.strip():
        raise error("name", "must be a non-empty string")
    if not any(key in table for key in MATCH_KEYS):
        raise error(None, "rule %r matches no board: give key, address or device" % name)
    parsed = {}
    for key, parse in PARSERS.items():
        if key in table:
            try:
                parsed[key] = parse(table[key])
            except _KeyValueError as exc:
                raise error(key, str(exc), exc.inner) from None
            except ValueError as exc:
                raise error(key, str(exc)) from None
    try:
        naming = _merged(base, parsed)
    except NamingError as exc:  # each part was valid on its own: not expected, still one line
        raise error(None, str(exc)) from None
    return Rule(name.strip(), naming, parsed.get("key"), parsed.get("address"),
                parsed.get("device"))


# ----------------------------------------------------------------------------- the file

def load(path: str, base: Naming | None = None) -> list:
    """The rules of the fleet file ``path`` over the command line's ``base`` naming. Raises
    FleetError (one line) for anything wrong with it."""
    base = base or Naming()
    try:
        with open(path, "rb") as file:
            raw = file.read()
    except OSError as exc:
        raise FleetError("cannot read fleet file %s: %s" % (path, exc.strerror or exc)) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise FleetError("fleet file %s line %d: not UTF-8 text" % (path, line)) from None
    lines = _Lines(text)
    try:
        document = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise FleetError(_syntax_error(path, str(exc), lines)) from None
    for key in document:
        if key != TABLE:
            raise FleetError("fleet file %s line %d: key %r: unknown (the file holds [[%s]] "
                             "rules)" % (path, lines.find(None, key), key, TABLE))
    tables = document.get(TABLE, [])
    if not isinstance(tables, list):
        raise FleetError("fleet file %s line %d: key %r: must be [[%s]] tables"
                         % (path, lines.find(None, TABLE), TABLE, TABLE))
    rules = [_rule(index, table, base, lines, path) for index, table in enumerate(tables)]
    seen = {}
    for index, rule in enumerate(rules):
        if rule.name in seen:
            raise FleetError("fleet file %s line %d: key 'name': %r is already rule %d's (names "
                             "tell boards apart in the log)" % (path, lines.find(index, "name"),
                                                               rule.name, seen[rule.name] + 1))
        seen[rule.name] = index
    return rules


_AT = re.compile(r"\s*\(at (?:line (\d+), column \d+|end of document)\)\s*$")


def _syntax_error(path: str, message: str, lines: _Lines) -> str:
    found = _AT.search(message)
    line = int(found.group(1)) if found and found.group(1) else max(1, len(lines.lines))
    reason = _AT.sub("", message) if found else message
    text = lines.lines[line - 1] if 0 < line <= len(lines.lines) else ""
    key = text.split("=", 1)[0].strip() if "=" in text else text.strip()
    near = " key %r:" % key if key else ""
    return "fleet file %s line %d:%s TOML syntax: %s" % (path, line, near, reason)


class Fleet:
    """The rules of one fleet file; ``assign`` for the ROS middleware (``RosMiddleware(fleet=)``),
    ``reload`` for the agent's SIGHUP. Used on the agent's loop thread only."""

    def __init__(self, path: str, base: Naming | None = None):
        self.path = path
        self.base = base or Naming(global_names=GLOBAL_NAMES)
        self.rules = load(path, self.base)  # FleetError at start: the agent does not start

    def assign(self, origin) -> tuple:
        """(the Naming, the rule's name) of the first rule ``origin`` matches; (the command
        line's Naming, None) when none does."""
        for rule in self.rules:
            if rule.matches(origin):
                return rule.naming, rule.name
        return self.base, None

    def domains(self) -> set:
        """The domains the rules put boards in (worth preparing at start, like the default)."""
        return {rule.naming.domain for rule in self.rules if rule.naming.domain is not None}

    def reload(self) -> bool:
        """Read the file again for the boards created from now on; on any error a warning line
        and the rules stay as they were. Whether the new rules are in use."""
        try:
            rules = load(self.path, self.base)
        except FleetError as exc:
            log.warning("%s; the %d rule(s) loaded before stay", exc, len(self.rules))
            return False
        self.rules = rules
        log.info("%s; for boards created from now on (those there keep their names)",
                 self.describe())
        return True

    def describe(self) -> str:
        """``fleet file F: 2 rules: robot1, robot2``: the banner's line."""
        names = ", ".join(rule.name for rule in self.rules) or "none"
        return "fleet file %s: %d rule%s: %s" % (self.path, len(self.rules),
                                                  "" if len(self.rules) == 1 else "s", names)
