"""``python -m xrce.agent ...`` is the ``xrce-agent`` command."""

import sys

from xrce.agent.launcher import main

sys.exit(main())
