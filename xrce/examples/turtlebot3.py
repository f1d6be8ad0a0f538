# A simulated TurtleBot3 (burger) firmware on the XRCE client, written the way MCU firmware is.
#
# One loop, no threads: wait for input a few milliseconds at a time, integrate the wheels, publish
# whatever is due. It runs unchanged under MicroPython (give it any transport object) and under
# CPython::
#
#     python -m xrce.examples.turtlebot3 udp4 --agent 127.0.0.1 -p 8888
#     python -m xrce.examples.turtlebot3 serial --dev /dev/pts/5 [-b 115200]
#
# Node ``turtlebot3_node``. Publishes ``/sensor_state`` (turtlebot3_msgs/SensorState),
# ``/imu``, ``/battery_state``, ``/odom`` and ``/tf`` (odom → base_footprint), every header stamped
# with the agent's clock (``Session.epoch_ns`` after ``sync_time``, repeated periodically).
# Subscribes ``/cmd_vel``: commands drive a differential-drive model whose wheel speeds give the
# encoder counts and the odometry; without a command for ``failsafe_ms`` the wheels stop.
#
# Topic QoS follows what ROS 2 subscribers of each topic expect, because a best-effort writer never
# matches a reliable reader: sensor streams (sensor_state, imu, battery_state) are best-effort,
# ``/odom`` and ``/tf`` reliable. ``/odom`` is larger than one 512-byte message and is fragmented,
# which only the reliable stream can do.
#
# One module on purpose, though past the ~500 lines the project splits files at: its command line
# (turtlebot3_cli) and ROS extras (turtlebot3_extras) are apart already, and moving the robot's
# motion model and messages into a module of their own (a base class) measured 480 bytes more live
# heap after construction from .mpy on MicroPython's 32-bit unix port (192 from .py): the second
# module's object, globals and names, with nothing saved in return.

import gc
import math
import sys

from xrce import IS_MICROPYTHON, const, ticks_add, ticks_diff, ticks_ms
from xrce.wire.cdr import CdrWriter
from xrce.client.session import Session, ping_agent
from xrce.msgs.geometry_msgs import TransformStamped, Twist
from xrce.msgs.nav_msgs import Odometry
from xrce.msgs.sensor_msgs import BatteryState, Imu
from xrce.msgs.tf2_msgs import TFMessage
from xrce.msgs.turtlebot3_msgs import SensorState

NODE_NAME = "turtlebot3_node"

# Constants through micropython.const with a leading underscore: the compiler folds them into the
# code that uses them, so a board keeps no global, no name and no float object for each (~30 bytes
# apiece).

# TurtleBot3 burger geometry and limits (ROBOTIS e-Manual).
_WHEEL_RADIUS = const(0.033)
_WHEEL_SEPARATION = const(0.160)
_MAX_LINEAR_VELOCITY = const(0.22)
_MAX_ANGULAR_VELOCITY = const(2.84)
ENCODER_TICKS_PER_REV = const(4096)  # DYNAMIXEL XL430 position resolution
_TWO_PI = const(6.283185307179586)

_BATTERY_FULL_V = const(12.4)  # 3S LiPo, 1800 mAh
_BATTERY_EMPTY_V = const(10.5)
_BATTERY_CAPACITY_AH = const(1.8)
_GRAVITY = const(9.80665)
# sensor_msgs/BatteryState constants: on a board the class has them only after
# xrce.msgs.constants.load_constants(BatteryState), which would intern all 23 names for these three.
_POWER_SUPPLY_STATUS_DISCHARGING = const(2)
_POWER_SUPPLY_HEALTH_GOOD = const(1)
_POWER_SUPPLY_TECHNOLOGY_LIPO = const(3)

# The serialized size of the largest sample (/odom: fixed frame ids, no sequences that grow), which
# sizes the session's buffers before anything else is allocated; tests/turtlebot3/test_turtlebot3.py checks it.
LARGEST_SAMPLE = const(720)
TIME_SYNC_PERIOD_MS = const(10000)
FAILSAFE_MS = const(500)
_PHASE_STEP_MS = const(17)  # offset between the topics' periods (ms)
_MAX_WAIT_MS = const(5)  # the loop's longest sleep: bounds fail-safe and schedule jitter
_MAX_MESSAGES_PER_STEP = const(16)  # drain a burst of input, but keep publishing on time

