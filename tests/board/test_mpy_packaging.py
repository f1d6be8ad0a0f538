"""Getting the client onto boards: mip package.json and freeze manifest in sync with the client
file set, every client module compiled by mpy-cross, and the .mpy files imported by MicroPython."""

import json
import os
import subprocess
import sys

import pytest

from mp_harness import run_micropython
from xrce.tools import mpy

# Present on boards but not in the WebAssembly port; modules may fail to import only on these.
# Board modules the WebAssembly port lacks. ``socket`` is not among them: the harness mounts a
# socket module built on its UDP bridge (tests/micropython/socket.py), so the UDP transport's
# MicroPython path runs here too.
BOARD_ONLY_MODULES = ("usocket", "machine", "network")


def _module_name(relative):
    name = relative[: -len(".py")].replace("/", ".")
    return name[: -len(".__init__")] if name.endswith(".__init__") else name


def test_client_file_set_excludes_cpython_only_code():
    files = mpy.client_files()
    assert "xrce/__init__.py" in files and "xrce/wire/cdr.py" in files and "xrce/wire/__init__.py" in files
    assert files == sorted(set(files))
    assert "xrce/client/cli_arguments.py" not in files  # argparse: the CLI's half that is not cli.py
    for relative in files:
        assert (mpy.REPO_ROOT / relative).is_file(), relative
        assert relative.endswith(".py")
        assert not relative.startswith(("xrce/agent/", "xrce/tools/")), relative
        assert os.path.basename(relative) not in ("cli.py", "__main__.py"), relative
        assert relative not in mpy.CPYTHON_ONLY_MODULES
        top = relative.split("/")[1] if relative.count("/") > 1 else None
        assert top in (None,) + mpy.CLIENT_SUBPACKAGES, relative


def test_client_files_follow_the_tree(tmp_path):
    for relative in ("xrce/__init__.py", "xrce/core.py", "xrce/tools/msggen.py", "xrce/client/deep/x.py",
                     "xrce/client/cli.py", "xrce/agent/server.py", "xrce/tools/mpy.py",
                     "xrce/transports/__main__.py", "xrce/msgs/std_msgs.py", "xrce/other/y.py"):
        (tmp_path / relative).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / relative).write_text("")
    assert mpy.client_files(tmp_path) == [
        "xrce/__init__.py", "xrce/client/deep/x.py", "xrce/core.py", "xrce/msgs/std_msgs.py",
    ]


def test_mip_package_json_is_in_sync():
    committed = mpy.REPO_ROOT / "package.json"
    hint = "regenerate with: python -m xrce.tools.mpy mip-json"
    assert committed.read_text(encoding="utf-8") == mpy.render_mip_package_json(), hint
    package = json.loads(committed.read_text(encoding="utf-8"))
    assert [target for target, _ in package["urls"]] == mpy.shipped_files()
    assert "xrce/examples/turtlebot3.py" in mpy.shipped_files()  # the firmware ships with the client
    assert all(target == url for target, url in package["urls"])  # relative URLs: same layout
    import xrce

    assert package["version"] == xrce.__version__


def test_freeze_manifest_is_in_sync():
    manifest = mpy.REPO_ROOT / "manifest.py"
    assert manifest.read_text(encoding="utf-8") == mpy.render_manifest(), (
        "regenerate with: python -m xrce.tools.mpy manifest"
    )
    # Evaluate it as MicroPython's manifest tool does: files are relative to the package, the
    # package to base_path, base_path to the manifest's own directory.
    frozen = []
    metadata = {}

    def package(package_path, files=None, base_path=".", opt=None):
        for name in files:
            frozen.append(os.path.normpath(os.path.join(base_path, package_path, name)))

    exec(compile(manifest.read_text(), str(manifest), "exec"),
         {"package": package, "metadata": lambda **kw: metadata.update(kw)})
    assert frozen == mpy.shipped_files()
    assert all((manifest.parent / path).is_file() for path in frozen)
    assert set(metadata) <= {"description", "version", "license", "author"}


