"""``python -m xrce.client``: the ``xrce-client`` command line (see ``xrce.client.cli``)."""

import sys

from xrce.client.cli import main

sys.exit(main())
