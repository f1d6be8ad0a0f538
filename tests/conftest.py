"""Fixtures shared by several test modules, defined here once: pytest builds a session-scoped one
once per run (an import into two modules would make two), and a test module gets the engine
fixture without importing it."""

import os
import termios
import tty

import pytest

from engine_peer import ced_agent  # noqa: F401
from install_env import sourced_ros, wheel_venv, xrce_wheels  # noqa: F401


@pytest.fixture
def pty_pair():
    """Opens raw pseudo-terminal pairs on demand: ``make()`` -> (master fd, slave path)."""
    opened = []

    def make():
        master, slave = os.openpty()
        tty.setraw(master, termios.TCSANOW)
        opened.extend((master, slave))
        return master, os.ttyname(slave)

    yield make
    for fd in opened:
        os.close(fd)