def test_cli_writes_the_generated_files(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(mpy.REPO_ROOT))
    for command, name, render in (("mip-json", "package.json", mpy.render_mip_package_json),
                                  ("manifest", "manifest.py", mpy.render_manifest)):
        target = tmp_path / name
        result = subprocess.run([sys.executable, "-m", "xrce.tools.mpy", command, str(target)],
                                capture_output=True, text=True, timeout=60, env=env)
        assert result.returncode == 0, result.stderr
        assert target.read_text(encoding="utf-8") == render()
    assert mpy.main(["frobnicate"]) == 2


@pytest.fixture(scope="module")
def mpy_build(tmp_path_factory):
    outdir = tmp_path_factory.mktemp("mpy")
    return outdir, mpy.build_mpy(outdir)


def test_build_mpy_compiles_every_client_file(mpy_build, capsys):
    outdir, written = mpy_build
    files = mpy.shipped_files()
    assert "xrce/examples/turtlebot3.py" in files and "xrce/examples/turtlebot3_cli.py" not in files
    assert sorted(p.relative_to(outdir).as_posix() for p in written) == sorted(f[:-3] + ".mpy" for f in files)
    for path in written:
        header = path.read_bytes()[:4]
        # 'M', format version 6 (what 1.27 loads: sys.implementation._mpy == 0x306), arch bits 0 =
        # portable bytecode (the v6 sub-version is only stamped on native code), 31-bit small ints
        assert header == b"M\x06\x00\x1f", (path, header)
    total = sum(p.stat().st_size for p in written)
    with capsys.disabled():
        print("\n.mpy: %d modules, %d bytes (sources %d bytes)" % (
            len(written), total, sum((mpy.REPO_ROOT / f).stat().st_size for f in files)))


def test_build_mpy_reports_compile_errors(tmp_path):
    (tmp_path / "xrce").mkdir()
    (tmp_path / "xrce" / "broken.py").write_text("def oops(:\n")
    with pytest.raises(RuntimeError, match="xrce/broken.py"):
        mpy.build_mpy(tmp_path / "out", root=tmp_path, files=["xrce/broken.py"])


IMPORT_ALL = r"""
import sys
for name in sys.argv[1:]:
    try:
        module = __import__(name)
        for part in name.split(".")[1:]:
            module = getattr(module, part)
        print("ok", name, module.__file__)
    except ImportError as error:
        print("importerror", name, error)
for name in %r:
    try:
        __import__(name)
        print("present", name)
    except ImportError:
        pass
from xrce.wire.cdr import CdrReader, CdrWriter
w = CdrWriter()
w.u16(0xBEEF)
w.f64(2.5)
w.string("mpy")
r = CdrReader(w.getvalue())
print("cdr", r.u16(), r.f64(), r.string())
""" % (BOARD_ONLY_MODULES,)


def test_compiled_mpy_files_import_under_micropython(mpy_build):
    outdir, _ = mpy_build
    names = [_module_name(f) for f in mpy.client_files()]
    result = run_micropython(IMPORT_ALL, *names, mounts=[(outdir, "/lib")], default_mount=False, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    lines = result.stdout.splitlines()
    assert not [line for line in lines if line.startswith("present")], "wasm port unexpectedly has a board module"
    assert lines[-1] == "cdr 48879 2.5 mpy"
    seen = set()
    for line in lines[:-1]:
        status, name, detail = line.split(" ", 2)
        seen.add(name)
        if status == "ok":
            # loaded from the compiled file, not from a .py that happened to be on the path
            assert detail == "/lib/%s%s.mpy" % (name.replace(".", "/"), "/__init__" if detail.endswith("__init__.mpy") else ""), line
        else:
            missing = detail.split("'")[1] if "'" in detail else detail
            assert missing in BOARD_ONLY_MODULES, line
    assert seen == set(names)
