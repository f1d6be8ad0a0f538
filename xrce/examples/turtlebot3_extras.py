# What the simulated TurtleBot3 offers ROS 2 beyond topics when made with ``ros_extras=True``: its
# calibration as parameters and a patrol as an action, where real firmware would put them.
#
# Parameters of node ``turtlebot3_node`` (`ros2 param list /turtlebot3_node`):
#   wheel_radius (m, 0.01..0.1)  the radius the encoders' odometry assumes: counts per metre follow
#   failsafe_ms (100..5000)      how long without /cmd_vel before the wheels stop
#   model (read-only)            "burger"
# Action ``/patrol`` (turtlebot3_msgs/action/Patrol): drive one lap of a circle of the goal's radius
# at 0.1 m/s, feedback ``left_time`` (s) every second, result ``success``; cancelling stops the
# wheels at once. /cmd_vel keeps priority: a command received during a patrol aborts it, except in
# its first second, when commands sent before their sender saw the goal may still arrive (a node
# that yields /cmd_vel to a patrol, as `xrce-agent demo` does, learns of it from the action status).
#
# Its own module: a board whose firmware does not ask for them never loads it, nor the parameter and
# action code (xrce.client.parameters, xrce.client.actions) it brings.

from xrce import const, ticks_diff, ticks_ms
from xrce.client.actions import ActionServer
from xrce.client.parameters import ParameterServer
from xrce.msgs.turtlebot3_msgs import Patrol

_PATROL_SPEED = const(0.1)  # m/s
_FEEDBACK_MS = const(1000)
_TWO_PI = const(6.283185307179586)
_HANDOVER_MS = const(1000)


class RobotExtras:
    def __init__(self, robot, node):
        self.robot = robot
        self.params = ParameterServer(robot.session, node, "/" + robot.node_name,
                                      on_change=self._on_change, max_params=4)
        self.params.declare("wheel_radius", 0.033, min_value=0.01, max_value=0.1,
                            description="wheel radius the odometry assumes (m)")
        self.params.declare("failsafe_ms", robot.failsafe_ms, min_value=100, max_value=5000,
                            description="stop without /cmd_vel for this long (ms)")
        self.params.declare("model", "burger", read_only=True)
        self.wheel_radius = 0.033
        self.patrol = ActionServer(robot.session, node, "/patrol", Patrol, self._on_goal, max_goals=1)
        self._goal = None
        self._started_ms = 0
        self._lap_ms = 0
        self._feedback_ms = 0
        self._commands = 0

    def _on_change(self, name, value):
        if name == "wheel_radius":
            self.wheel_radius = value
        elif name == "failsafe_ms":
            self.robot.failsafe_ms = value
        return True

    def _on_goal(self, goal):
        # One patrol at a time, of a radius the robot can turn.
        radius = goal.goal.radius
        if self._goal is not None or not 0.05 <= radius <= 2.0:
            return False
        self._goal = goal
        self._lap_ms = int(_TWO_PI * radius / _PATROL_SPEED * 1000)
        self._started_ms = self._feedback_ms = ticks_ms()
        self._commands = self.robot.commands_received
        return True

    def step(self, now):
        # Called by TurtleBot3.step_stages on each pass: the patrol's wheels, feedback and end.
        goal = self._goal
        if goal is None:
            return
        robot = self.robot
        elapsed = ticks_diff(now, self._started_ms)
        if elapsed < _HANDOVER_MS:
            self._commands = robot.commands_received  # already on its way when the goal came
        if goal.cancel_requested or robot.commands_received != self._commands or elapsed >= self._lap_ms:
            robot._move(now)
            robot.linear = 0.0
            robot.angular = 0.0
            result = Patrol.Result(success=elapsed >= self._lap_ms)
            if goal.cancel_requested:
                goal.canceled(result)
            elif robot.commands_received != self._commands:
                goal.abort(result)
            else:
                goal.succeed(result)
            self._goal = None
            return
        angular = _PATROL_SPEED / goal.goal.radius
        if robot.linear != _PATROL_SPEED or robot.angular != angular:
            robot._move(now)
            robot.linear = _PATROL_SPEED
            robot.angular = angular
        robot._last_command_ms = now  # the patrol commands the wheels: no fail-safe stop
        if ticks_diff(now, self._feedback_ms) >= _FEEDBACK_MS:
            self._feedback_ms = now
            goal.publish_feedback(Patrol.Feedback(left_time=(self._lap_ms - elapsed) * 0.001))
