import sys

from xrce.tools.ros_cli.cli import main

sys.exit(main())
