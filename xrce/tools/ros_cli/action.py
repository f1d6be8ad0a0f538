"""``xrce-ros action list | send_goal`` with ros2action's options and output."""

from __future__ import annotations

from xrce.tools.ros_cli.arguments import CommandError, UsageError, add_graph_arguments
from xrce.tools.ros_cli.graph import NODE_NAME_PREFIX, CliNode
from xrce.tools.ros_cli.messages import (interface_class, message_to_yaml, parse_yaml_values,
                                         set_message_fields)

NAME = "action"
HELP = "Various action related sub-commands"


def add_verbs(verbs):
    parser = verbs.add_parser("list", help="Output a list of action names")
    add_graph_arguments(parser)
    parser.add_argument("-t", "--show-types", action="store_true",
                        help="Additionally show the action type")
    parser.add_argument("-c", "--count-actions", action="store_true",
                        help="Only display the number of actions discovered")
    parser.set_defaults(run=list_actions)

    parser = verbs.add_parser("send_goal", help="Send an action goal")
    parser.add_argument("action_name", help="Name of the ROS action (e.g. '/fibonacci')")
    parser.add_argument("action_type",
                        help="Type of the ROS action (e.g. 'example_interfaces/action/Fibonacci')")
    parser.add_argument("goal", nargs="?", default="{}",
                        help="Goal request values in YAML format (e.g. '{order: 10}')")
    parser.add_argument("-f", "--feedback", action="store_true",
                        help="Echo feedback messages for the goal")
    parser.set_defaults(run=send_goal)


def list_actions(args):
    from rclpy.action import get_action_names_and_types

    with CliNode(spin_time=args.spin_time) as cli:
        actions = get_action_names_and_types(cli.node)
    if args.count_actions:
        print(len(actions))
        return
    for name, types in actions:
        print("%s [%s]" % (name, ", ".join(types)) if args.show_types else name)


def _status_name(status):
    from action_msgs.msg import GoalStatus

    return {GoalStatus.STATUS_ACCEPTED: "ACCEPTED", GoalStatus.STATUS_EXECUTING: "EXECUTING",
            GoalStatus.STATUS_CANCELING: "CANCELING", GoalStatus.STATUS_SUCCEEDED: "SUCCEEDED",
            GoalStatus.STATUS_CANCELED: "CANCELED", GoalStatus.STATUS_ABORTED: "ABORTED",
            }.get(status, "UNKNOWN")


def _show_feedback(feedback_message):
    print("Feedback:\n    %s" % message_to_yaml(feedback_message.feedback))


def send_goal(args):
    from action_msgs.msg import GoalStatus
    from rclpy.action import ActionClient

    action_class = interface_class(args.action_type, "action")
    goal = action_class.Goal()
    try:
        set_message_fields(goal, parse_yaml_values(args.goal))
    except UsageError:
        raise
    except Exception as error:
        raise UsageError("Failed to populate message fields: %r" % error) from None
    name = "%s_send_goal_%s" % (NODE_NAME_PREFIX, args.action_type.replace("/", "_"))
    with CliNode(name=name) as cli:
        client = ActionClient(cli.node, action_class, args.action_name)
        handle = None
        try:
            print("Waiting for an action server to become available...")
            cli.spin_until(client.server_is_ready)
            print("Sending goal:\n     %s" % message_to_yaml(goal))
            sent = client.send_goal_async(goal, _show_feedback if args.feedback else None)
            cli.spin_until_done(sent)
            handle = sent.result()
            if handle is None:
                raise CommandError("Exception while sending goal: %r" % sent.exception())
            if not handle.accepted:
                handle = None
                print("Goal was rejected.")
                return
            print("Goal accepted with ID: %s\n" % bytes(handle.goal_id.uuid).hex())
            done = handle.get_result_async()
            cli.spin_until_done(done)
            result = done.result()
            if result is None:
                raise CommandError("Exception while getting result: %r" % done.exception())
            handle = None
            print("Result:\n    %s" % message_to_yaml(result.result))
            print("Goal finished with status: %s" % _status_name(result.status))
        finally:
            # Ctrl-C while the goal runs: cancel it, as ros2action does, so that the server
            # does not go on with a goal nobody waits for.
            if handle is not None and handle.status in (GoalStatus.STATUS_ACCEPTED,
                                                        GoalStatus.STATUS_EXECUTING):
                print("Canceling goal...")
                canceled = handle.cancel_goal_async()
                if cli.spin_until_done(canceled, 5.0) and canceled.result() is not None:
                    print("Goal canceled.")
            client.destroy()