_NS_PER_S = const(1000000000)
_GC_THRESHOLD = const(4096)
_STATUS_OK = const(0x00)  # the XRCE STATUS values (xrce.wire.constants)
_STATUS_OK_MATCHED = const(0x01)
_STATUS_NONE = const(0xFF)  # not answered yet


def _clamp(value, limit):
    if value > limit:
        return limit
    if value < -limit:
        return -limit
    return value


def _set_stamp(header, ns):
    header.stamp.sec = ns // _NS_PER_S
    header.stamp.nanosec = ns % _NS_PER_S


def _set_yaw(quaternion, yaw):
    quaternion.x = 0.0
    quaternion.y = 0.0
    quaternion.z = math.sin(yaw * 0.5)
    quaternion.w = math.cos(yaw * 0.5)


def _collect():
    # On a board, collect the garbage now, and from now on every _GC_THRESHOLD bytes allocated
    # rather than only once an allocation fails: what is kept for good (set-up's objects) and what
    # the loop allocates (its floats, a message's new values, a datagram received) then stay in the
    # free space nearest what is already kept, and the rest of the heap stays in one piece for a
    # datagram's block. Filled to the top before each collection, the heap was cut into pieces
    # too small for a 513-byte datagram with 20 KB free (issue 32).
    # (Not on the WebAssembly port, whose collector cannot run while Python code does: it
    # collects when the host's call into Python returns, and grows the heap meanwhile.)
    if IS_MICROPYTHON and sys.platform != "webassembly":
        gc.collect()
        gc.threshold(_GC_THRESHOLD)


class _Periodic:
    # A drift-free period: the next deadline advances by whole periods, not from 'now'. (No
    # __slots__: MicroPython ignores them and would keep the tuple of names.)

    def __init__(self, period_ms, now):
        self.period_ms = period_ms
        self.due = now

    def take(self, now):
        # True once per elapsed period; a late loop catches up by skipping, never by bursting.
        if ticks_diff(now, self.due) < 0:
            return False
        self.due = ticks_add(self.due, self.period_ms)
        if ticks_diff(now, self.due) >= 0:
            self.due = ticks_add(now, self.period_ms)
        return True

    def remaining(self, now):
        return ticks_diff(self.due, now)


