"""What the parts tests (tests/agent/test_engine_parts.py, tests/agent/test_middleware_parts.py)
read from the source with ``ast``: the classes of a folder, their bases, the names each defines
for its instances and the ``self.name`` each reads."""

from __future__ import annotations

import ast
from pathlib import Path


def classes_in(folder: Path) -> dict:
    """{class name: (module file name, ast.ClassDef)} for every class in ``folder``'s modules."""
    found = {}
    for path in sorted(folder.glob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                assert node.name not in found, "two classes called %s in %s" % (node.name, folder)
                found[node.name] = (path.name, node)
    return found


def base_names(node) -> list:
    names = []
    for base in node.bases:
        if isinstance(base, ast.Name):
            names.append(base.id)
        elif isinstance(base, ast.Attribute):
            names.append(base.attr)
        else:
            names.append(ast.dump(base))
    return names


def methods(node):
    """(method, name of its instance argument) for the class's own methods."""
    for item in node.body:
        if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)) and item.args.args and \
                not any(isinstance(d, ast.Name) and d.id == "staticmethod"
                        for d in item.decorator_list):
            yield item, item.args.args[0].arg


def defined_by(node) -> set:
    """Names a class defines for its instances: its methods, properties and class attributes,
    and every ``self.name`` assigned in its methods (``self`` being each method's first
    argument)."""
    names = set()
    for item in node.body:
        if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)):
            names.add(item.name)
        elif isinstance(item, ast.Assign):
            names |= {t.id for t in item.targets if isinstance(t, ast.Name)}
        elif isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
            names.add(item.target.id)
    for method, me in methods(node):
        for sub in ast.walk(method):
            targets = []
            if isinstance(sub, ast.Assign):
                targets = sub.targets
            elif isinstance(sub, (ast.AugAssign, ast.AnnAssign)):
                targets = [sub.target]
            for target in targets:
                for element in (target.elts if isinstance(target, ast.Tuple) else [target]):
                    if isinstance(element, ast.Attribute) and isinstance(element.value, ast.Name) \
                            and element.value.id == me:
                        names.add(element.attr)
    return names


def read_by(node) -> dict:
    """{name: line} of every ``self.name`` the class's methods read."""
    reads = {}
    for method, me in methods(node):
        for sub in ast.walk(method):
            if isinstance(sub, ast.Attribute) and isinstance(sub.value, ast.Name) and \
                    sub.value.id == me and isinstance(sub.ctx, ast.Load):
                reads.setdefault(sub.attr, sub.lineno)
    return reads


def strays(classes: dict, checked, also_defined=lambda name: set()) -> list:
    """A line for each ``self.name`` read by a class of ``checked`` that neither it nor
    ``also_defined(class name)`` defines (dunder names are Python's)."""
    found = []
    for name in sorted(checked):
        module, node = classes[name]
        defined = defined_by(node) | also_defined(name)
        for attribute, line in sorted(read_by(node).items()):
            if attribute not in defined and not attribute.startswith("__"):
                found.append("%s:%d %s reads self.%s, which it never sets" % (
                    module, line, name, attribute))
    return found
