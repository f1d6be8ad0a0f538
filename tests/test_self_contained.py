"""The repository needs nothing beside it: no file names a path outside the checkout.

A clone anywhere else must pass the README's commands, so data the tests and benchmarks read lives
in the repository (``tests/golden/``) and every relative link in the docs resolves inside it.
"""

import os
import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

# Absolute paths of the machines the project was written on, and the reference share beside it.
OUTSIDE_PATTERNS = [
    re.compile(r"/work(?=/)"),  # spelt with a lookahead so this file does not match itself
    re.compile(r"\.\./shared\b"),
    re.compile(r"""["']shared["']\s*/\s*["']protocol["']"""),
    re.compile(r"/(?:root|home/\w+)/"),
]
PARENTS_INDEX = re.compile(r"\.parents\[(\d+)\]")
MARKDOWN_LINK = re.compile(r"\]\(([^)\s#]+)(?:#[^)]*)?\)")
TEXT_SUFFIXES = {".py", ".md", ".toml", ".json", ".mjs", ".js", ".cfg", ".txt", ".yaml", ".yml",
                 ".cmake", ".xml", ".sh", ""}


def _tracked_files():
    if (REPO / ".git").exists():
        out = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=True).stdout
        names = [n for n in out.decode().split("\0") if n]
    else:  # an exported tree: walk it, skipping what installs put there
        skip = {".git", ".venv", "node_modules", "__pycache__", "build", "dist"}
        names = [str(p.relative_to(REPO)) for p in REPO.rglob("*")
                 if p.is_file() and not skip.intersection(p.relative_to(REPO).parts)]
    this_file = Path(__file__).resolve().relative_to(REPO).as_posix()
    return [n for n in names if Path(n).suffix in TEXT_SUFFIXES and n != this_file
            and (REPO / n).is_file()]


FILES = _tracked_files()


def test_the_tree_is_listed():
    assert "README.md" in FILES and "tests/golden/wire_captures.json" in FILES


@pytest.mark.parametrize("name", [n for n in FILES if not n.endswith(".json")])
def test_no_path_outside_the_repository(name):
    text = (REPO / name).read_text(errors="replace")
    for pattern in OUTSIDE_PATTERNS:
        match = pattern.search(text)
        assert match is None, "%s names a path outside the repository: %r" % (name, match.group(0))
    depth = len(Path(name).parts) - 1  # Path(__file__).parents[depth] is the repository root
    for match in PARENTS_INDEX.finditer(text):
        assert int(match.group(1)) <= depth, "%s climbs out of the checkout with %s" % (name, match.group(0))


@pytest.mark.parametrize("name", [n for n in FILES if n.endswith(".md")])
def test_markdown_links_resolve_inside_the_repository(name):
    source = REPO / name
    for target in MARKDOWN_LINK.findall(source.read_text()):
        if re.match(r"^[a-z]+:", target):
            continue  # a URL, not a path
        resolved = (source.parent / target).resolve()
        assert resolved.is_relative_to(REPO), "%s links outside the repository: %s" % (name, target)
        assert resolved.exists(), "%s links to a missing file: %s" % (name, target)


def test_golden_captures_are_in_the_repository():
    import json
    captures = json.loads((REPO / "tests" / "golden" / "wire_captures.json").read_text())
    assert sum(len(ds) for ds in captures["scenarios"].values()) >= 200
    assert os.path.exists(REPO / "docs" / "XRCE-WIRE.md")
