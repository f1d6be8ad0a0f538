"""Start-up and run of the agent once its command line is parsed: the checks that still end in
a bad-argument line (``check``), then ``run``: logging, the ROS environment, the engine, the
links, the banner and the stats signal (SIGUSR1) and the fleet file's reload (SIGHUP), until
SIGINT/SIGTERM.

Once every link is open, one banner line goes to stdout (flushed) — tests wait for it. A port that
cannot be opened gives one line naming it and exit code 1; SIGINT/SIGTERM close the agent cleanly
and exit 0 (as eProsima's agent).
"""

from __future__ import annotations

import asyncio
import errno
import logging
import os
import signal
import sys

from xrce.agent.cli.arguments import PROG, VERBOSITY_LEVELS, CliError
from xrce.agent.cli.event_loop import event_loop
from xrce.agent.cli.subcommands import SUBCOMMANDS
from xrce.agent.cli.transports import IP_SUBCOMMANDS
from xrce.agent.observe import observability


def check(args):
    """What parsing alone cannot check, before anything starts; the refs (``-r``) loaded.
    Raises CliError."""
    if getattr(args, "allow_from", None) and args.subcommand not in IP_SUBCOMMANDS:
        raise CliError("--allow-from needs an IP link (udp4, udp6, tcp4, tcp6), not %s"
                       % args.subcommand)
    check_paths(args)
    args.naming = make_naming(args)
    args.fleet = make_fleet(args)
    event_loop()
    return load_refs(args.refs) if args.refs else None


def make_naming(args):
    """The ``Naming`` of ``--ros-args``, ``--namespace``, ``--domain`` and ``--global-topics``
    (None: none given, so nothing changes). Raises CliError."""
    from xrce.agent.middleware.ros.naming import Naming, NamingError, parse_ros_args

    try:
        namespace, remaps = parse_ros_args(args.ros_args or ())
        if args.namespace is not None:
            if namespace is not None and namespace != args.namespace:
                raise NamingError("--namespace %s and --ros-args __ns:=%s disagree"
                                  % (args.namespace, namespace))
            # A plain option is made absolute, as rcl does a node's relative namespace.
            namespace = args.namespace if args.namespace.startswith("/") else "/" + args.namespace
        global_names = [n.strip() for n in args.global_topics.split(",") if n.strip()]
        for name in global_names:
            if not name.startswith("/"):
                raise NamingError("--global-topics: %r is not an absolute name" % name)
        if namespace is None and not remaps and args.domain is None and \
                getattr(args, "fleet", None) is None:
            return None
        naming = Naming(namespace or "/", remaps, global_names, args.domain)
    except NamingError as exc:
        raise CliError(str(exc)) from None
    if args.middleware == "ced":
        raise CliError("--ros-args, --namespace, --domain and --fleet name ROS entities: they "
                       "need -m dds")
    return naming


def make_fleet(args):
    """The ``Fleet`` of ``--fleet FILE`` over the command line's naming (None without one).
    Raises CliError: one line with the file, the line and the key."""
    path = getattr(args, "fleet", None)
    if path is None:
        return None
    from xrce.agent.middleware.ros.fleet import Fleet, FleetError  # standard library only

    try:
        return Fleet(path, args.naming)
    except FleetError as exc:
        raise CliError(str(exc)) from None


# ----------------------------------------------------------------------------- refs and middleware

def load_refs(path):
    """``{profile_name: xml}`` of a Fast DDS XML profiles file (xrce.agent.engine.xmlrep's
    ``refs_from_profiles``). Raises CliError."""
    import xml.etree.ElementTree as ElementTree  # only with -r: see xrce.agent.engine.xmlrep._parse

    from xrce.agent.engine.xmlrep import refs_from_profiles

    try:
        with open(path, "rb") as profiles:
            document = profiles.read()
    except OSError as exc:
        raise CliError("cannot read refs file %s: %s" % (path, exc.strerror or exc))
    try:
        return refs_from_profiles(document)
    except ElementTree.ParseError as exc:
        raise CliError("refs file %s is not valid XML: %s" % (path, exc))


