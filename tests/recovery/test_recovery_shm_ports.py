"""A killed agent's Fast DDS shared-memory ports while the restarted agent makes its participant
(xrce/agent/middleware/ros/participant.py, ``dead_ports_held``): the port lock files nobody holds
are held for that time, so Fast DDS takes another port number; live ones are left alone, and
everything is released afterwards. Real ``flock`` locks on files laid out as Fast DDS lays them
out, in a temporary directory (the host's /dev/shm belongs to every Fast DDS process on it)."""

import fcntl
import os

from xrce.agent.middleware.ros import participant


def _lockable(path):
    """Whether another open of ``path`` gets the exclusive lock Fast DDS's reader takes."""
    fd = os.open(path, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except OSError:
        return False
    finally:
        os.close(fd)


def test_dead_ports_are_held_while_the_participant_is_made_and_released_after(tmp_path):
    for name in ("fastrtps_port7413", "fastrtps_port7413_el", "fastrtps_port7415_el",
                 "fastdds_port7417_el", "fastrtps_port7413_sl", "fastrtps_0dec56d7b2b210a0_el",
                 "other_port7419_el", "fastrtps_port7661_el", "fastrtps_port7001_el",
                 "fastrtps_port7412_el"):
        (tmp_path / name).write_bytes(b"")
    live = os.open(tmp_path / "fastrtps_port7415_el", os.O_RDONLY)  # a live reader's lock
    fcntl.flock(live, fcntl.LOCK_EX | fcntl.LOCK_NB)
    dead = [tmp_path / "fastrtps_port7413_el", tmp_path / "fastdds_port7417_el"]
    # segments, shared locks, another program's prefix, domain 1's port, numbers no user port has
    others = [tmp_path / name for name in (
        "fastrtps_0dec56d7b2b210a0_el", "other_port7419_el", "fastrtps_port7413_sl",
        "fastrtps_port7661_el", "fastrtps_port7001_el", "fastrtps_port7412_el")]
    try:
        with participant.dead_ports_held(0, str(tmp_path)) as held:
            assert held == 2
            assert not any(_lockable(path) for path in dead)  # Fast DDS sees them taken
            assert all(_lockable(path) for path in others)
        assert all(_lockable(path) for path in dead)
        assert not _lockable(tmp_path / "fastrtps_port7415_el")  # the live one: still its owner's
    finally:
        os.close(live)
    assert sorted(os.listdir(tmp_path)) == sorted(  # nothing removed, nothing made
        ["fastrtps_port7413", "fastrtps_port7413_el", "fastrtps_port7415_el",
         "fastdds_port7417_el", "fastrtps_port7413_sl", "fastrtps_0dec56d7b2b210a0_el",
         "other_port7419_el", "fastrtps_port7661_el", "fastrtps_port7001_el",
         "fastrtps_port7412_el"])


def test_no_shared_memory_directory_holds_nothing(tmp_path):
    with participant.dead_ports_held(0, str(tmp_path / "absent")) as held:
        assert held == 0
