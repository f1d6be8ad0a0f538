"""Every float constant in the modules manifest.py freezes fits a 32-bit float.

MicroPython's freezer (tools/mpy-tool.py, 1.27) writes each float constant for every object
representation a port may use and packs it as a 32-bit float whatever the target: one constant past
3.4e38 stops the firmware build on every port, and a single-precision board would read it as inf
anyway. No MicroPython source is needed here: the check is the same ``struct.pack('<f', x)``."""

import ast
import struct

import pytest

from xrce.tools import mpy


def _manifest_files(text):
    # manifest.py is MicroPython's manifest language, a Python subset: run it with the two calls it
    # makes recorded instead of executed by makemanifest.
    listed = []

    def package(name, files=(), base_path=".", opt=None):
        listed.extend(name + "/" + relative for relative in files)

    exec(compile(text, "manifest.py", "exec"), {"metadata": lambda **kw: None, "package": package})
    return listed


def _float_constants(source, filename):
    for node in ast.walk(ast.parse(source, filename)):
        if isinstance(node, ast.Constant) and isinstance(node.value, (float, complex)):
            parts = (node.value.real, node.value.imag) if isinstance(node.value, complex) else (node.value,)
            for value in parts:
                yield node.lineno, value


def _unholdable(value):
    """Why a 32-bit float cannot hold value, or None."""
    try:
        packed = struct.pack("<f", value)
    except OverflowError:
        return "too large for a 32-bit float"
    if value != 0.0 and struct.unpack("<f", packed)[0] == 0.0:
        return "a 32-bit float holds it as 0.0"
    return None


def _findings(root, files):
    found = []
    for relative in files:
        source = (root / relative).read_text(encoding="utf-8")
        for line, value in _float_constants(source, relative):
            why = _unholdable(value)
            if why:
                found.append("%s:%d: %r is %s" % (relative, line, value, why))
    return found


def test_manifest_lists_what_is_shipped():
    listed = _manifest_files((mpy.REPO_ROOT / mpy.MANIFEST_NAME).read_text(encoding="utf-8"))
    assert listed == mpy.shipped_files()
    assert "xrce/client/parameters.py" in listed


def test_every_frozen_float_constant_fits_32_bits():
    listed = _manifest_files((mpy.REPO_ROOT / mpy.MANIFEST_NAME).read_text(encoding="utf-8"))
    assert len(listed) > 100
    found = _findings(mpy.REPO_ROOT, listed)
    assert not found, "mpy-tool.py cannot freeze these (write an unbounded value as float('inf')):\n" + "\n".join(found)


@pytest.mark.parametrize("literal, caught", [
    ("1.7976931348623157e308", True),   # the largest double: the constant that stopped the freeze
    ("-3.5e38", True),                   # its minus sign is an operator: the literal alone overflows
    ("1e-50", True),                     # non-zero, but 0.0 in 32 bits
    ("2j * 1e39", True),
    ("3.4e38", False),
    ("1e-40", False),                    # a 32-bit subnormal still holds it
    ("float('inf')", False),             # computed when the module runs: no constant to freeze
    ("0.0", False),
])
def test_the_check_catches_what_the_freezer_stops_on(tmp_path, literal, caught):
    (tmp_path / "m.py").write_text("X = %s\n" % literal)
    assert bool(_findings(tmp_path, ["m.py"])) == caught