def check_paths(args):
    """Paths named on the command line, checked before anything starts, so a typo is one line
    naming the flag (exit 2) rather than an errno once the agent is half up, or silence."""
    for directory in getattr(args, "interfaces", ()):
        if not os.path.isdir(directory):
            what = "does not exist" if not os.path.exists(directory) else "is not a directory"
            raise CliError("argument --interfaces: %s %s (give a directory holding interface "
                           "packages, each with its package.xml)" % (directory, what))
    capture = getattr(args, "capture", None)
    if capture:
        parent = os.path.dirname(os.path.abspath(capture))
        if os.path.isdir(capture):
            raise CliError("argument --capture: %s is a directory (give a file name)" % capture)
        if not os.path.isdir(parent):
            raise CliError("argument --capture: directory %s does not exist (create it or "
                           "write the capture elsewhere)" % parent)
        if not os.access(parent, os.W_OK) or (os.path.exists(capture)
                                              and not os.access(capture, os.W_OK)):
            raise CliError("argument --capture: %s is not writable (write the capture "
                           "elsewhere)" % capture)
    stats_port = getattr(args, "stats_port", None)
    if stats_port is not None and not 0 <= stats_port <= 65535:
        raise CliError("argument --stats-port: port %d is not in 0..65535" % stats_port)


def make_middleware(name, linger_s=None, request_timeout_s=None, naming=None, fleet=None):
    # Imported lazily: "ced" must work on machines without ROS, and rclpy is slow to import.
    if name == "ced":
        from xrce.agent.middleware.ced import CedMiddleware
        return CedMiddleware()
    from xrce.agent.middleware.dds.dds_middleware import DdsMiddleware
    from xrce.agent.middleware.ros import REQUEST_TIMEOUT_S
    from xrce.agent.middleware.ros import DOMAIN_LINGER_S
    return DdsMiddleware(park_creation=True,
                         linger_s=DOMAIN_LINGER_S if linger_s is None else linger_s,
                         request_timeout_s=REQUEST_TIMEOUT_S if request_timeout_s is None
                         else request_timeout_s, naming=naming, fleet=fleet)


def _raw_message_type(type_name):
    """The ROS middleware's type lookup by DDS name, for /diagnostics (observe is a floor below the
    middleware: it is handed this). Imported on first use: without rclpy it raises, and the agent
    runs without /diagnostics."""
    from xrce.agent.middleware.ros.raw_types import raw_message_type
    return raw_message_type(type_name)


