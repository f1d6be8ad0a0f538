"""Client footprint under real MicroPython 1.27 (tests/micropython harness) next to CPython.

    .venv/bin/python bench/micropython/client_footprint.py [--mpy] [--iterations N]

Each step is a piece of MicroPython-compatible source defining ``run(report, argv)``; it runs in a
fresh MicroPython interpreter (so heap deltas are not disturbed by earlier steps) and, when marked
``cpython=True``, also in-process under CPython for comparison. ``report(key, value)`` records a
figure. To add a step (sessions, messages, ...), write its source and append a ``Step`` to STEPS.

Heap figures are live heap, what a board keeps after its garbage collector ran: the WebAssembly
port cannot collect while Python runs, so heap steps are generators run by the harness's stepped
mode, which collects between ``yield``s; ``mpheap.live`` is the heap in use after that collection.
(Plain ``gc.collect(); gc.mem_alloc()`` there counts every byte ever allocated, garbage included.)

--mpy measures the mpy-cross output instead of the .py sources (what a board loading /lib/*.mpy
pays: no compiler on import).
"""

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
import bench.common  # noqa: E402,F401  (the test helpers on sys.path)

from mp_harness import run_micropython  # noqa: E402
from xrce.tools import mpy  # noqa: E402

# Imported in this order so each delta is what the module adds on top of the ones before it: first
# the core every firmware loads (a session over one transport), then each optional feature, then
# the general codec the agent uses (no client module imports it).
LAYERED_IMPORTS = (
    "xrce",  # the package: error types and CPython/MicroPython shims
    "xrce.wire.cdr",
    "xrce.wire.message",
    "xrce.wire.streams",
    "xrce.client",  # xrce.client.session and xrce.client.outbound
    "xrce.transports",
    "xrce.transports.udp",
    "xrce.msgs",
    # optional features (Session methods named in xrce.client.on_demand load it first)
    "xrce.client.recovery",
    "xrce.client.on_demand",  # time sync and ping: the rest of the minimum core
    # set-up and teardown: a board imports these for each call and drops them again, so this is
    # what they cost while a call runs, not what a firmware keeps
    "xrce.client.entities",  # creating and deleting entities, READ_DATA
    "xrce.client.lifecycle",  # constructing, creating, deleting and restoring the session
    "xrce.client.fragments",
    "xrce.client.services",
    "xrce.client.discovery",
    "xrce.client.ping",
    "xrce.transports.custom",
    "xrce.transports.crc",
    "xrce.transports.framing",
    "xrce.transports.serial",
    "xrce.transports.tcp",
    # the general codec (agent side)
    "xrce.wire.constants",
    "xrce.wire.objects",
    "xrce.wire.submessages",
)
# Message classes load lazily, one module per type: their cost is measured per type.
MESSAGE_TYPES = (
    "std_msgs.String",
    "geometry_msgs.Twist",
    "sensor_msgs.Imu",
    "sensor_msgs.LaserScan",
    "nav_msgs.Odometry",
    "tf2_msgs.TFMessage",
)


class Step:
    __slots__ = ("name", "source", "cpython", "argv", "stepped")

    def __init__(self, name, source, cpython=False, argv=(), stepped=False):
        self.name = name
        self.source = source
        self.cpython = cpython
        self.argv = tuple(str(arg) for arg in argv)
        self.stepped = stepped  # source defines a generator run(report, argv): live heap via mpheap


IMPORTS_SOURCE = r"""
import mpheap

def run(report, argv):
    yield
    start = mpheap.live
    for name in argv:
        before = mpheap.live
        try:
            __import__(name)
        except ImportError as error:
            report(name, "skipped (%s)" % error)
            yield
            continue
        yield
        report(name, mpheap.live - before)
    report("total heap after imports", mpheap.live - start)
"""

MESSAGE_TYPES_SOURCE = r"""
import mpheap

def run(report, argv):
    yield
    for spec in argv:
        package, type_name = spec.split(".")
        before = mpheap.live
        try:
            module = __import__("xrce.msgs." + package, None, None, (type_name,))
            getattr(module, type_name)
        except (ImportError, AttributeError) as error:
            report(spec, "skipped (%s)" % error)
            yield
            continue
        module = None
        yield
        report(spec, mpheap.live - before)
"""

