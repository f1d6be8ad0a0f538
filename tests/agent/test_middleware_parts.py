"""The ROS middleware is made of parts that own their state (issue 54), not of mixins sharing it.

``RosMiddleware`` used to be ``class RosMiddleware(RosDomains, RosServices, ParkedCreation,
ShownEntities, NameCollisions, Middleware)``, five mixins reading what its ``__init__`` set, and
``DdsMiddleware(PlainDds, RosMiddleware)`` one more. Now ``RosMiddleware``
(xrce/agent/middleware/ros/ros_middleware.py) implements ``Middleware`` and builds its parts
(``EntityRecords``, ``RosDomains``, ``ParkedCreation``, ``RosServices``, ``EndpointWatches``,
``NameCollisions``, ``ShownEntities``, ``RosCompiledPathSupport``, with ``RunContext`` for the loop
and what the engine sets), each handed its collaborators in its constructor; ``DdsMiddleware``
adds ``PlainDds``. The rules of tests/agent/test_engine_parts.py, read from the source with
``ast``, hold in xrce/agent/middleware/ros/ and xrce/agent/middleware/dds/:

- no class there inherits from another class there, but ``DdsMiddleware`` from ``RosMiddleware``
  (``COMPOSER_EXTENDED``);
- every ``self.name`` a class reads is one it defines itself; a class implementing an interface
  of xrce/agent/middleware/__init__.py (``Middleware``, ``CompiledPathSupport``) may also read
  what the interface defines, ``DdsMiddleware`` what ``RosMiddleware`` does. Exceptions and the
  few classes built on a base from outside (``OUTSIDE_BASES``, each with its reason) are left out;
- no part names its composer: no module but the composers' imports ``ros_middleware`` or
  ``dds_middleware``, or names ``RosMiddleware``, ``DdsMiddleware`` or a ``middleware``.
"""

from __future__ import annotations

import ast
from pathlib import Path

from class_parts import base_names, classes_in, defined_by, strays

MIDDLEWARE = Path(__file__).resolve().parents[2] / "xrce" / "agent" / "middleware"
FOLDERS = (MIDDLEWARE / "ros", MIDDLEWARE / "dds")
COMPOSERS = {"ros_middleware.py": "RosMiddleware", "dds_middleware.py": "DdsMiddleware"}
PARTS = {"RosMiddleware", "EntityRecords", "RosDomains", "ParkedCreation", "RosServices",
         "EndpointWatches", "NameCollisions", "NameClaims", "ShownEntities",
         "RosCompiledPathSupport", "RunContext", "DdsMiddleware", "PlainDds"}
# The one class built on another of these folders: `-m dds` is the ROS middleware with one part
# more, each of its methods taking what is plain DDS and handing the rest on with super().
COMPOSER_EXTENDED = {"DdsMiddleware": "RosMiddleware"}
# Interfaces (xrce/agent/middleware/__init__.py) a class may implement: what they define is its.
INTERFACES = {"Middleware", "CompiledPathSupport"}
# Classes built on a base from outside, whose attributes are the base's.
OUTSIDE_BASES = {
    "AgentNode": "an rclpy Node: the agent's hidden node in a domain, with rclpy's attributes",
    "_RawTypeMeta": "a metaclass (type): the raw message classes rclpy takes for CDR bytes",
    "_RawServiceMeta": "a metaclass (type): the raw service classes, likewise",
    "_NumpyOnFirstUse": "a module (types.ModuleType) standing in for numpy until it is used",
}
EXCEPTION_BASES = {"Exception", "ValueError", "MiddlewareError"}


def _classes():
    found = {}
    for folder in FOLDERS:
        for name, (module, node) in classes_in(folder).items():
            assert name not in found, "two middleware classes called %s" % name
            found[name] = ("%s/%s" % (folder.name, module), node)
    return found


