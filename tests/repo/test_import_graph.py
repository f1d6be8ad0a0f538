"""No accidental import circles (issue 24): the import graph of xrce/ and bench/ has no cycle but
the client's lazy-loading one, which is named below with its reason.

The graph is read from the source with ``ast``, not by importing it, so it sees every import a
module can make: at module level and inside functions (a lazy import still ties two modules
together, and a circle through one breaks as soon as it runs at import time), absolute and relative,
and ``from package import name`` where ``name`` is a submodule. Imports under ``if TYPE_CHECKING:``
are left out: they never run, they only name a type for annotations. Imports by a string
(``__import__(name)``) are not seen. The tree is walked, so moving modules needs no change here.

Two rules:
- no module-level circle anywhere, a module's import of its own package included: one would leave a
  half-initialised module to whichever of the two is imported first;
- no circle at all, lazy imports included, outside ``ON_PURPOSE``. Here a module's import of a
  package it is part of (``from xrce import DecodeError`` in xrce.wire.cdr) does not count: Python runs
  a package before any of its modules, so the package is the layer below them, and a package that
  loads its own modules on first use (xrce.msgs) is not a circle of two layers.
"""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

# (directory, how its modules are named): xrce/ and bench/ are packages imported from the
# repository root (a bench script puts the checkout on sys.path and imports bench.common).
ROOTS = [(REPO / "xrce", "xrce"), (REPO / "bench", "bench")]

# The one circle kept on purpose, and why (xrce/client/session.py says it too). On a board every
# module imported costs heap for as long as it stays, so the session loads what a firmware may never
# use on its first use, from inside the function that needs it: replies to service calls
# (services), time sync and the in-session ping (on_demand, which loads services for the names it
# serves), and the session-less ping, which `from xrce.client.session import ping_agent` still
# reaches. Those modules build on the session (its sample decoding, its agent-info parsing), so
# they import it at their top. Turning that around would make every board load them with the
# session. Only these modules may share a circle, and the session imports them only lazily.
LAZY_SESSION = "xrce.client.session"
ON_PURPOSE = {LAZY_SESSION, "xrce.client.services", "xrce.client.on_demand", "xrce.client.ping"}


