"""Stopping the bench's child processes the way a user would: Ctrl-C first, kill only if it hangs.

The demo (``xrce-agent demo``) stops its agent and robot the same way; one function serves both.
"""

from xrce.agent.demo import stop_child as interrupt  # noqa: F401  (the benches import it from here)
