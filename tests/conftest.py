"""Fixtures shared by several test modules, defined here once: pytest builds a session-scoped one
once per run (an import into two modules would make two), and a test module gets the engine
fixture without importing it."""

from engine_peer import ced_agent  # noqa: F401
from install_env import sourced_ros, wheel_venv, xrce_wheels  # noqa: F401
