"""The ``xrce-ros`` command line: ``xrce-ros <group> <verb> ...`` as ``ros2 <group> <verb> ...``.

Exit codes: 0 done; 1 the graph did not give what was asked (ros2cli prints the same sentence on
stderr and exits 1 there too); 2 a bad argument, in one line on stderr (ros2cli prints a usage
dump: scripts and tests read one line); 130 Ctrl-C (ros2cli exits 2 there, which would read as a
bad argument).
"""

from __future__ import annotations

import os
import sys

from xrce.tools.ros_cli.arguments import (EXIT_FAILED, EXIT_INTERRUPTED, PROG, ArgumentParser,
                                          CommandError, UsageError, usage_exit)


# ----------------------------------------------------------------------------- parser

def build_parser():
    from xrce.tools.ros_cli import action, node, param, service, topic

    parser = ArgumentParser(
        prog=PROG,
        description="The ros2 verbs a micro-ROS user needs to see a board, on this venv's rclpy "
                    "(ros2cli's syntax and output; no daemon).")
    groups = parser.add_subparsers(dest="group", metavar="COMMAND", required=True)
    for module in (action, node, param, service, topic):
        group = groups.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        verbs = group.add_subparsers(dest="verb", metavar="VERB", required=True)
        module.add_verbs(verbs)
    return parser


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
    from rclpy.exceptions import NameValidationException

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
    except BrokenPipeError:
        # The reader went away (`xrce-ros topic echo /odom | head`): end quietly, and keep the
        # interpreter's final flush from failing on the same pipe.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_FAILED
