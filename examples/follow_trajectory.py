#!/usr/bin/env python3
"""
Send the driver one FollowJointTrajectory goal, as MoveIt does, and print its result.

The driver serves control_msgs/action/FollowJointTrajectory on
/dxl_servo_driver/follow_joint_trajectory (docs/interfaces.md, docs/moveit.md). This client, in
plain rclpy, reads where the named joints are from /joint_states, sends a trajectory of two
points from there (halfway at half the duration, the goal at the end, at rest), prints the
feedback's errors while it runs, then the result and where the joints arrived. With the driver
running (`make run`, or `make run PARAMS=config/arm_sim.yaml`), in another terminal, from the
repository:

    . tools/env.sh
    python examples/follow_trajectory.py shoulder=0.5
    python examples/follow_trajectory.py shoulder_pan=0.3 elbow=-0.4 --duration 3
    python examples/follow_trajectory.py r_shoulder=0.2 --ros-args -r __ns:=/right

The goal's path and goal tolerances are left at zero: the driver's defaults then apply. It exits
0 when the result is SUCCESSFUL, 1 otherwise (a refused goal, a failed one, a joint the driver
does not publish, no driver or no joint_states within --timeout seconds).
"""

import argparse
import sys
import time
from typing import Any, Dict, List, Optional, Tuple

from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
import rclpy
from rclpy.action import ActionClient
from rclpy.node import Node
from rclpy.task import Future
from rclpy.utilities import remove_ros_args
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

# FollowJointTrajectory.Result's error codes, by value (the action's definition).
CODES = {0: 'SUCCESSFUL', -1: 'INVALID_GOAL', -2: 'INVALID_JOINTS', -3: 'OLD_HEADER_TIMESTAMP',
         -4: 'PATH_TOLERANCE_VIOLATED', -5: 'GOAL_TOLERANCE_VIOLATED'}


def target(text: str) -> Tuple[str, float]:
    """Return one JOINT=POSITION argument as (name, position in rad)."""
    name, sep, value = text.partition('=')
    try:
        if not sep or not name:
            raise ValueError
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r}: expected JOINT=POSITION, e.g. '
                                         'shoulder=0.5') from None


def parse_args(argv: List[str]) -> argparse.Namespace:
    """Return the script's own arguments (the --ros-args part is rclpy's)."""
    parser = argparse.ArgumentParser(
        description='Send one FollowJointTrajectory goal to the driver; print its result.')
    parser.add_argument('targets', nargs='*', type=target, metavar='JOINT=POSITION',
                        default=[('shoulder', 0.5)],
                        help='where each joint goes, in rad (default: shoulder=0.5)')
    parser.add_argument('--duration', type=float, default=2.0,
                        help='seconds the trajectory takes (default 2)')
    parser.add_argument('--driver', default='dxl_servo_driver',
                        help="the driver node's name (default dxl_servo_driver)")
    parser.add_argument('--timeout', type=float, default=10.0,
                        help='seconds to wait for the driver and its joint_states (default 10)')
    args = parser.parse_args(remove_ros_args(argv)[1:])
    if args.duration <= 0:
        parser.error('--duration must be above 0')
    return args


def seconds(value_s: float) -> Duration:
    """Return a duration message of value_s seconds."""
    whole = int(value_s)
    return Duration(sec=whole, nanosec=int(round((value_s - whole) * 1e9)))


def trajectory(names: List[str], start: List[float], goal: List[float],
               duration_s: float) -> JointTrajectory:
    """Return the two points: halfway at half the duration, the goal at rest at the end."""
    middle = [(a + b) / 2.0 for a, b in zip(start, goal)]
    speed = [(b - a) / duration_s * 1.5 for a, b in zip(start, goal)]   # a smooth bell's peak
    return JointTrajectory(joint_names=names, points=[
        JointTrajectoryPoint(positions=middle, velocities=speed,
                             time_from_start=seconds(duration_s / 2.0)),
        JointTrajectoryPoint(positions=goal, velocities=[0.0] * len(goal),
                             time_from_start=seconds(duration_s))])


