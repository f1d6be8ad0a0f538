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
"""

from __future__ import annotations

import fcntl
import os
import re
import shutil
import tempfile
import time

SHM_DIR = "/dev/shm"
# Fast DDS 2.x names them fastrtps_*, 3.x fastdds_*.
_SEGMENT_LOCK = re.compile(r"^(fastrtps|fastdds)_[0-9a-z]{16}(_el|_sl)$")
_PORT_LOCK = re.compile(r"^(fastrtps|fastdds)_port\d{1,5}(_el|_sl)$")
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


def remove_dead_fastdds_segments(before: set) -> list:
    """Remove the Fast DDS segments and ports created since ``before`` whose owners are all gone;
    the names removed."""
    removed = []
    now = time.time()
    for name in sorted(shm_names() - before):
        is_segment, is_port = _SEGMENT_LOCK.match(name), _PORT_LOCK.match(name)
        if not (is_segment or is_port):
            continue
        lock = os.path.join(SHM_DIR, name)
        try:
            if now - os.stat(lock).st_mtime < MIN_AGE_S or _locked(lock):
                continue
        except OSError:
            continue
        base = name[:-3]
        victims = [name, base] + (["sem.%s_mutex" % base] if is_port else [])
        for victim in victims:
            try:
                os.remove(os.path.join(SHM_DIR, victim))
                removed.append(victim)
            except OSError:
                pass
    return removed


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
