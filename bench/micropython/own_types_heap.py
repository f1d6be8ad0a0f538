"""The heap your own message types cost a board, under real MicroPython 1.27 (tests/micropython harness).

    .venv/bin/python bench/micropython/own_types_heap.py [PKG_DIR ...] [--mpy]

Each PKG_DIR (an interface package: msg/, srv/, action/) goes through ``xrce-client gen-msgs``
(``--mpy``: compiled, as a board loads ``/lib/*.mpy``); every type it defines is then imported on
MicroPython, each in an interpreter of its own on top of what a firmware has loaded before its own
types (the message runtime, a first type, the string, sequence and array helpers), and encoded and
decoded once (its plan, built on first use, stays). Printed per type: the live heap its import keeps, and with its plan.

Then the same for a package this script writes, one type per field kind with 1 and with 9 fields of
that kind (names of 6 characters, all different, as a type's own names are), which gives what a
type costs by itself and what each field of a kind adds: plan a type of yours as the first figure
plus its fields'. Live heap is what stays after the garbage collector ran (the harness's stepped
mode, ``mpheap.live``); figures move by up to ~1 KB where an import happens to grow MicroPython's
string pool by a block (its names are interned there), so read them as a table, not a byte count.
"""

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
import bench.common  # noqa: E402,F401  (the test helpers on sys.path)

from mp_harness import run_micropython  # noqa: E402
from xrce.tools import mpy, msggen  # noqa: E402
from xrce.tools.msg_parser import load_actions, load_package  # noqa: E402

KINDS_PACKAGE = "heap_kinds_msgs"
# (label, field type, a value for its test sample): one type per kind, 1 and 9 fields of it.
KINDS = (
    ("bool", "bool", "True"),
    ("int32", "int32", "7"),
    ("float64", "float64", "0.5"),
    ("string", "string", "'abc'"),
    ("bounded string", "string<=16", "'abc'"),
    ("int32[] (sequence)", "int32[]", "[1, 2]"),
    ("float64[9] (fixed array)", "float64[9]", "[0.5] * 9"),
    ("uint8[] (bytes)", "uint8[]", "b'ab'"),
    ("nested geometry_msgs/Vector3", "geometry_msgs/Vector3", None),
)

MEASURE_SOURCE = r"""
import mpheap
from xrce.wire.cdr import CdrReader, CdrWriter

def _round_trip(cls):
    w = CdrWriter(bytearray(4096))
    cls().encode(w)
    cls.decode(CdrReader(w.getvalue()))

def run(report, argv):
    # What a firmware has before its own types: the runtime, a first type, the helpers of strings,
    # sequences and arrays (xrce.msgs._seq) and Vector3 (the nested kind's own type).
    from xrce.msgs.std_msgs import String
    from xrce.msgs.geometry_msgs import Vector3
    from xrce.msgs.sensor_msgs import BatteryState, Image, Imu
    for cls in (String, Vector3, BatteryState, Image, Imu):
        _round_trip(cls)
    cls = None
    yield
    yield
    package, name = argv[0].split(".")
    before = mpheap.live
    cls = getattr(__import__("xrce.msgs." + package, None, None, (name,)), name)
    yield
    imported = mpheap.live - before
    _round_trip(getattr(cls, "Request", cls))  # a service: its request stands for it
    cls = None
    yield
    report(argv[0], "%d %d" % (imported, mpheap.live - before))
"""

STEPPED_RUNNER_TAIL = r"""
import sys
def _report(key, value):
    print("REPORT\t%s\t%s" % (key, value))
def main():
    return run(_report, sys.argv[1:])
"""


def _names(label, count):
    stem = "".join(c for c in label if c.isalnum())[:3].lower()
    return ["%s_%d%s" % (stem, i, "abcdefghij"[i]) for i in range(count)]


def write_kinds_package(root):
    """heap_kinds_msgs: for each kind K, K1 (one field of K) and K9 (nine)."""
    package = Path(root) / KINDS_PACKAGE
    (package / "msg").mkdir(parents=True)
    types = []
    for index, (label, field_type, _) in enumerate(KINDS):
        for count in (1, 9):
            name = "Kind%d%s" % (index, "One" if count == 1 else "Nine")
            lines = ["%s %s" % (field_type, field) for field in _names("k%d" % index, count)]
            (package / "msg" / (name + ".msg")).write_text("\n".join(lines) + "\n")
            types.append(name)
    return package, types


def generate(package_dirs, outdir, compiled):
    written, _ = mpy.gen_msgs([str(d) for d in package_dirs], str(outdir), compiled=compiled)
    specs = []
    for directory in package_dirs:
        package, messages, services = load_package(str(directory))
        names = msggen.package_class_names(messages, services, load_actions(str(directory)))
        specs += ["%s.%s" % (package, name) for name in names]
    return specs


def measure(outdir, specs):
    mounts = [(path, "/lib/xrce/msgs/" + path.name) for path in sorted((Path(outdir) / "xrce" / "msgs").iterdir())]
    figures = {}
    for spec in specs:  # each type in an interpreter of its own: no other type's garbage or plan
        result = run_micropython(MEASURE_SOURCE + STEPPED_RUNNER_TAIL, spec, mounts=mounts, timeout=300,
                                 stepped=True, heap=2 * 1024 * 1024)
        if result.returncode != 0:
            raise SystemExit("MicroPython failed on %s:\n%s%s" % (spec, result.stdout, result.stderr))
        for line in result.stdout.splitlines():
            if line.startswith("REPORT\t"):
                _, key, value = line.split("\t", 2)
                figures[key] = tuple(int(v) for v in value.split())
    return figures


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("packages", nargs="*", metavar="PKG_DIR", help="your interface packages")
    parser.add_argument("--mpy", action="store_true", help="measure mpy-cross output (as /lib/*.mpy) instead of .py")
    options = parser.parse_args(argv)
    form = ".mpy" if options.mpy else ".py"
    with tempfile.TemporaryDirectory(prefix="xrce-own-types-") as scratch:
        scratch = Path(scratch)
        if options.packages:
            specs = generate([Path(p) for p in options.packages], scratch / "own", options.mpy)
            figures = measure(scratch / "own", specs)
            print("MicroPython 1.27 (WebAssembly, Node), from %s: live heap per type, bytes" % form)
            print("  %-48s %10s %16s" % ("type", "import", "with its plan"))
            for spec in specs:
                imported, planned = figures[spec]
                print("  %-48s %10d %16d" % (spec.replace(".", "/"), imported, planned))
            print()
        kinds_dir, types = write_kinds_package(scratch / "src")
        specs = generate([kinds_dir], scratch / "kinds", options.mpy)
        figures = measure(scratch / "kinds", specs)
    print("Per field kind, from %s (a type of 1 field, and what each of 8 more adds; with plans), bytes" % form)
    print("  %-32s %18s %16s" % ("field kind", "type of 1 field", "each more field"))
    for index, (label, _, _) in enumerate(KINDS):
        one = figures["%s.Kind%dOne" % (KINDS_PACKAGE, index)][1]
        nine = figures["%s.Kind%dNine" % (KINDS_PACKAGE, index)][1]
        print("  %-32s %18d %16d" % (label, one, round((nine - one) / 8)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