def wait(node: Node, future: Future, timeout_s: float) -> bool:
    """Spin until future is done; False after timeout_s."""
    rclpy.spin_until_future_complete(node, future, timeout_sec=timeout_s)
    return future.done()


def follow(node: Node, args: argparse.Namespace) -> int:
    """Send the goal, print feedback, result and where the joints are; return the exit code."""
    latest: List[Optional[JointState]] = [None]

    def keep(msg: JointState) -> None:
        latest[0] = msg
    node.create_subscription(JointState, 'joint_states', keep, 10)
    action = node.resolve_topic_name(f'{args.driver}/follow_joint_trajectory')
    client = ActionClient(node, FollowJointTrajectory, action)
    names = [name for name, _ in args.targets]
    goal = [position for _, position in args.targets]

    deadline = time.monotonic() + args.timeout
    if not client.wait_for_server(timeout_sec=args.timeout):
        print(f'no action server on {action} within {args.timeout:g} s (is the '
              'driver running, in this namespace and ROS_DOMAIN_ID?)', file=sys.stderr)
        return 1
    positions: Dict[str, float] = {}
    first: Optional[float] = None
    while not all(name in positions for name in names):
        missing = [name for name in names if name not in positions]
        now = time.monotonic()
        # A servo may miss a cycle's read; a joint missing from a second of messages is none.
        if first is not None and now - first > 1.0:
            print(f'{", ".join(missing)}: not among the joints on '
                  f'{node.resolve_topic_name("joint_states")} ({", ".join(positions)})',
                  file=sys.stderr)
            return 1
        if now > deadline:
            print(f'no joint_states within {args.timeout:g} s', file=sys.stderr)
            return 1
        rclpy.spin_once(node, timeout_sec=0.05)
        if latest[0] is not None:
            first = now if first is None else first
            positions.update(zip(latest[0].name, latest[0].position))
    start = [positions[name] for name in names]
    print('from ' + '  '.join(f'{n}={p:+.3f}' for n, p in zip(names, start)) + ' to '
          + '  '.join(f'{n}={p:+.3f}' for n, p in zip(names, goal))
          + f' in {args.duration:g} s', flush=True)

    printed = [0.0]

    def feedback(message: Any) -> None:   # the action's FeedbackMessage
        now = time.monotonic()
        if now - printed[0] >= 0.5:   # a line every half second, not every cycle
            printed[0] = now
            errors = message.feedback.error.positions
            print('  error ' + '  '.join(f'{n}={e:+.3f}' for n, e in zip(names, errors)),
                  flush=True)
    request = FollowJointTrajectory.Goal(
        trajectory=trajectory(names, start, goal, args.duration))
    sent = client.send_goal_async(request, feedback_callback=feedback)
    if not wait(node, sent, args.timeout):
        print('the driver did not answer the goal', file=sys.stderr)
        return 1
    handle = sent.result()
    if not handle.accepted:
        print('the goal was rejected', file=sys.stderr)
        return 1
    done = handle.get_result_async()
    if not wait(node, done, args.duration + args.timeout):
        print('no result', file=sys.stderr)
        return 1
    result = done.result().result
    code = CODES.get(result.error_code, str(result.error_code))
    print(f'result: {code}' + (f' ({result.error_string})' if result.error_string else ''),
          flush=True)
    # Where the joints are now: a joint_states message newer than the result.
    latest[0] = None
    deadline = time.monotonic() + args.timeout
    while latest[0] is None and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    if latest[0] is not None:
        now = dict(zip(latest[0].name, latest[0].position))
        print('arrived ' + '  '.join(f'{n}={now[n]:+.3f}' for n in names if n in now),
              flush=True)
    return 0 if result.error_code == FollowJointTrajectory.Result.SUCCESSFUL else 1


def main(argv: Optional[List[str]] = None) -> int:
    """Run the script; return its exit code."""
    argv = sys.argv if argv is None else argv
    args = parse_args(argv)
    rclpy.init(args=argv)
    node = rclpy.create_node('follow_trajectory')
    try:
        return follow(node, args)
    except KeyboardInterrupt:
        return 130
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