CDR_TWIST_SOURCE = r"""
import gc
from xrce.wire.cdr import CdrReader, CdrWriter
try:
    from time import ticks_us, ticks_diff
except ImportError:
    from time import perf_counter_ns as _ns
    def ticks_us():
        return _ns() // 1000
    def ticks_diff(a, b):
        return a - b

def run(report, argv):
    iterations = int(argv[0])
    twist = (0.5, 0.0, 0.0, 0.0, 0.0, -1.25)  # linear xyz, angular xyz
    writer = CdrWriter(bytearray(64))
    start = ticks_us()
    for _ in range(iterations):
        writer.reset()
        for value in twist:
            writer.f64(value)
    encode_us = ticks_diff(ticks_us(), start)
    body = bytes(writer.buf[: writer.pos])
    assert len(body) == 48
    start = ticks_us()
    for _ in range(iterations):
        reader = CdrReader(body)
        decoded = (reader.f64(), reader.f64(), reader.f64(), reader.f64(), reader.f64(), reader.f64())
    decode_us = ticks_diff(ticks_us(), start)
    assert decoded == twist
    report("encode us/op", encode_us / iterations)
    report("decode us/op", decode_us / iterations)
    gc.collect()
    before = gc.mem_alloc()
    writer.reset()
    for value in twist:
        writer.f64(value)
    report("heap bytes per encode (preallocated writer)", gc.mem_alloc() - before)
"""

SESSION_SOURCE = r"""
import mpheap

class _NullTransport:
    # The heap figure is the client's, not a socket's: a board's UDP socket lives in its network stack.
    mtu = 512
    def send(self, data):
        return True
    def recv(self, timeout_ms):
        return None
    def close(self):
        pass

def run(report, argv):
    yield
    start = mpheap.live
    from xrce.client.session import Session
    yield
    from xrce.msgs.std_msgs import String
    yield
    from xrce.msgs.geometry_msgs import Twist
    yield
    imported = mpheap.live
    report("import: session + String + Twist", imported - start)
    session = Session(_NullTransport(), key=b"\x01\x02\x03\x04")
    node = session.create_participant(name="footprint")
    writer = session.create_writer(node, "/chatter", String, reliable=False)
    session.create_reader(node, "/cmd_vel", Twist, lambda message: None)
    session.flush()
    session.write(writer, String(data="hello"), stream_id=session.best_effort)
    session.flush()
    yield
    report("session + 1 publisher + 1 subscriber (runtime objects)", mpheap.live - imported)
    report("TOTAL import + session + publisher + subscriber", mpheap.live - start)
    # The rest of the issue's minimum core loads on first use (xrce.client.on_demand; deleting goes
    # through xrce.client.entities, loaded for the call): a firmware that syncs time, pings and
    # deletes an entity pays this figure, not the one above.
    session.sync_time(timeout_ms=0)
    session.ping(timeout_ms=0)
    session.delete_entity(writer)
    session.flush()
    yield
    report("TOTAL with time sync, ping and delete used", mpheap.live - start)
"""

# Parameters and actions load only when a firmware makes a parameter server or an action
# server/client: what each adds on top of a session with one publisher and one subscriber (the
# headline above, which neither changes).
FEATURE_SESSION = r"""
import mpheap

class _NullTransport:
    mtu = 512
    def send(self, data):
        return True
    def recv(self, timeout_ms):
        return None
    def close(self):
        pass

def _session():
    from xrce.client.session import Session
    from xrce.msgs.std_msgs import String
    from xrce.msgs.geometry_msgs import Twist
    session = Session(_NullTransport(), key=b"\x01\x02\x03\x04")
    node = session.create_participant(name="footprint")
    session.create_writer(node, "/chatter", String, reliable=False)
    session.create_reader(node, "/cmd_vel", Twist, lambda message: None)
    session.flush()
    return session, node
"""

PARAMETERS_SOURCE = FEATURE_SESSION + r"""
def run(report, argv):
    yield
    session, node = _session()
    yield
    start = mpheap.live
    import xrce.client.parameters
    yield
    imported = mpheap.live
    report("import xrce.client.parameters (+ rcl_interfaces package)", imported - start)
    params = xrce.client.parameters.ParameterServer(session, node, "/footprint")
    params.declare("motor_kp", 120, min_value=0, max_value=1000)
    params.declare("wheel_radius", 0.033)
    params.declare("use_imu", True)
    params.declare("robot_name", "tb3")
    session.flush()
    yield
    report("server: 6 services, /parameter_events, 4 parameters (types + objects)", mpheap.live - imported)
    # One request served: the set path and the event it publishes (plans of the types it encodes).
    from xrce.msgs import rcl_interfaces
    callback = session._readers[params.repliers[2]][0]
    request = rcl_interfaces.SetParameters.Request(parameters=[rcl_interfaces.Parameter(
        name="motor_kp", value=rcl_interfaces.ParameterValue(type=2, integer_value=150))])
    callback(bytes(24), request)
    request = None
    session.flush()
    yield
    report("TOTAL parameter server after serving a set", mpheap.live - start)
"""

