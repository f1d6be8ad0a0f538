"""tests/helpers/hygiene.py removes what a run left in /dev/shm, and only that: here its lttng-ust part,
with a rendezvous file of a made-up ABI number (the real ones, where no process maps them, go too,
as after a run)."""

import os
import subprocess
import sys

import hygiene

NAME = "lttng-ust-wait-99-%d" % os.getuid()
PATH = os.path.join(hygiene.SHM_DIR, NAME)

HOLD_MAPPED = """
import mmap, sys
with open(sys.argv[1], "r+b") as handle:
    mapping = mmap.mmap(handle.fileno(), 4096)
    print("mapped", flush=True)
    sys.stdin.read()
"""


def _create():
    with open(PATH, "wb") as handle:
        handle.write(bytes(4096))


def test_a_rendezvous_file_goes_once_no_process_maps_it():
    _create()
    holder = subprocess.Popen([sys.executable, "-c", HOLD_MAPPED, PATH],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "mapped"
        assert NAME not in hygiene.remove_unused_lttng_wait_files()
        assert os.path.exists(PATH)
    finally:
        holder.stdin.close()
        holder.wait(timeout=30)
    try:
        assert NAME in hygiene.remove_unused_lttng_wait_files()
        assert not os.path.exists(PATH)
    finally:
        if os.path.exists(PATH):
            os.remove(PATH)


def test_other_files_stay():
    """Only lttng-ust's rendezvous files: a look-alike name of another program stays."""
    path = os.path.join(hygiene.SHM_DIR, "lttng-ust-wait-99-%d-other" % os.getuid())
    with open(path, "wb") as handle:
        handle.write(bytes(16))
    try:
        hygiene.remove_unused_lttng_wait_files()
        assert os.path.exists(path)
    finally:
        os.remove(path)
