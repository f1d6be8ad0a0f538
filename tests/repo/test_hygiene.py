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



def _dead_port():
    """A dead Fast DDS port's three files (lock file unlocked, old: its owner made it long ago)
    under a number no Fast DDS process uses."""
    port = "fastrtps_port%d" % (60001 + 2 * (os.getpid() % 700))
    paths = [os.path.join(hygiene.SHM_DIR, name)
             for name in (port + "_el", port, "sem.%s_mutex" % port)]
    for path in paths:
        with open(path, "wb") as handle:
            handle.write(bytes(4096))
        os.utime(path, (0, 0))
    return paths


def test_a_dead_port_a_new_owner_has_opened_stays_and_an_unused_one_goes():
    """A participant restarted in the same domain takes its old port number at once: Fast DDS
    opens and maps the dead port's segment before it takes the lock. Another run's clean-up
    (the same /dev/shm) must then leave it: unlinked, the new owner read a segment its peers no
    longer found (tests/fastpath/test_fastpath_repliers.py's second agent got no request)."""
    paths = _dead_port()
    holder = subprocess.Popen([sys.executable, "-c", HOLD_MAPPED, paths[1]],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "mapped"
        hygiene.remove_dead_fastdds_segments(set(), min_age_s=1.0)
        assert all(os.path.exists(path) for path in paths), paths
    finally:
        holder.stdin.close()
        holder.wait(timeout=30)
    try:
        hygiene.remove_dead_fastdds_segments(set(), min_age_s=1.0)
        assert not any(os.path.exists(path) for path in paths), paths
    finally:
        for path in paths:
            if os.path.exists(path):
                os.remove(path)