ACTIONS_SOURCE = FEATURE_SESSION + r"""
def run(report, argv):
    yield
    session, node = _session()
    yield
    start = mpheap.live
    import xrce.client.actions
    yield
    imported = mpheap.live
    report("import xrce.client.actions (+ the action_msgs package)", imported - start)
    from xrce.msgs.test_msgs import Fibonacci
    yield
    typed = mpheap.live
    report("test_msgs/action/Fibonacci (its 8 types, 3 descriptors)", typed - imported)
    server = xrce.client.actions.ActionServer(session, node, "/fibonacci", Fibonacci,
                                              lambda goal: True, max_goals=2)
    session.flush()
    yield
    served = mpheap.live
    report("action server, 2 goals at most (entities + objects)", served - typed)
    # One goal accepted, one feedback: the send-goal, status and feedback paths.
    request = Fibonacci.SendGoal.Request()
    request.goal_id.uuid = bytes(range(16))
    request.goal.order = 5
    session._readers[server.send_goal_replier][0](bytes(24), request)
    request = None
    server.active()[0].publish_feedback(Fibonacci.Feedback(sequence=[0, 1, 1]))
    session.flush()
    yield
    executing = mpheap.live
    report("server with one goal executing", executing - served)
    client = xrce.client.actions.ActionClient(session, node, "/fibonacci_peer", Fibonacci, max_goals=2)
    session.flush()
    yield
    report("action client, 2 goals at most (entities + objects)", mpheap.live - executing)
    report("TOTAL actions (server with a goal + client)", mpheap.live - start)
"""

MESSAGES_SOURCE = r"""
import gc
from xrce.wire.cdr import CdrWriter
from xrce.msgs.geometry_msgs import Point, Pose, Quaternion, Twist, TwistWithCovariance, Vector3
from xrce.msgs.nav_msgs import Odometry
from xrce.msgs.sensor_msgs import Imu
from xrce.msgs.std_msgs import Header
from xrce.msgs.turtlebot3_msgs import SensorState
try:
    from time import ticks_us, ticks_diff
except ImportError:
    from time import perf_counter_ns as _ns
    def ticks_us():
        return _ns() // 1000
    def ticks_diff(a, b):
        return a - b

def _time(report, name, message, iterations):
    # The best of five batches: other processes on the machine only ever make a batch slower.
    cls = type(message)
    batch = max(1, iterations // 5)
    encode = decode = None
    for _ in range(5):
        start = ticks_us()
        for _ in range(batch):
            data = message.to_bytes()
        took = ticks_diff(ticks_us(), start)
        encode = took if encode is None or took < encode else encode
        start = ticks_us()
        for _ in range(batch):
            decoded = cls.from_bytes(data)
        took = ticks_diff(ticks_us(), start)
        decode = took if decode is None or took < decode else decode
    assert decoded == message
    iterations = batch
    report("%s encode us/op" % name, encode / iterations)
    report("%s decode us/op" % name, decode / iterations)
    report("%s encode+decode us/op" % name, (encode + decode) / iterations)
    # What encoding into a session's preallocated writer leaves behind (MicroPython: the harness
    # cannot collect while Python runs, so garbage shows here too).
    if not hasattr(gc, "mem_alloc"):
        return  # CPython
    writer = CdrWriter(bytearray(1024))
    message.encode(writer)
    label = "%s heap bytes per encode (preallocated writer)" % name
    gc.collect()
    before = gc.mem_alloc()
    writer.reset()
    message.encode(writer)
    allocated = gc.mem_alloc() - before
    report(label, allocated)

def run(report, argv):
    iterations = int(argv[0])
    _time(report, "Twist", Twist(linear=Vector3(x=0.5), angular=Vector3(z=-1.25)), iterations)
    state = SensorState(bumper=1, cliff=0.5, sonar=1.5, illumination=2.0, led=3, button=1,
                        torque=True, left_encoder=1234, right_encoder=-1234, battery=12.5)
    _time(report, "SensorState", state, iterations)
    header = Header(frame_id="base_link")
    header.stamp.sec = 1700000000
    header.stamp.nanosec = 250000000
    covariance = [0.01 * i for i in range(9)]
    imu = Imu(header=header, orientation=Quaternion(0.0, 0.0, 0.38, 0.92), orientation_covariance=covariance,
              angular_velocity=Vector3(0.0, 0.0, 0.5), angular_velocity_covariance=covariance,
              linear_acceleration=Vector3(0.1, 0.0, 9.81), linear_acceleration_covariance=covariance)
    _time(report, "Imu", imu, iterations)
    odometry = Odometry(header=header, child_frame_id="base_footprint")
    odometry.pose.pose = Pose(Point(1.0, 2.0, 0.0), Quaternion(0.0, 0.0, 0.38, 0.92))
    odometry.pose.covariance = [0.001 * i for i in range(36)]
    odometry.twist = TwistWithCovariance(Twist(Vector3(0.2, 0.0, 0.0), Vector3(0.0, 0.0, 0.1)),
                                         [0.002 * i for i in range(36)])
    _time(report, "Odometry", odometry, iterations)
"""