class TurtleBot3:
    # The robot: ``connect()``, ``setup()``, then ``step()`` in a loop (or ``run()``).
    #
    # Counters for observers and tests: ``commands_received``, ``last_command`` ((linear.x,
    # angular.z) as received), ``failsafe_trips``, ``published`` (topic → samples written),
    # ``failed_topics`` (topics the agent refused), ``time_syncs``; the state: ``x``, ``y``, ``yaw``,
    # ``linear``, ``angular`` (the velocities being driven), ``left_ticks``, ``right_ticks``.

    def __init__(self, transport, domain_id=0, node_name=NODE_NAME, cmd_vel_reliable=True,
                 periods_ms=None, failsafe_ms=FAILSAFE_MS, time_sync_period_ms=TIME_SYNC_PERIOD_MS,
                 key=None, log=print, ros_extras=False):
        # ``ros_extras``: calibration parameters and the /patrol action as well
        # (xrce.examples.turtlebot3_extras, loaded only then).
        self.transport = transport
        self.domain_id = domain_id
        self.node_name = node_name
        self.cmd_vel_reliable = cmd_vel_reliable
        # /sensor_state at 10 Hz as the OpenCR firmware; odom and tf at the rate a navigation stack
        # expects; the battery changes slowly.
        self.periods_ms = {"sensor_state": 100, "imu": 100, "odom": 100, "tf": 100, "battery_state": 1000}
        if periods_ms:
            self.periods_ms.update(periods_ms)
        self.failsafe_ms = failsafe_ms
        self.time_sync_period_ms = time_sync_period_ms
        self.log = log
        _collect()  # the imports' garbage (loading .mpy code), before anything the robot keeps
        # The session's buffers first, while the heap is in one piece: blocks a board keeps for
        # good, sized for the largest sample (/odom: fragmented), so that no sample grows one in
        # the loop (on a board: a 1 KB block in one piece, when the heap is the most cut up).
        # History 4: /odom (two fragments) and /tf at 10 Hz wait about a heartbeat period (100 ms)
        # for the agent's acknowledgement; each slot is a message buffer.
        self.session = Session(transport, key=key, history=4, largest_sample=LARGEST_SAMPLE)

        self.commands_received = 0
        self.last_command = None
        self.failsafe_trips = 0
        self.time_syncs = 0
        self.published = {}
        self.failed_topics = []
        self.ros_extras = ros_extras
        self.extras = None
        self._writers = {}
        self._schedule = []
        self._sync_timer = None

        self.x = 0.0
        self.y = 0.0
        self.yaw = 0.0
        self.linear = 0.0
        self.angular = 0.0
        self.left_angle = 0.0  # wheel angles (rad) since start; the encoders count them
        self.right_angle = 0.0
        self.left_ticks = 0
        self.right_ticks = 0
        self.battery_voltage = _BATTERY_FULL_V
        self._last_command_ms = None
        self._last_motion_ms = None

        # One instance of each message, refilled in place: no allocation per sample.
        self._sensor_state = SensorState()
        self._sensor_state.torque = True
        self._imu = Imu()
        self._imu.header.frame_id = "imu_link"
        self._imu.linear_acceleration.z = _GRAVITY
        self._battery = BatteryState()
        self._battery.design_capacity = _BATTERY_CAPACITY_AH
        self._battery.power_supply_status = _POWER_SUPPLY_STATUS_DISCHARGING
        self._battery.power_supply_health = _POWER_SUPPLY_HEALTH_GOOD
        self._battery.power_supply_technology = _POWER_SUPPLY_TECHNOLOGY_LIPO
        self._battery.present = True
        self._odom = Odometry()
        self._odom.header.frame_id = "odom"
        self._odom.child_frame_id = "base_footprint"
        self._transform = TransformStamped()
        self._transform.header.frame_id = "odom"
        self._transform.child_frame_id = "base_footprint"
        self._tf = TFMessage(transforms=[self._transform])

    # ------------------------------------------------------------------ start-up

    def connect(self, timeout_ms=1000, attempts=0):
        # Ping the agent until it answers (``attempts`` 0: forever, as the OpenCR firmware).
        # Returns the round-trip time in µs, or None when the attempts ran out.
        tried = 0
        while attempts <= 0 or tried < attempts:
            rtt = ping_agent(self.transport, timeout_ms, 1)
            if rtt is not None:
                return rtt
            tried += 1
            if tried == 1 or tried % 10 == 0:
                self.log("turtlebot3: waiting for the agent (%d pings unanswered)" % tried)
        return None

    def setup(self, timeout_ms=5000):
        # Session, clock, node, publishers and the /cmd_vel subscription. Topics the agent refuses
        # (e.g. a message package it cannot load) are logged and left out; the robot runs without
        # them. Returns False if the session or node could not be created.
        ok = False
        for ok in self.setup_stages(timeout_ms):
            pass
        return ok

    def setup_stages(self, timeout_ms=5000):
        # ``setup`` one exchange with the agent at a time, for a firmware loop that does other work
        # (or collects its garbage) in between: yields None after each stage, then True or False.
        # A type's first encode builds its plan, which the message runtime then keeps: built here,
        # one type per stage, the loop's first passes neither wait for it nor carry what building
        # it allocates (on a board: up to ~5 KB for Odometry) on top of the settled heap. Into the
        # session's buffer for a sample too large for a message (to_bytes would grow a writer per
        # sample and copy each out); the largest must fit the buffers LARGEST_SAMPLE sized.
        session = self.session
        writer = CdrWriter(session._outputs[session.reliable].big or bytearray(64))
        largest = 0
        for sample in (self._sensor_state, self._imu, self._battery, self._odom, self._tf):
            writer.reset()
            sample.encode(writer)
            if writer.pos > largest:
                largest = writer.pos
            yield
        writer = None
        if largest > LARGEST_SAMPLE:
            session.size_output_buffers(largest)  # a sample grown past what was planned for
        if not session.create(attempts=10, timeout_ms=1000):
            self.log("turtlebot3: the agent refused the session (status %r)" % (session.create_status,))
            yield False
            return
        yield
        self.sync_clock()
        yield
        # Creating entities buffers their requests, waiting for their STATUS is the exchange: a
        # stage each, so that neither carries the other's garbage. On a board the creation code
        # (xrce.client.entities) is loaded once here and kept until the last entity, instead of
        # being loaded, and left as ~5 KB of garbage, by each call.
        session.hold_set_up()
        node = session.create_participant(domain_id=self.domain_id, name=self.node_name)
        yield
        if not (yield from self._statuses(timeout_ms)):
            self.log("turtlebot3: node not created: %r" % (session.last_statuses,))
            session.hold_set_up(False)
            yield False
            return
        yield
        # The /cmd_vel subscription first: commands can flow while the publishers are being
        # created, and its creation, the largest of set-up (a reader is also a READ_DATA), runs
        # before the others have added to the heap.
        session.create_reader(node, "/cmd_vel", Twist, self._on_cmd_vel,
                              reliable=self.cmd_vel_reliable, depth=10)
        yield
        if not (yield from self._statuses(timeout_ms)):
            self.log("turtlebot3: /cmd_vel subscription failed: %r" % (session.last_statuses,))
            self.failed_topics.append("cmd_vel")
        yield
        yield from self._add_writer(node, "sensor_state", "/sensor_state", SensorState, False, timeout_ms)
        yield from self._add_writer(node, "imu", "/imu", Imu, False, timeout_ms)
        yield from self._add_writer(node, "battery_state", "/battery_state", BatteryState, False, timeout_ms)
        yield from self._add_writer(node, "odom", "/odom", Odometry, True, timeout_ms)
        yield from self._add_writer(node, "tf", "/tf", TFMessage, True, timeout_ms)
        if self.ros_extras:
            from xrce.examples.turtlebot3_extras import RobotExtras

            self.extras = RobotExtras(self, node)
            yield
            if not (yield from self._statuses(timeout_ms)):
                self.failed_topics.append("parameters/patrol")
        session.hold_set_up(False)
        yield
        _collect()
        now = ticks_ms()
        self._last_motion_ms = now
        self._sync_timer = _Periodic(self.time_sync_period_ms, ticks_add(now, self.time_sync_period_ms))
        self._schedule = []
        # Staggered phases, like separate firmware timers: samples due at the same instant would
        # queue behind each other (and behind /odom's fragments) on the link and in the agent.
        for index, topic in enumerate(self._writers):
            self._schedule.append((topic, _Periodic(self.periods_ms[topic],
                                                    ticks_add(now, index * _PHASE_STEP_MS))))
        yield True

    def _statuses(self, timeout_ms):
        # ``session.run_until_all_status(timeout_ms)`` as stages of ``setup_stages``, one message
        # taken in per stage, as ``step_stages`` takes them: whatever arrives meanwhile (commands
        # on /cmd_vel once subscribed, acknowledgements, heartbeats) then leaves its garbage in a
        # stage of its own, for a board's collector or the harness's, instead of all of it in one
        # (on a board each datagram received is also a new block, xrce/transports/udp.py).
        # Its value (``yield from``): True if every request was answered OK.
        session = self.session
        start = ticks_ms()
        ok = True
        while True:
            if session.run_until_all_status(0):
                return ok
            pending = False
            statuses = session.last_statuses
            for rid in statuses:  # a status answered now is collected: note the ones that failed
                if statuses[rid] == _STATUS_NONE:
                    pending = True
                elif statuses[rid] != _STATUS_OK and statuses[rid] != _STATUS_OK_MATCHED:
                    ok = False
            if not pending:
                return ok
            remaining = timeout_ms - ticks_diff(ticks_ms(), start)
            if remaining <= 0:
                return False
            # Never longer than the heartbeat period: the session's waits send heartbeats on time.
            session.spin_once(remaining if remaining < session.heartbeat_ms else session.heartbeat_ms)
            yield

    def _add_writer(self, node, topic, ros_name, msg_class, reliable, timeout_ms):
        # Stages of ``setup_stages``: the creation, then the exchange.
        session = self.session
        writer = session.create_writer(node, ros_name, msg_class, reliable=reliable, depth=10)
        yield
        if (yield from self._statuses(timeout_ms)):
            stream = session.reliable if reliable else session.best_effort
            self._writers[topic] = (writer, stream)
            self.published[topic] = 0
        else:
            self.failed_topics.append(topic)
            self.log("turtlebot3: %s not created (%s): %r" % (ros_name, msg_class.TYPE_NAME,
                                                               session.last_statuses))
        yield

    def sync_clock(self):
        if self.session.sync_time(timeout_ms=200, attempts=3):
            self.time_syncs += 1
            return True
        self.log("turtlebot3: time sync unanswered")
        return False

    # ------------------------------------------------------------------ commands and motion

    def _on_cmd_vel(self, twist):
        self._move(ticks_ms())  # integrate up to now with the previous velocities first
        self.commands_received += 1
        self.last_command = (twist.linear.x, twist.angular.z)
        self.linear = _clamp(twist.linear.x, _MAX_LINEAR_VELOCITY)
        self.angular = _clamp(twist.angular.z, _MAX_ANGULAR_VELOCITY)
        self._last_command_ms = ticks_ms()

    def _move(self, now):
        # Integrate the differential drive from the last update to ``now``.
        last = self._last_motion_ms
        self._last_motion_ms = now
        if last is None:
            return
        dt = ticks_diff(now, last) * 0.001
        if dt <= 0.0:
            return
        # The wheels turn at the speeds the command asks for; pose and encoders follow from them.
        half_track = self.angular * _WHEEL_SEPARATION * 0.5
        left_speed = self.linear - half_track
        right_speed = self.linear + half_track
        radius = _WHEEL_RADIUS if self.extras is None else self.extras.wheel_radius  # a parameter
        self.left_angle += left_speed * dt / radius
        self.right_angle += right_speed * dt / radius
        self.left_ticks = int(self.left_angle * ENCODER_TICKS_PER_REV / _TWO_PI)
        self.right_ticks = int(self.right_angle * ENCODER_TICKS_PER_REV / _TWO_PI)
        linear = (left_speed + right_speed) * 0.5
        angular = (right_speed - left_speed) / _WHEEL_SEPARATION
        heading = self.yaw + angular * dt * 0.5  # midpoint heading: exact for straight lines and
        self.x += linear * dt * math.cos(heading)  # second-order accurate on arcs
        self.y += linear * dt * math.sin(heading)
        yaw = self.yaw + angular * dt
        self.yaw = math.atan2(math.sin(yaw), math.cos(yaw))
        # A burger draws about 1 A driving: the voltage sags linearly with the charge used.
        used = (0.3 + 0.7 * (abs(linear) / _MAX_LINEAR_VELOCITY)) * dt / 3600.0 / _BATTERY_CAPACITY_AH
        self.battery_voltage -= used * (_BATTERY_FULL_V - _BATTERY_EMPTY_V)
        if self.battery_voltage < _BATTERY_EMPTY_V:
            self.battery_voltage = _BATTERY_EMPTY_V

    def _check_failsafe(self, now):
        last = self._last_command_ms
        if last is not None and ticks_diff(now, last) > self.failsafe_ms:
            self._move(now)  # up to now at the commanded speeds, from now on standing
            self._last_command_ms = None
            self.linear = 0.0
            self.angular = 0.0
            self.failsafe_trips += 1

    # ------------------------------------------------------------------ publishing

    def _publish(self, topic, stamp_ns):
        # Refill the topic's one message in place and write it. (One method for the five topics:
        # on a board each method and the bound method a table of them would hold cost heap.)
        if topic == "sensor_state":
            msg = self._sensor_state
            msg.left_encoder = self.left_ticks
            msg.right_encoder = self.right_ticks
            msg.battery = self.battery_voltage
            header = msg.header
        elif topic == "imu":
            msg = self._imu
            _set_yaw(msg.orientation, self.yaw)
            msg.angular_velocity.z = self.angular
            header = msg.header
        elif topic == "battery_state":
            msg = self._battery
            msg.voltage = self.battery_voltage
            msg.percentage = (self.battery_voltage - _BATTERY_EMPTY_V) / (_BATTERY_FULL_V - _BATTERY_EMPTY_V)
            msg.current = -(0.3 + 0.7 * abs(self.linear) / _MAX_LINEAR_VELOCITY)
            header = msg.header
        elif topic == "odom":
            msg = self._odom
            pose = msg.pose.pose
            pose.position.x = self.x
            pose.position.y = self.y
            _set_yaw(pose.orientation, self.yaw)
            msg.twist.twist.linear.x = self.linear
            msg.twist.twist.angular.z = self.angular
            header = msg.header
        else:  # tf
            transform = self._transform
            transform.transform.translation.x = self.x
            transform.transform.translation.y = self.y
            _set_yaw(transform.transform.rotation, self.yaw)
            header = transform.header
            msg = self._tf
        _set_stamp(header, stamp_ns)
        writer, stream = self._writers[topic]
        if self.session.write(writer, msg, stream_id=stream):
            self.published[topic] += 1
        # Out at once, as rmw_microxrcedds flushes on every publish: a sample must not wait
        # behind the fragments of a larger one written after it.
        self.session.flush()

    # ------------------------------------------------------------------ the loop

    def step(self):
        # One pass of the main loop: input for at most ``_MAX_WAIT_MS``, motion, due publications.
        for _ in self.step_stages():
            pass

    def step_stages(self):
        # ``step`` one piece at a time, for a firmware loop that runs other tasks (or collects its
        # garbage) in between: yields after the input (each message taken in, and once more after
        # the wait, so every pass yields), after each publication and after a time sync. (``step``
        # drains it: the generator is ~100 bytes of garbage a pass.)
        session = self.session
        now = ticks_ms()
        wait = _MAX_WAIT_MS
        for _, timer in self._schedule:
            remaining = timer.remaining(now)
            if remaining < wait:
                wait = remaining if remaining > 0 else 0
        if session.spin_once(wait):
            yield
            count = 1
            while count < _MAX_MESSAGES_PER_STEP and session.spin_once(0):
                count += 1
                yield
        now = ticks_ms()
        self._check_failsafe(now)
        yield
        for topic, timer in self._schedule:
            if timer.take(now):
                # The motion is integrated when something needs it (a publication, a command,
                # the fail-safe), not on every pass: its float arithmetic is most of what a pass
                # would otherwise allocate (~700 bytes on a board, where every float is an object).
                self._move(now)
                self._publish(topic, session.epoch_ns())
                yield
        if self._sync_timer is not None and self._sync_timer.take(now):
            self.sync_clock()
            yield
        if self.extras is not None:
            self.extras.step(now)

    def run(self, duration_ms=None, should_stop=None):
        # Loop ``step`` for ``duration_ms`` (None: forever) or until ``should_stop()`` is true.
        start = ticks_ms()
        while True:
            if duration_ms is not None and ticks_diff(ticks_ms(), start) >= duration_ms:
                return
            if should_stop is not None and should_stop():
                return
            self.step()

    def shutdown(self):
        # Delete the session on the agent (its ROS entities go with it) and close the transport.
        try:
            self.session.delete(attempts=2, timeout_ms=300)
        finally:
            self.session.close()


# ---------------------------------------------------------------------- CPython command line

def main(argv=None):
    # The command line lives in its own module: a board running this firmware never pays for it. It
    # is handed the robot class rather than importing this module, so neither imports the other.
    from xrce.examples.turtlebot3_cli import main

    return main(TurtleBot3, argv)


if __name__ == "__main__":
    import sys
    sys.exit(main())
