"""The agent's engine is made of parts that own their state (issue 46), not of mixins sharing it.

``xrce.agent.engine.agent.Agent`` used to be ``class Agent(SessionTable, ObjectRegistry,
DataPath, Liveliness)``, five mixins reading some forty attributes that other mixins set. Now each
part (``Inbound``, ``Sessions``, ``ObjectRegistry``, ``DataPath``, ``StreamOutput``,
``Acknowledgments``, ``Liveliness``, ``MismatchReport``, ``Scheduler``, ``Output``, ...) is an
object that gets its collaborators in its constructor, and ``Agent`` builds and wires them. Three
rules keep it so, read from the source with ``ast`` (so no import is needed to see them):

- no class of the engine inherits from another class of the engine (no mixins; ``Agent``'s only
  base is ``object``);
- every ``self.name`` a class of the engine reads is one that class itself defines (assigns in one
  of its methods, or defines as a method, property or class attribute): a class that reads what
  another sets is a mixin in disguise. Classes built on a base from outside the engine (an
  exception, ``bytes``, the wire module's stream classes) are left out: their attributes are the
  base's;
- no module of the engine but the agent's own knows the agent: none imports ``engine.agent`` or
  names ``agent`` (the compiled path too is given the parts it works with, by
  ``Agent.attach_compiled_path``).
"""

from __future__ import annotations

import ast
from pathlib import Path

from class_parts import base_names as _base_names
from class_parts import classes_in, strays
from class_parts import defined_by as _defined_by
from class_parts import read_by as _read_by

ENGINE = Path(__file__).resolve().parents[2] / "xrce" / "agent" / "engine"
FOLDERS = (ENGINE, ENGINE / "compiled")  # the Python parts, and the compiled path's Python side
KNOWS_THE_AGENT = {"agent.py"}  # the composer
# The parts the agent is composed of: each must stay a class of its own.
PARTS = {"Agent", "Inbound", "Sessions", "ClientTable", "MemoryBudget", "ClientProxy",
         "ObjectRegistry", "DataPath", "StreamOutput", "Acknowledgments", "Liveliness",
         "MismatchReport", "Scheduler", "Output"}


def _engine_classes():
    """{class name: (module file name, ast.ClassDef)} for every class in the engine's modules."""
    classes = {}
    for folder in FOLDERS:
        found = classes_in(folder)
        assert not found.keys() & classes.keys(), found.keys() & classes.keys()
        classes.update(found)
    return classes


def test_the_parts_are_there():
    classes = _engine_classes()
    assert PARTS <= set(classes), PARTS - set(classes)
    # and the rules below see what they look for: a method, an attribute set in __init__, a read
    _, agent = classes["Agent"]
    assert {"receive", "tick", "sessions", "datapath"} <= _defined_by(agent)
    assert "datapath" in _read_by(agent)


def test_no_engine_class_is_built_from_another():
    classes = _engine_classes()
    mixed = {name: [b for b in _base_names(node) if b in classes]
             for name, (_, node) in classes.items()}
    mixed = {name: bases for name, bases in mixed.items() if bases}
    assert not mixed, "engine classes built from other engine classes (mixins): %s" % mixed
    for name in PARTS:
        assert not classes[name][1].bases, "%s has bases: %s" % (name, _base_names(classes[name][1]))


def test_the_agent_is_a_class_of_its_own_at_run_time():
    from xrce.agent.engine.agent import Agent
    from xrce.agent.engine.datapath import DataPath
    from xrce.agent.engine.inbound import Inbound
    from xrce.agent.engine.liveliness import Acknowledgments, Liveliness
    from xrce.agent.engine.mismatch_report import MismatchReport
    from xrce.agent.engine.objects import ObjectRegistry
    from xrce.agent.engine.sessions import Sessions
    from xrce.agent.engine.stream_output import StreamOutput

    for part in (Agent, Inbound, Sessions, ObjectRegistry, DataPath, StreamOutput,
                 Acknowledgments, Liveliness, MismatchReport):
        assert part.__bases__ == (object,), part


def test_each_class_reads_only_what_it_defines():
    classes = _engine_classes()
    # Classes built on an outside base (an exception, bytes, a stream, a Protocol) are left out.
    checked = [name for name, (_, node) in classes.items()
               if not node.bases or _base_names(node) == ["object"]]
    found = strays(classes, checked)
    assert not found, "\n".join(found)


def test_no_part_reaches_through_the_agent():
    offenders = []
    for path in sorted(path for folder in FOLDERS for path in folder.glob("*.py")):
        if path.name in KNOWS_THE_AGENT:
            continue
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and \
                    node.module.endswith("engine.agent"):
                offenders.append("%s:%d imports the agent" % (path.name, node.lineno))
            elif isinstance(node, ast.Name) and node.id == "agent" or \
                    isinstance(node, ast.Attribute) and node.attr == "agent":
                offenders.append("%s:%d names the agent" % (path.name, node.lineno))
    assert not offenders, "\n".join(offenders)
