"""What the bench scripts share, and where they find the checkout.

A bench script runs as a file (``python bench/agent/cost.py``), so Python puts only its own folder
on ``sys.path``. Its first lines put the checkout there and import this package, which adds the
test helpers the benchmarks reuse (``agent_process``, ``ros_helpers``, ``microros_replay``,
``firmware_replier``, ``mp_harness``): the one place that knows where those live.
"""

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
TEST_HELPERS = REPO / "tests" / "helpers"

for _folder in (REPO, TEST_HELPERS):  # the helpers first, as every script had them
    if str(_folder) in sys.path:
        sys.path.remove(str(_folder))
    sys.path.insert(0, str(_folder))