def configure_logging(verbosity):
    level = VERBOSITY_LEVELS[verbosity]
    logging.basicConfig(level=level, stream=sys.stderr,
                        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s")
    logging.getLogger().setLevel(level)


# ----------------------------------------------------------------------------- running

async def serve(args, refs):
    """Run the agent on the links of ``args.subcommand`` until SIGINT/SIGTERM; the exit code."""
    from xrce.agent.engine.agent import Agent

    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop.set)

    middleware = make_middleware(args.middleware, getattr(args, "domain_linger", None),
                                 getattr(args, "request_timeout", None),
                                 getattr(args, "naming", None), getattr(args, "fleet", None))
    naming, fleet = getattr(args, "naming", None), getattr(args, "fleet", None)
    if naming is not None and naming.describe():
        logging.getLogger("xrce.agent").info("names given to boards: %s", naming.describe())
    if fleet is not None:
        fleet_log = logging.getLogger("xrce.agent.fleet")
        fleet_log.info("%s", fleet.describe())
        for rule in fleet.rules:
            fleet_log.debug("fleet rule %s", rule.describe())
        loop.add_signal_handler(signal.SIGHUP, _reload_fleet, fleet, middleware)
    agent = Agent(middleware, refs=refs, loop=loop,
                  client_dead_time=args.client_dead_time / 1000.0,
                  client_expire_time=args.client_expire_time / 1000.0,
                  max_clients=args.max_clients, max_objects_per_client=args.max_objects,
                  max_reassembly_bytes=args.max_reassembly,
                  max_output_queue_bytes=args.max_output_queue,
                  max_client_bytes=args.max_client_memory, max_total_bytes=args.max_memory)
    from xrce.agent.engine.admission import AdmissionPolicy
    agent.admission = AdmissionPolicy.from_args(args)
    if agent.admission is not None:
        logging.getLogger("xrce.agent.admission").info("admission: %s", agent.admission.describe())
    links = SUBCOMMANDS[args.subcommand].make_links(args, agent)
    started = []
    run_task = None
    observe = None
    try:
        state = open_state(args, agent, links)
    except CliError as exc:
        sys.stderr.write("%s: error: %s\n" % (PROG, exc))
        sys.stderr.flush()
        return 1
    try:
        # The middleware joins no ROS domain at start: each is joined with its first client
        # participant; the default one is prepared (its context, no DDS participant, unless under
        # a discovery server) so a first board finds it ready (xrce.agent.middleware.ros.membership).
        await agent.start()
        if hasattr(middleware, "prepare_default"):
            middleware.prepare_default()
        if state is not None:
            # Before any link opens: a board's first message finds its session restored.
            agent.state = state
            state.start(loop)
            await state.restore()
        run_task = asyncio.ensure_future(agent.run())
        try:
            for link in links:
                await link.start()
                started.append(link)
            if getattr(args, "discovery", None) is not None:  # an IP link's option
                from xrce.agent.links import udp
                discovery = udp.DiscoveryServer(links[0].port, args.discovery,
                                                 family=getattr(links[0], "family", None))
                await discovery.start()
                started.append(discovery)
            observe = observability.Observability.from_args(args, agent, started, middleware,
                                                            raw_message_type=_raw_message_type)
            await observe.start()
        except OSError as exc:
            sys.stderr.write("%s: error: %s\n" % (PROG, _open_error(args, links, started, exc)))
            sys.stderr.flush()
            return 1
        banner = "; ".join(link.describe() for link in started)
        if observe.describe():
            banner += "; " + observe.describe()
        from xrce.agent.cli.addresses import banner_suffix

        sys.stdout.write("%s: %s (middleware %s)%s\n" % (PROG, banner, args.middleware,
                                                         banner_suffix(started)))
        sys.stdout.flush()
        loop.add_signal_handler(signal.SIGUSR1, _print_stats, agent, started)
        stopped = asyncio.ensure_future(stop.wait())
        done, _ = await asyncio.wait({run_task, stopped}, return_when=asyncio.FIRST_COMPLETED)
        if run_task in done and run_task.exception() is not None:
            logging.getLogger("xrce.agent").error("agent stopped: %r", run_task.exception())
            stopped.cancel()
            return 1
        stopped.cancel()
        return 0
    finally:
        if run_task is not None and not run_task.done():
            run_task.cancel()
            try:
                await run_task
            except asyncio.CancelledError:
                pass
        # The engine first, so DELETE-time replies can still go out through the open links.
        await agent.close()
        if observe is not None:  # after the engine, so a capture ends with the DELETE replies
            await observe.close()
        for link in reversed(started):
            await link.close()
        for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGUSR1, signal.SIGHUP):
            loop.remove_signal_handler(signum)


def _reload_fleet(fleet, middleware):
    """SIGHUP: the fleet file again, for the boards created from now on (a bad file: a warning
    and the rules loaded before); the domains it names prepared like the default one."""
    if fleet.reload() and hasattr(middleware, "prepare"):
        middleware.prepare(sorted(fleet.domains()))


