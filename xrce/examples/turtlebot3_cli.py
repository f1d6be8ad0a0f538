# The command line of the simulated TurtleBot3 firmware (CPython), kept apart from the firmware in
# xrce/examples/turtlebot3.py so that a board loading the firmware does not load this too:
#
#     python -m xrce.examples.turtlebot3 udp4 --agent 127.0.0.1 -p 8888
#     python -m xrce.examples.turtlebot3 serial --dev /dev/pts/5 [-b 115200]
#
# The firmware's main() hands its robot class to main() here instead of this module importing the
# firmware, so the two do not import each other.


def status_line(robot):
    import math

    published = ", ".join("%s %d" % (topic, count) for topic, count in sorted(robot.published.items()))
    return ("turtlebot3: at x=%+.3f m y=%+.3f m yaw=%+.1f deg, moving %.2f m/s %+.2f rad/s; "
            "%d cmd_vel received, fail-safe stopped it %d times; published %s"
            % (robot.x, robot.y, math.degrees(robot.yaw), robot.linear, robot.angular,
               robot.commands_received, robot.failsafe_trips, published or "nothing"))


def _make_transport(args):
    if args.transport == "udp4":
        from xrce.transports.udp import UdpTransport
        return UdpTransport(args.agent, args.port)
    from xrce.transports.serial import SerialTransport
    return SerialTransport(args.dev, args.baudrate)


def main(robot_class, argv=None):
    # robot_class: xrce.examples.turtlebot3.TurtleBot3 (its main() passes it).
    import argparse
    import signal
    import sys
    import time

    class OneLineErrors(argparse.ArgumentParser):
        def error(self, message):  # one line and exit 2, as xrce-agent and xrce-client
            sys.stderr.write("turtlebot3: error: %s\n" % message)
            raise SystemExit(2)

    parser = OneLineErrors(prog="python -m xrce.examples.turtlebot3",
                           description="simulated TurtleBot3 burger firmware")
    sub = parser.add_subparsers(dest="transport", required=True)
    udp = sub.add_parser("udp4", help="reach the agent over UDP/IPv4")
    udp.add_argument("--agent", default="127.0.0.1", help="agent address (default 127.0.0.1)")
    udp.add_argument("-p", "--port", type=int, default=8888, help="agent port (default 8888)")
    serial = sub.add_parser("serial", help="reach the agent over a serial line")
    serial.add_argument("--dev", "-D", required=True, help="serial device")
    serial.add_argument("-b", "--baudrate", type=int, default=115200,
                        help="line speed (default 115200)")
    for child in (udp, serial):
        child.add_argument("--domain", type=int, default=None,
                           help="ROS domain of the node (default: $ROS_DOMAIN_ID or 0)")
        child.add_argument("--cmd-vel-best-effort", action="store_true",
                           help="subscribe /cmd_vel best-effort (default reliable)")
        child.add_argument("--status-period", type=float, default=0.0, metavar="S",
                           help="print a status line every S seconds (0: never)")
        child.add_argument("--connect-attempts", type=int, default=0,
                           help="agent pings before giving up (0: forever)")
        child.add_argument("--ros-extras", action="store_true",
                           help="also serve calibration parameters and the /patrol action")
    args = parser.parse_args(argv)
    import os
    domain = args.domain
    if domain is None:
        try:
            domain = int(os.environ.get("ROS_DOMAIN_ID", "0") or 0)
        except ValueError:
            parser.error("ROS_DOMAIN_ID=%s is not a number (unset it or pass --domain N)"
                         % os.environ["ROS_DOMAIN_ID"])

    # SIGTERM ends the process as Ctrl-C does, at any time: while it waits for an agent or sets
    # up, by raising KeyboardInterrupt there (connect() pings forever by default); once the loop
    # runs, by ending it after the current step, so that no write is cut in half.
    stop = []
    running = []

    def on_sigterm(*_):
        if not running:
            raise KeyboardInterrupt
        stop.append(True)

    signal.signal(signal.SIGTERM, on_sigterm)
    log = lambda text: (sys.stdout.write(text + "\n"), sys.stdout.flush())  # noqa: E731
    try:
        transport = _make_transport(args)
        robot = robot_class(transport, domain_id=domain,
                            cmd_vel_reliable=not args.cmd_vel_best_effort, log=log,
                            ros_extras=args.ros_extras)
    except KeyboardInterrupt:  # stopped before it had anything to log out of
        return 0
    try:
        if robot.connect(attempts=args.connect_attempts) is None:
            log("turtlebot3: no agent answered")
            return 1
        if not robot.setup():
            return 1
        failed = ", ".join(robot.failed_topics) if robot.failed_topics else "none"
        log("turtlebot3: running (node %s, domain %d; topics the agent refused: %s)"
            % (robot.node_name, domain, failed))
        period = args.status_period
        status_due = time.monotonic() if period > 0 else None  # the first line at once
        running.append(True)
        while not stop:
            robot.step()
            now = time.monotonic()
            if status_due is not None and now >= status_due:
                # drift-free: whole periods on; a late loop skips what it missed, never bursts
                status_due += period
                if now >= status_due:
                    status_due = now + period
                log(status_line(robot))
        return 0
    except KeyboardInterrupt:
        return 0
    finally:
        running.append(True)  # a second SIGTERM does not cut the logout short
        try:
            robot.shutdown()
        except Exception:  # the agent may be gone already; the process is ending anyway
            transport.close()
        log(status_line(robot))
