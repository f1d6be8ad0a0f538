"""The repository needs nothing beside it: no file names a path outside the checkout.

A clone anywhere else must pass the README's commands, so data the tests and benchmarks read lives
in the repository (``tests/golden/``) and every relative link in the docs resolves inside it.
"""

import os
import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

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


FENCE = re.compile(r"^```.*?^```", re.S | re.M)
HEADING = re.compile(r"^#{1,6}\s+(.+?)\s*#*\s*$", re.M)
LINK_WITH_ANCHOR = re.compile(r"\]\(([^)\s#]*)#([^)\s]+)\)")


def github_anchors(markdown):
    """The anchors GitHub gives a file's headings: lower case, markup and punctuation dropped,
    spaces to hyphens, a repeated one numbered (-1, -2, ...); headings in code blocks are not."""
    anchors, seen = set(), {}
    for title in HEADING.findall(FENCE.sub("", markdown)):
        title = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", title)  # a link's text stays
        slug = re.sub(r"[^\w\- ]", "", title.replace("`", "").lower()).replace(" ", "-")
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        anchors.add(slug if count == 0 else "%s-%d" % (slug, count))
    return anchors


def test_anchor_slugs_are_githubs():
    assert github_anchors("# `xrce-client`: poke an agent\n## Figures against eProsima's agent\n"
                          "```sh\n# not a heading\n```\n## Set-up, and `hold_set_up`\n## Set-up, and `hold_set_up`\n") \
        == {"xrce-client-poke-an-agent", "figures-against-eprosimas-agent", "set-up-and-hold_set_up",
            "set-up-and-hold_set_up-1"}


@pytest.mark.parametrize("name", [n for n in FILES if n.endswith(".md")])
def test_markdown_anchors_name_a_heading(name):
    """README -> docs, docs -> docs and within a page: a link's #anchor is a heading of its target."""
    source = REPO / name
    for target, anchor in LINK_WITH_ANCHOR.findall(FENCE.sub("", source.read_text())):
        if re.match(r"^[a-z]+:", target):
            continue  # a URL
        page = (source.parent / target).resolve() if target else source
        if page.suffix != ".md":
            continue  # GitHub's #L12 line anchors of source files are not headings
        assert page.is_file(), "%s links to a missing page: %s" % (name, target)
        assert anchor in github_anchors(page.read_text()), \
            "%s links to #%s, which is no heading of %s" % (name, anchor, page.relative_to(REPO))


def test_every_doc_is_reachable_from_the_readme():
    """docs/*.md hold what moved out of README: each is linked from README or from a linked doc."""
    docs = {n for n in FILES if n.startswith("docs/") and n.endswith(".md")}
    reached, todo = set(), ["README.md"]
    while todo:
        name = todo.pop()
        source = REPO / name
        for target in MARKDOWN_LINK.findall(source.read_text()):
            path = (source.parent / target).resolve()
            if path.suffix == ".md" and path.is_relative_to(REPO):
                linked = path.relative_to(REPO).as_posix()
                if linked in docs and linked not in reached:
                    reached.add(linked)
                    todo.append(linked)
    assert docs and reached == docs, "not linked from README: %s" % sorted(docs - reached)


def test_golden_captures_are_in_the_repository():
    import json
    captures = json.loads((REPO / "tests" / "golden" / "wire_captures.json").read_text())
    assert sum(len(ds) for ds in captures["scenarios"].values()) >= 200
    assert os.path.exists(REPO / "docs" / "XRCE-WIRE.md")
