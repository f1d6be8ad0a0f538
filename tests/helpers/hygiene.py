"""What a test run must not leave behind (issue 23): ROS log files in ~/.ros and Fast DDS
shared-memory segments in /dev/shm.

- ``private_ros_log_dir()``: ROS_LOG_DIR pointed at a temporary directory for the whole run, so
  rcl's log files (one per rclpy context, most of them empty) of the test process and of every
  child started with ``os.environ`` go there, and are removed with it.
- ``remove_dead_fastdds_segments(before)``: a Fast DDS process killed with SIGKILL (tests kill
  agents on purpose) leaves its segments in /dev/shm. Each segment and port has a lock file
  (``<name>_el`` or ``_sl``) that its live owners hold with ``flock``; one nobody holds belongs
  to dead processes, which is also how Fast DDS's own ``fastdds shm clean`` tells them apart.
  Only files that appeared during the run are considered, and only once their lock file is a
  few seconds old: a segment being created has its lock taken within microseconds.
- ``remove_dead_fastdds_segments_after_exit(before)``: the same once the test process has exited.
  At the end of a run some owners are still alive: the test process itself (its in-process rclpy
  participants go with it) and children still stopping; their segments are dead only after the
  run (1-3 were left per run). A small detached process waits for the test process to end and
  then removes them, for a few seconds while late children finish.
- lttng-ust's rendezvous files: every process that loads rcl or the rmw (the wheels link
  lttng-ust for ROS's tracepoints) creates ``/dev/shm/lttng-ust-wait-<abi>`` and
  ``...-<abi>-<uid>`` when no LTTng session daemon has, and no environment variable stops it.
  They are removed after the run when no process maps them, also those that were there before it:
  a run that follows another (``.ci/run``'s two jobs) finds the first run's files, which that run
  could not remove while the second one's processes mapped them. Unmapped, they serve nobody (a
  session daemon and every traced process keep them mapped) and the next such process makes them
  again.
"""

from __future__ import annotations

import fcntl
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

SHM_DIR = "/dev/shm"
# Fast DDS 2.x names them fastrtps_*, 3.x fastdds_*.
_SEGMENT_LOCK = re.compile(r"^(fastrtps|fastdds)_[0-9a-z]{16}(_el|_sl)$")
_PORT_LOCK = re.compile(r"^(fastrtps|fastdds)_port\d{1,5}(_el|_sl)$")
_PORT = re.compile(r"^(fastrtps|fastdds)_port\d{1,5}$")
_LTTNG_WAIT = re.compile(r"^lttng-ust-wait-\d+(-\d+)?$")
MIN_AGE_S = 2.0


def shm_names() -> set:
    try:
        return set(os.listdir(SHM_DIR))
    except OSError:
        return set()


def _locked(path: str) -> bool:
    try:
        with open(path, "ab") as handle:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return False
    except OSError:
        return True


def remove_dead_fastdds_segments(before: set, min_age_s: float = MIN_AGE_S) -> list:
    """Remove the Fast DDS segments and ports created since ``before`` whose owners are all gone
    and whose lock file is at least ``min_age_s`` old; the names removed."""
    removed = []
    now = time.time()
    present = shm_names()
    # Every lock is looked at, old ones too: a port's lock file may predate the run while the
    # port and its mutex were made during it. Only what appeared during the run is removed.
    for name in sorted(present):
        is_segment, is_port = _SEGMENT_LOCK.match(name), _PORT_LOCK.match(name)
        if not (is_segment or is_port):
            continue
        base = name[:-3]
        victims = [v for v in [name, base] + (["sem.%s_mutex" % base] if is_port else [])
                   if v in present and v not in before]
        if not victims:
            continue
        lock = os.path.join(SHM_DIR, name)
        try:
            if now - os.stat(lock).st_mtime < min_age_s or _locked(lock):
                continue
        except OSError:
            continue
        removed += _remove_unless_reopened(victims)
    # A port whose lock file is gone: its last user removed the lock and left the port and its
    # mutex (seen after a run, 2 ports). Fast DDS itself takes a port whose lock it can take as
    # dead, and a missing lock file is one it can create and take.
    for name in sorted(present - before):
        if _PORT.match(name) and not any(name + suffix in present for suffix in ("_el", "_sl")):
            try:
                if now - os.stat(os.path.join(SHM_DIR, name)).st_mtime < min_age_s:
                    continue
            except OSError:
                continue
            removed += _remove_unless_reopened(
                [v for v in (name, "sem.%s_mutex" % name) if v in present])
    return removed


def _mapped_by_any_process(paths: set) -> set:
    """Which of ``paths`` some live process has mapped. A file is known by its device and inode:
    a process in another mount namespace shows its own /dev/shm's files under the same names."""
    wanted = {}
    for path in paths:
        try:
            status = os.stat(path)
        except OSError:
            continue
        wanted[("%02x:%02x" % (os.major(status.st_dev), os.minor(status.st_dev)),
                str(status.st_ino))] = path
    mapped = set()
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open("/proc/%s/maps" % pid, errors="replace") as maps:
                for line in maps:
                    fields = line.split(None, 5)
                    if len(fields) == 6 and (fields[3], fields[4]) in wanted:
                        mapped.add(wanted[fields[3], fields[4]])
        except OSError:
            continue
    return mapped


def remove_unused_lttng_wait_files() -> list:
    """Remove the lttng-ust rendezvous files that no process maps."""
    created = {os.path.join(SHM_DIR, name) for name in shm_names() if _LTTNG_WAIT.match(name)}
    if not created:
        return []
    unused = created - _mapped_by_any_process(created)
    return _remove(sorted(os.path.basename(path) for path in unused))


