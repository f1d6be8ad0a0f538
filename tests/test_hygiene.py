"""tests/hygiene.py removes what a run left in /dev/shm, and only that: here its lttng-ust part,
with a rendezvous file of a made-up ABI number so that the real ones are never touched."""

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


def test_a_rendezvous_file_of_the_run_goes_once_no_process_maps_it():
    before = hygiene.shm_names() - {NAME}
    _create()
    holder = subprocess.Popen([sys.executable, "-c", HOLD_MAPPED, PATH],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "mapped"
        assert hygiene.remove_unused_lttng_wait_files(before) == []
        assert os.path.exists(PATH)
    finally:
        holder.stdin.close()
        holder.wait(timeout=30)
    try:
        assert hygiene.remove_unused_lttng_wait_files(before) == [NAME]
        assert not os.path.exists(PATH)
    finally:
        if os.path.exists(PATH):
            os.remove(PATH)


def test_a_rendezvous_file_from_before_the_run_stays():
    _create()
    try:
        assert hygiene.remove_unused_lttng_wait_files(hygiene.shm_names()) == []
        assert os.path.exists(PATH)
    finally:
        os.remove(PATH)
