"""The agent's own log level, below DEBUG: ``TRACE`` (``-v 6``) logs every message decoded and sent,
on logger ``xrce.agent``. A ground module (standard library only): the command line names the level
before it loads any of the agent, the engine logs at it."""

import logging

TRACE = 5
logging.addLevelName(TRACE, "TRACE")