RUNNER_TAIL = r"""
import sys
def _report(key, value):
    print("REPORT\t%s\t%s" % (key, value))
run(_report, sys.argv[1:])
"""

STEPPED_RUNNER_TAIL = r"""
import sys
def _report(key, value):
    print("REPORT\t%s\t%s" % (key, value))
def main():
    return run(_report, sys.argv[1:])
"""


def _is_message_module(name):
    return name.startswith("xrce.msgs.") and name != "xrce.msgs._dict" and name != "xrce.msgs._lookup"


def build_steps(iterations):
    names = list(LAYERED_IMPORTS)
    for relative in mpy.client_files():
        name = relative[: -len(".py")].replace("/", ".")
        name = name[: -len(".__init__")] if name.endswith(".__init__") else name
        if name not in names and name != "xrce" and not _is_message_module(name):
            names.append(name)
    return [
        Step("imports", IMPORTS_SOURCE, argv=names, stepped=True),
        # Each type in a fresh interpreter on top of the wire core would be purer; cumulative is
        # what an application importing them in this order pays.
        Step("message_types", MESSAGE_TYPES_SOURCE, argv=MESSAGE_TYPES, stepped=True),
        Step("cdr_twist", CDR_TWIST_SOURCE, cpython=True, argv=[iterations]),
        Step("client_session", SESSION_SOURCE, stepped=True),
        Step("messages", MESSAGES_SOURCE, cpython=True, argv=[iterations]),
        Step("parameters", PARAMETERS_SOURCE, stepped=True),
        Step("actions", ACTIONS_SOURCE, stepped=True),
    ]


def run_on_micropython(step, mounts, default_mount):
    tail = STEPPED_RUNNER_TAIL if step.stepped else RUNNER_TAIL
    # The stepped steps run with a real heap cap: 1 MiB is far above what they need.
    result = run_micropython(step.source + tail, *step.argv, mounts=mounts, default_mount=default_mount,
                             timeout=300, stepped=step.stepped, heap=1024 * 1024)
    if result.returncode != 0:
        raise SystemExit("step %s failed under MicroPython:\n%s%s" % (step.name, result.stdout, result.stderr))
    figures = []
    for line in result.stdout.splitlines():
        if line.startswith("REPORT\t"):
            _, key, value = line.split("\t", 2)
            figures.append((key, value))
    return figures


def run_on_cpython(step):
    figures = []
    namespace = {"__name__": "bench_step_" + step.name}
    exec(compile(step.source, "<step %s>" % step.name, "exec"), namespace)
    # CPython has no gc.mem_alloc: heap figures are MicroPython-only.
    try:
        namespace["run"](lambda key, value: figures.append((key, str(value))), list(step.argv))
    except AttributeError as error:
        if "mem_alloc" not in str(error):
            raise
    return figures


def _format(value):
    try:
        number = float(value)
    except ValueError:
        return value
    return "%d" % number if number == int(number) else "%.2f" % number


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mpy", action="store_true", help="measure mpy-cross output instead of .py")
    parser.add_argument("--iterations", type=int, default=1000)
    parser.add_argument("--steps", default="", help="comma-separated step names to run (default: all)")
    options = parser.parse_args(argv)
    wanted = [name for name in options.steps.split(",") if name]
    with tempfile.TemporaryDirectory(prefix="xrce-mpy-") as outdir:
        built = mpy.build_mpy(outdir)
        core = [p for p in built if "/msgs/" not in str(p).replace("\\", "/")]
        print("client .mpy: %d files, %d bytes (wire core, client, transports: %d files, %d bytes)" % (
            len(built), sum(p.stat().st_size for p in built), len(core), sum(p.stat().st_size for p in core)))
        if options.mpy:
            mounts, default_mount = [(outdir, "/lib")], False
        else:
            mounts, default_mount = [], True
        print("MicroPython 1.27 (WebAssembly, Node) loading %s; CPython %s" % (
            ".mpy" if options.mpy else ".py", sys.version.split()[0]))
        for step in build_steps(options.iterations):
            if wanted and step.name not in wanted:
                continue
            micro = run_on_micropython(step, mounts, default_mount)
            cpython = dict(run_on_cpython(step)) if step.cpython else {}
            print("\n[%s]" % step.name)
            width = max(len(key) for key, _ in micro)
            header = "  %-*s  %14s" % (width, "", "MicroPython")
            print(header + ("  %14s" % "CPython" if cpython else ""))
            for key, value in micro:
                line = "  %-*s  %14s" % (width, key, _format(value))
                if cpython:
                    line += "  %14s" % _format(cpython.get(key, "-"))
                print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
