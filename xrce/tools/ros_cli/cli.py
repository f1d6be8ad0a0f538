"""The ``xrce-ros`` command line: ``xrce-ros <group> <verb> ...`` as ``ros2 <group> <verb> ...``.

Exit codes as ros2cli's: 0 done (a command without its verb prints its help, as ``ros2`` does); 1
the graph did not give what was asked (the same sentence on stderr); 2 a bad argument, in one line
on stderr (ros2cli prints a usage dump first: scripts and tests read one line), and 2 after Ctrl-C
too (ros2cli returns ``signal.SIGINT``); 15 after SIGTERM (ros2cli's ExternalShutdownException).
"""

from __future__ import annotations

import os
import signal
import sys

from xrce.command_line import OneLineErrorParser
from xrce.tools.ros_cli.arguments import (EXIT_FAILED, EXIT_INTERRUPTED, EXIT_TERMINATED, PROG,
                                          CommandError, UsageError, usage_exit)


# ----------------------------------------------------------------------------- parser

def build_parser():
    from xrce.tools.ros_cli import action, interface, node, param, service, topic

    parser = OneLineErrorParser(
        prog=PROG,
        description="The ros2 verbs a micro-ROS user needs to see a board, on this venv's rclpy "
                    "(ros2cli's syntax and output; no daemon).")
    parser.set_defaults(help_of=parser)
    groups = parser.add_subparsers(dest="group", metavar="COMMAND")
    for module in (action, interface, node, param, service, topic):
        group = groups.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        group.set_defaults(help_of=group)
        verbs = group.add_subparsers(dest="verb", metavar="VERB")
        module.add_verbs(verbs)
    return parser


class Terminated(Exception):
    """SIGTERM, raised between two steps of a verb as Ctrl-C is: the node is destroyed on the way
    out, as ros2cli's context shutdown destroys its node."""


def _terminate(signum, frame):
    raise Terminated()


def main(argv=None):
    # The agent's Fast DDS profile, on the same terms as the agent takes it (not over a user's
    # profile, nor for another RMW): with Fast DDS's defaults a participant that joins next to
    # running nodes often loses their answers to its first announcement and sees them only at
    # their next one, 3 s later (docs/PERFORMANCE.md), which is after a command like this has
    # listed the graph and gone. Its asynchronous discovery writers keep those answers.
    from xrce.agent.middleware.ros import fastdds_profile

    fastdds_profile.install()
    parser = build_parser()
    args = parser.parse_args(argv)
    # Line-buffered as ros2cli makes it: a pipe reader (a script, a test) sees each message when
    # it is printed, not when a block fills.
    sys.stdout.reconfigure(line_buffering=True)
    if not hasattr(args, "run"):  # `xrce-ros`, `xrce-ros topic`: the help, as ros2 prints it
        args.help_of.print_help()
        return 0
    from rclpy.exceptions import NameValidationException

    signal.signal(signal.SIGTERM, _terminate)
    try:
        return args.run(args) or 0
    except UsageError as error:
        usage_exit(str(error))
    except NameValidationException as error:  # a topic, service or node name rclpy refuses
        usage_exit(" ".join(str(error).split()))
    except CommandError as error:
        sys.stderr.write("%s\n" % error)
        return EXIT_FAILED
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    except Terminated:
        return EXIT_TERMINATED
    except BrokenPipeError:
        # The reader went away (`xrce-ros topic echo /odom | head`): end quietly, and keep the
        # interpreter's final flush from failing on the same pipe.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_FAILED