def open_state(args, agent, links):
    """The state store's recorder for ``args`` (None with --no-state); CliError when its file
    cannot be opened at all (an unreadable one is moved aside and started clean)."""
    from xrce.agent.cli.transports import state_path

    path = state_path(args)
    if path is None:
        # Debug, not info: without --no-state this is a free port (-p 0) or a pseudoterminal made
        # anew, which a restarted agent does not listen on again, so a store would bring no board
        # back; and a line before the banner would break scripts that read the banner first.
        logging.getLogger("xrce.agent.state").debug(
            "no state store (%s): a restarted agent will not know this one's sessions",
            "--no-state" if getattr(args, "no_state", False) else "no port or device to key "
            "a default by; --state FILE")
        return None
    from xrce.agent.state.recorder import StateRecorder
    from xrce.agent.state.store import StateStore, StoreError

    try:
        store = StateStore(path)
    except StoreError as exc:
        raise CliError("%s (--state FILE elsewhere, or --no-state)" % exc)
    logging.getLogger("xrce.agent.state").debug("state store %s", path)
    return StateRecorder(store, agent, links)


def _open_error(args, links, started, exc):
    """What could not be opened, by flag and port: the errno alone does not say which."""
    # asyncio's servers wrap the errno in their own sentence; the errno's own words are enough.
    reason = os.strerror(exc.errno) if exc.errno else (exc.strerror or str(exc))
    if getattr(exc, "filename", None):  # a file, not a socket
        return "cannot open %s: %s" % (exc.filename, reason)
    pending = [link for link in links if link not in started]
    if pending:
        link = pending[0]
        port = getattr(link, "requested_port", None)
        if port is not None:
            hint = " (another agent there? choose another -p)" if exc.errno == errno.EADDRINUSE else ""
            return "cannot open %s port %d (-p): %s%s" % (link.name, port, reason, hint)
        return "cannot open %s: %s" % (link.describe(), reason)
    if getattr(args, "discovery", None) is not None:
        from xrce.agent.links import udp
        if not any(isinstance(link, udp.DiscoveryServer) for link in started):
            return "cannot open discovery port %d (-d): %s" % (args.discovery, reason)
    if getattr(args, "stats_port", None) is not None:
        return "cannot open stats port %d (--stats-port): %s" % (args.stats_port, reason)
    return reason


def _print_stats(agent, links):
    """SIGUSR1: one ``xrce-agent: stats {json}`` line on stdout with the engine's and every link's
    counters, for scripts and tests watching a running agent."""
    import json

    report = {"engine": agent.stats.as_dict(), "clients": len(agent.clients),
              "links": {link.name: link.stats.as_dict() for link in links}}
    sys.stdout.write("%s: stats %s\n" % (PROG, json.dumps(report, sort_keys=True)))
    sys.stdout.flush()


def run(args, refs):
    """The agent of ``args`` until SIGINT/SIGTERM; the exit code."""
    configure_logging(args.verbose)
    if args.interfaces:  # the build code loads only when there is something to tell it
        from xrce.agent import interfaces
        interfaces.add_search_dirs(args.interfaces)
    if args.middleware == "dds":
        from xrce.agent.interfaces import ros_install as rosenv
        try:  # the one line saying which ROS 2, rclpy and RMW this agent joins
            rosenv.log_ros_in_use(logging.getLogger("xrce.agent.rosenv"))
        except rosenv.RosUnavailable as exc:
            sys.stderr.write("%s: error: %s\n" % (PROG, exc))
            sys.stderr.flush()
            return 1
        from xrce.agent.middleware.ros import fastdds_profile, rclpy_services
        rclpy_services.defer_unused()  # before anything imports rclpy.node
        profile = fastdds_profile.install()  # before any participant: Fast DDS reads it once
        if profile:
            logging.getLogger("xrce.agent.rosenv").debug("Fast DDS participant profile: %s", profile)
    description, loop_factory = event_loop()
    logging.getLogger("xrce.agent").debug("event loop: %s", description)
    try:
        with asyncio.Runner(loop_factory=loop_factory) as runner:
            return runner.run(serve(args, refs))
    except KeyboardInterrupt:  # a second Ctrl-C during shutdown
        return 130