def _interfaces():
    tree = ast.parse((MIDDLEWARE / "__init__.py").read_text())
    return {node.name: defined_by(node) for node in tree.body
            if isinstance(node, ast.ClassDef) and node.name in INTERFACES}


def _is_exception(classes, name) -> bool:
    bases = base_names(classes[name][1])
    return any(b in EXCEPTION_BASES or b in classes and _is_exception(classes, b) for b in bases)


def test_the_parts_are_there():
    classes = _classes()
    assert PARTS <= set(classes), PARTS - set(classes)
    assert set(_interfaces()) == INTERFACES
    _, middleware = classes["RosMiddleware"]
    assert {"records", "domains", "services", "compiled", "create_datawriter"} <= \
        defined_by(middleware)


def test_no_class_is_built_from_another():
    classes = _classes()
    mixed = {name: [b for b in base_names(node) if b in classes]
             for name, (_, node) in classes.items()}
    mixed = {name: bases for name, bases in mixed.items()
             if bases and not _is_exception(classes, name)}
    assert mixed == {name: [base] for name, base in COMPOSER_EXTENDED.items()}, mixed
    for name in PARTS - set(COMPOSER_EXTENDED):
        bases = base_names(classes[name][1])
        assert set(bases) <= INTERFACES, "%s has bases: %s" % (name, bases)


def test_the_classes_built_on_outside_bases_are_the_listed_ones():
    classes = _classes()
    outside = {name for name, (_, node) in classes.items()
               if node.bases and not _is_exception(classes, name)
               and not set(base_names(node)) <= INTERFACES and name not in COMPOSER_EXTENDED}
    assert outside == set(OUTSIDE_BASES), outside ^ set(OUTSIDE_BASES)


def test_the_middleware_is_composed_at_run_time():
    from xrce.agent.middleware import CompiledPathSupport, Middleware
    from xrce.agent.middleware.dds.dds_middleware import DdsMiddleware
    from xrce.agent.middleware.ros.ros_middleware import RosMiddleware

    assert RosMiddleware.__bases__ == (Middleware,)
    assert DdsMiddleware.__bases__ == (RosMiddleware,)
    middleware = DdsMiddleware()
    support = middleware.compiled_path_support()
    assert isinstance(support, CompiledPathSupport) and support is not middleware
    middleware.engine_lock = lock = object()
    assert middleware.run.engine_lock is lock  # the parts' RunContext hears what the engine set


def test_each_class_reads_only_what_it_defines():
    classes = _classes()
    interfaces = _interfaces()

    def inherited(name) -> set:
        names = set()
        for base in base_names(classes[name][1]):
            if base in interfaces:
                names |= interfaces[base]
            elif COMPOSER_EXTENDED.get(name) == base:
                names |= defined_by(classes[base][1]) | inherited(base)
        return names

    checked = [name for name in classes
               if name not in OUTSIDE_BASES and not _is_exception(classes, name)]
    found = strays(classes, checked, inherited)
    assert not found, "\n".join(found)


def test_no_part_names_its_composer():
    offenders = []
    for folder in FOLDERS:
        for path in sorted(folder.glob("*.py")):
            if path.name in COMPOSERS:
                continue
            tree = ast.parse(path.read_text(), filename=str(path))
            for node in ast.walk(tree):
                if isinstance(node, ast.ImportFrom) and node.module and \
                        node.module.rsplit(".", 1)[-1] in ("ros_middleware", "dds_middleware"):
                    offenders.append("%s:%d imports a composer" % (path.name, node.lineno))
                elif isinstance(node, ast.Name) and node.id in (
                        "RosMiddleware", "DdsMiddleware", "middleware") or \
                        isinstance(node, ast.Attribute) and node.attr == "middleware" or \
                        isinstance(node, ast.arg) and node.arg == "middleware":
                    offenders.append("%s:%d names the middleware" % (path.name, node.lineno))
    assert not offenders, "\n".join(offenders)
