"""``python -m xrce.agent.cli ...``: the command line without the launcher's import shaping
(``python -m xrce.agent`` is the ``xrce-agent`` command)."""

import sys

from xrce.agent.cli import main

sys.exit(main())
