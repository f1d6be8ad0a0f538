"""Fixtures shared by several test modules with session scope: defined here once so that pytest
builds each of them once per run (an import into two modules would make two)."""

from install_env import sourced_ros, wheel_venv, xrce_wheels  # noqa: F401
