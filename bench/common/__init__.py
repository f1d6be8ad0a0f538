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

# A bench's agents keep their default state stores (xrce.agent.state) in a folder of this run's
# own, removed at exit, not in the user's ~/.local/state: a bench's sessions must neither pile up
# there (one file per free port) nor be restored into the user's own agent on that port.
import atexit as _atexit  # noqa: E402
import os as _os  # noqa: E402
import shutil as _shutil  # noqa: E402
import tempfile as _tempfile  # noqa: E402

_STATE_HOME = _tempfile.mkdtemp(prefix="xrce-bench-state-")
_os.environ["XDG_STATE_HOME"] = _STATE_HOME
_atexit.register(_shutil.rmtree, _STATE_HOME, True)