def _remove(names) -> list:
    removed = []
    for name in names:
        try:
            os.remove(os.path.join(SHM_DIR, name))
            removed.append(name)
        except OSError:
            pass
    return removed


def _remove_unless_reopened(names) -> list:
    """Remove a dead segment or port (``names``, its lock file last) unless a live process has
    its file open or mapped meanwhile. A restarted participant takes its old port number again at
    once (an agent restarted in the same domain gets the same participant id): Fast DDS opens and
    maps the dead port's segment, then takes its lock, and a clean-up that found it dead just
    before (another run's, in this shared /dev/shm) unlinked the segment the new owner reads: its
    peers then wrote to a new one, and no sample reached it. So the segment is first moved out of
    the way (a rename: whoever opens it by name from then on makes a fresh one), and put back if
    some process had opened it before (its descriptor, or its mapping once the descriptor is
    closed: read in that order, one of them shows)."""
    names = list(names)
    data = [name for name in names if not name.endswith(("_el", "_sl"))]
    aside = {}
    for name in data:
        path = os.path.join(SHM_DIR, name)
        moved = os.path.join(SHM_DIR, ".xrce-dead-%d-%s" % (os.getpid(), name))
        try:
            os.rename(path, moved)
        except OSError:
            continue
        aside[name] = moved
    in_use = _open_or_mapped_by_any_process(set(aside.values()))
    if in_use:
        for name, moved in aside.items():
            try:  # link, not rename: a fresh file made under the name meanwhile stays
                os.link(moved, os.path.join(SHM_DIR, name))
            except OSError:
                pass
            os.remove(moved)
        return []
    removed = []
    for name, moved in aside.items():
        try:
            os.remove(moved)
            removed.append(name)
        except OSError:
            pass
    return removed + [name for name in names if name not in data and _remove_unlocked(name)]


def _remove_unlocked(name: str) -> bool:
    """Remove a lock file unless someone holds it: a new owner may have taken it meanwhile, and
    a port without its lock file looks dead to everyone (Fast DDS and these clean-ups)."""
    try:
        fd = os.open(os.path.join(SHM_DIR, name), os.O_RDONLY | os.O_CLOEXEC | os.O_NOFOLLOW)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False
    else:
        return bool(_remove([name]))
    finally:
        os.close(fd)


def _open_or_mapped_by_any_process(paths: set) -> bool:
    """Whether any live process has one of ``paths`` open or mapped (descriptors first)."""
    wanted = set()
    for path in paths:
        try:
            status = os.stat(path)
        except OSError:
            continue
        wanted.add((status.st_dev, status.st_ino))
    if not wanted:
        return False
    maps_keys = {("%02x:%02x" % (os.major(dev), os.minor(dev)), str(ino)) for dev, ino in wanted}
    pids = [pid for pid in os.listdir("/proc") if pid.isdigit() and int(pid) != os.getpid()]
    for pid in pids:
        try:
            for fd in os.listdir("/proc/%s/fd" % pid):
                try:
                    status = os.stat("/proc/%s/fd/%s" % (pid, fd))
                except OSError:
                    continue
                if (status.st_dev, status.st_ino) in wanted:
                    return True
        except OSError:
            pass
        try:
            with open("/proc/%s/maps" % pid, errors="replace") as maps:
                for line in maps:
                    fields = line.split(None, 5)
                    if len(fields) == 6 and (fields[3], fields[4]) in maps_keys:
                        return True
        except OSError:
            continue
    return False


def _process_gone(pid: int) -> bool:
    try:
        with open("/proc/%d/stat" % pid) as stat:
            return stat.read().rsplit(")", 1)[1].split()[0] == "Z"  # exited, not yet reaped
    except OSError:
        return True


def _clean_after(pid: int, before: set, linger_s: float = 5.0) -> None:
    while not _process_gone(pid):
        time.sleep(0.05)
    end = time.monotonic() + linger_s
    while True:
        remove_dead_fastdds_segments(before, min_age_s=0.5)
        if time.monotonic() >= end:
            remove_unused_lttng_wait_files()
            return
        time.sleep(0.5)


def remove_dead_fastdds_segments_after_exit(before: set) -> None:
    """Remove now what is dead, and start a detached process that removes the rest once this
    process has exited (see the module docstring)."""
    remove_dead_fastdds_segments(before)
    cleaner = ("import sys; sys.path.insert(0, %r); import hygiene; "
               "hygiene._clean_after(%d, set(sys.stdin.read().split()))"
               % (os.path.dirname(os.path.abspath(__file__)), os.getpid()))
    process = subprocess.Popen([sys.executable, "-c", cleaner], stdin=subprocess.PIPE,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                               start_new_session=True, text=True)
    process.stdin.write("\n".join(sorted(before)))
    process.stdin.close()


class PrivateRosLogDir:
    """ROS_LOG_DIR set to a fresh temporary directory until ``close()``, which removes it."""

    def __init__(self):
        self.previous = os.environ.get("ROS_LOG_DIR")
        self.path = tempfile.mkdtemp(prefix="xrce-tests-ros-log-")
        os.environ["ROS_LOG_DIR"] = self.path

    def close(self):
        if self.previous is None:
            os.environ.pop("ROS_LOG_DIR", None)
        else:
            os.environ["ROS_LOG_DIR"] = self.previous
        shutil.rmtree(self.path, ignore_errors=True)