def module_names(root, prefix):
    """{dotted name: path} of every module below ``root``; a package is named by its __init__."""
    names = {}
    for path in sorted(root.rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if "__pycache__" in parts or any(not part.isidentifier() for part in parts):
            continue
        if parts[-1] == "__init__":
            parts.pop()
        dotted = ".".join(([prefix] if prefix else []) + parts)
        if dotted:
            names[dotted] = path
    return names


def _is_type_checking(test):
    return ((isinstance(test, ast.Name) and test.id == "TYPE_CHECKING")
            or (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"))


def _imports(tree):
    """(node, at_module_level) for every import statement that can run."""
    found = []

    def visit(node, top):
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.orelse:
                visit(child, top)
            return
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            found.append((node, top))
            return
        inner = top and not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
        for child in ast.iter_child_nodes(node):
            visit(child, inner)

    for statement in tree.body:
        visit(statement, True)
    return found


def _targets(node, importer, is_package, known):
    """The known modules an import statement loads (the most specific one each name names)."""
    if isinstance(node, ast.Import):
        bases = [alias.name for alias in node.names]
        return {_known_prefix(name, known) for name in bases} - {None}
    if node.level:
        package = importer if is_package else importer.rpartition(".")[0]
        for _ in range(node.level - 1):
            package = package.rpartition(".")[0]
        base = ".".join(p for p in (package, node.module) if p)
    else:
        base = node.module
    targets = set()
    for alias in node.names:
        submodule = "%s.%s" % (base, alias.name) if base else alias.name
        if submodule in known:
            targets.add(submodule)
        else:
            targets.add(_known_prefix(base, known))
    return targets - {None}


def _known_prefix(dotted, known):
    while dotted:
        if dotted in known:
            return dotted
        dotted = dotted.rpartition(".")[0]
    return None


def import_graph(roots):
    """({module: set of modules it imports}, {module: set it imports at module level})."""
    paths = {}
    for root, prefix in roots:
        paths.update(module_names(root, prefix))
    every, top_level = {}, {}
    for name, path in paths.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        is_package = path.name == "__init__.py"
        every[name], top_level[name] = set(), set()
        for node, at_top in _imports(tree):
            targets = _targets(node, name, is_package, paths) - {name}
            every[name] |= {t for t in targets if not name.startswith(t + ".")}
            if at_top:
                top_level[name] |= targets
    return every, top_level


def cycles(graph):
    """The strongly connected components of more than one module (Tarjan's, without recursion)."""
    index, low, on_stack, stack, found = {}, {}, set(), [], []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = set()
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.add(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return sorted(found)


def _describe(component, graph):
    edges = ["%s -> %s" % (a, b) for a in component for b in sorted(graph[a]) if b in component]
    return "\n    ".join(edges)


def test_the_graph_sees_the_tree():
    every, top_level = import_graph(ROOTS)
    # a module-level import, a lazy one, and a bench script's import of the bench's shared code
    assert "xrce.wire.cdr" in top_level["xrce.client.session"]
    assert "xrce.client.services" in every["xrce.client.session"]
    assert "xrce.client.services" not in top_level["xrce.client.session"]
    assert "bench.common.figures" in top_level["bench.run"]


def test_no_module_level_import_circle():
    _, top_level = import_graph(ROOTS)
    found = cycles(top_level)
    assert not found, "module-level import circles:\n" + "\n".join(
        "  " + _describe(c, top_level) for c in found)


def test_no_import_circle_but_the_client_lazy_loading_one():
    every, top_level = import_graph(ROOTS)
    accidental = [c for c in cycles(every) if not set(c) <= ON_PURPOSE]
    assert not accidental, "import circles (break them, or document one in ON_PURPOSE):\n" + "\n".join(
        "  " + _describe(c, every) for c in accidental)
    # the kept one is lazy loading: the session imports none of those modules at its top
    assert not top_level[LAZY_SESSION] & ON_PURPOSE


def test_a_synthetic_circle_is_found(tmp_path):
    package = tmp_path / "pkg"
    (package / "sub").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "sub" / "__init__.py").write_text("")
    # pkg.a -> pkg.sub.b at module level (relative, submodule named by `from . import`)
    (package / "a.py").write_text("from .sub import b\n")
    # pkg.sub.b -> pkg.c inside a function (relative, two levels up)
    (package / "sub" / "b.py").write_text("def f():\n    from ..c import thing\n")
    # pkg.c -> pkg.a at module level (absolute); pkg.d only under TYPE_CHECKING
    (package / "c.py").write_text("import pkg.a\nthing = 1\n")
    (package / "d.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                                  "    from pkg import a\nimport pkg.c\n")
    (package / "e.py").write_text("from pkg.d import *\n")
    # a package loading its own module on first use, which imports from the package
    (package / "sub" / "__init__.py").write_text("def f():\n    from pkg.sub import g\n")
    (package / "sub" / "g.py").write_text("from pkg.sub import f\n")
    every, top_level = import_graph([(package, "pkg")])
    assert cycles(every) == [["pkg.a", "pkg.c", "pkg.sub.b"]]
    assert cycles(top_level) == []  # the lazy import breaks it at module level
    assert every["pkg.d"] == {"pkg.c"} and every["pkg.e"] == {"pkg.d"}
    assert every["pkg.sub"] == {"pkg.sub.g"} and top_level["pkg.sub.g"] == {"pkg.sub"}
    # ... but a package importing at its top a module that imports the package is a circle
    (package / "sub" / "__init__.py").write_text("from pkg.sub import g\n")
    _, top_level = import_graph([(package, "pkg")])
    assert cycles(top_level) == [["pkg.sub", "pkg.sub.g"]]
    (package / "sub" / "__init__.py").write_text("")
    (package / "sub" / "b.py").write_text("import pkg.c\n")
    _, top_level = import_graph([(package, "pkg")])
    assert cycles(top_level) == [["pkg.a", "pkg.c", "pkg.sub.b"]]
    # a bench-like flat tree of scripts importing each other by bare name
    (tmp_path / "scripts").mkdir()
    (tmp_path / "scripts" / "run.py").write_text("import os\nfrom cost import measure\n")
    (tmp_path / "scripts" / "cost.py").write_text("def measure():\n    import run\n")
    every, _ = import_graph([(tmp_path / "scripts", "")])
    assert cycles(every) == [["cost", "run"]]


# The layers of xrce/ (issue 46): the wire core below everything that speaks it; the client and its
# transports beside each other, the agent above them. Lazy imports count: one would still tie the
# layers together. The package xrce itself (error types, shims) is below them all. The client's
# command line (CPython only) builds boards' files with xrce.tools: the client may use the tools.
LAYERS = {
    "xrce.wire": ("xrce.client", "xrce.agent", "xrce.tools", "xrce.transports", "xrce.msgs",
                  "xrce.examples"),
    "xrce.client": ("xrce.agent",),
    "xrce.transports": ("xrce.agent", "xrce.client", "xrce.tools"),
    "xrce.msgs": ("xrce.agent", "xrce.client", "xrce.transports"),
}


def _within(module, package):
    return module == package or module.startswith(package + ".")


def layer_crossings(every):
    """["a -> b"] for every import of a module from a layer above the importer's."""
    crossings = []
    for layer, above in LAYERS.items():
        for module in sorted(every):
            if _within(module, layer):
                crossings += ["%s -> %s" % (module, target) for target in sorted(every[module])
                              if any(_within(target, package) for package in above)]
    return crossings


def test_the_layers_hold():
    every, _ = import_graph(ROOTS)
    assert "xrce.wire.cdr" in every["xrce.wire.message"]  # the graph sees the wire package
    crossings = layer_crossings(every)
    assert not crossings, "imports against the layers:\n  " + "\n  ".join(crossings)
    # the top of xrce/ holds packages and at most a few modules (the package's own shims)
    top_modules = sorted(path.name for path in (REPO / "xrce").glob("*.py"))
    assert top_modules == ["__init__.py", "_cpython.py"], top_modules


def test_a_layer_crossing_is_found():
    every = {"xrce.wire.cdr": {"xrce.client.session"}, "xrce.client.session": {"xrce.wire.cdr"},
             "xrce.transports.udp": {"xrce.agent.links.udp"}, "xrce.msgs": {"xrce.wire.cdr"}}
    assert layer_crossings(every) == ["xrce.wire.cdr -> xrce.client.session",
                                      "xrce.transports.udp -> xrce.agent.links.udp"]


# The floors inside the agent (issue 54), top down: what runs the agent, what it serves on, the
# protocol engine, the middleware the engine creates entities in, what both report and build
# with, and the ground modules every floor may use. An import may point down or across a floor,
# never up: the engine knows no link, the middleware no engine, the observers neither.
AGENT_FLOORS = [
    ("xrce.agent.__main__", "xrce.agent.launcher", "xrce.agent.cli"),
    ("xrce.agent.links", "xrce.agent.state", "xrce.agent.demo"),
    ("xrce.agent.engine",),
    ("xrce.agent.middleware",),
    ("xrce.agent.observe", "xrce.agent.interfaces"),
    ("xrce.agent.heap", "xrce.agent.allow_lists", "xrce.agent.log_levels", "xrce.agent.c_sources",
     "xrce.agent._heap"),
]


def agent_floor(module):
    """The floor (0 = top) of an agent module; the package xrce.agent itself is the ground's."""
    for number, floor in enumerate(AGENT_FLOORS):
        if any(_within(module, place) for place in floor):
            return number
    return len(AGENT_FLOORS) - 1 if module == "xrce.agent" else None


def upward_imports(every):
    """["a -> b"] for every import of an agent module from a floor above the importer's."""
    found = []
    for module in sorted(every):
        floor = agent_floor(module)
        if floor is None:
            continue
        for target in sorted(every[module]):
            above = agent_floor(target)
            if above is not None and above < floor:
                found.append("%s -> %s" % (module, target))
    return found


def test_every_agent_module_has_a_floor():
    every, _ = import_graph(ROOTS)
    homeless = [m for m in sorted(every) if _within(m, "xrce.agent") and agent_floor(m) is None]
    assert not homeless, "agent modules on no floor (add them to AGENT_FLOORS): %s" % homeless


def test_the_agent_floors_only_point_down():
    every, _ = import_graph(ROOTS)
    found = upward_imports(every)
    assert not found, "imports up a floor inside the agent:\n  " + "\n  ".join(found)


def test_an_upward_import_inside_the_agent_is_found():
    every = {"xrce.agent.middleware.ros.domain": {"xrce.agent.engine.agent", "xrce.agent.heap"},
             "xrce.agent.engine.agent": {"xrce.agent.middleware", "xrce.agent.observe.names"},
             "xrce.agent.heap": {"xrce.agent.engine.compiled"}}
    assert upward_imports(every) == ["xrce.agent.heap -> xrce.agent.engine.compiled",
                                     "xrce.agent.middleware.ros.domain -> xrce.agent.engine.agent"]
