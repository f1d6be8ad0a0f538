"""``xrce-agent``: a command line compatible with eProsima's MicroXRCEAgent.

    xrce-agent udp4 -p 8888 [-d [PORT]] [-m dds|ced] [-r refs.xml] [-v 0..6]
    xrce-agent tcp6 -p 8888
    xrce-agent serial -D /dev/ttyUSB0 [-b 115200] [--crc arc|ccitt]
    xrce-agent multiserial --devs "/dev/ttyUSB0 /dev/ttyUSB1"
    xrce-agent pseudoterminal [-D /tmp/xrce_pty]

The pieces, each readable alone:

- ``arguments``: the parser class (one-line errors) and the option types;
- ``transports``: each transport's options, those every agent takes, the links each opens;
- ``subcommands``: the subcommand table (transports, ``stats``, ``build-interfaces``, ``demo``)
  and the parser built from it;
- ``startup``: the checks after parsing, then the agent's run (``serve``).

Errors in the arguments (a path that cannot be used included) give one ``xrce-agent: error: ...``
line on stderr naming the flag, and exit code 2. The process entry point is
xrce.agent.launcher, which shapes what is imported before this runs.
"""

from xrce.agent.cli.arguments import CliError
from xrce.agent.cli.subcommands import SUBCOMMANDS, build_parser


def main(argv=None):
    import sys

    from xrce.agent.middleware.ros.naming import split_ros_args  # standard library only

    # ``--ros-args ... [--]`` as ROS spells it, taken out first: outside it ``-r`` is ``--refs``.
    argv, ros_args = split_ros_args(sys.argv[1:] if argv is None else argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    args.ros_args = ros_args
    row = SUBCOMMANDS[args.subcommand]
    if row.run is not None:
        if ros_args is not None:
            parser.error("--ros-args names a running agent's entities: not for %s" % args.subcommand)
        return row.run(args)
    from xrce.agent.cli import startup

    try:
        refs = startup.check(args)
    except CliError as exc:
        parser.error(str(exc))
    del parser  # the agent runs for days: not with every subcommand's options kept alive
    return startup.run(args, refs)
