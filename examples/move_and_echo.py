#!/usr/bin/env python3
"""
Move one joint and print /joint_states: the rclpy way, where there is no `ros2` command line.

ROS 2 from PyPI wheels (`make setup`) has no `ros2` command line. This script does what

    ros2 topic pub --once /dxl_servo_driver/commands/position
        dxl_servo_driver_msgs/msg/JointCommand "{name: [shoulder], value: [0.5]}"
    ros2 topic echo /joint_states

(the first on one line) do together. With the driver running (`make run`), in another terminal,
from the repository:

    . tools/env.sh
    python examples/move_and_echo.py shoulder 0.5
    python examples/move_and_echo.py gripper 0.3 --kind current
    python examples/move_and_echo.py wheel 1.0 --kind velocity --rate 10
    python examples/move_and_echo.py r_shoulder 0.2 --ros-args -r __ns:=/right

It publishes one dxl_servo_driver_msgs/JointCommand on dxl_servo_driver/commands/<kind> (relative
to its namespace, as the driver's topics are; --driver names another node) once the driver
subscribes to it, then prints the joints' positions from /joint_states every --every seconds,
--count times. With --rate it publishes the command again at that rate while it prints, as
`ros2 topic pub -r` does: with `command_timeout` set, a velocity, current or PWM goal falls back
to zero unless it is sent again. It exits 1 when no driver subscribes, or no joint_states come,
within --timeout seconds.
"""

import argparse
import sys
import time
from typing import List, Optional

from dxl_servo_driver_msgs.msg import JointCommand
import rclpy
from rclpy.node import Node
from rclpy.utilities import remove_ros_args
from sensor_msgs.msg import JointState

KINDS = ('position', 'velocity', 'current', 'pwm')
UNITS = {'position': 'rad', 'velocity': 'rad/s', 'current': 'A', 'pwm': '(ratio)'}


def parse_args(argv: List[str]) -> argparse.Namespace:
    """Return the script's own arguments (the --ros-args part is rclpy's)."""
    parser = argparse.ArgumentParser(
        description='Publish one JointCommand to the driver, then print /joint_states.')
    parser.add_argument('joint', nargs='?', default='shoulder',
                        help='the joint to command (default: shoulder)')
    parser.add_argument('value', nargs='?', type=float, default=0.5,
                        help="the goal in the topic's unit: rad, rad/s, A or ratio (default 0.5)")
    parser.add_argument('--kind', choices=KINDS, default='position',
                        help='the command topic (default position)')
    parser.add_argument('--count', type=int, default=8,
                        help='how many joint_states to print (default 8)')
    parser.add_argument('--every', type=float, default=0.25,
                        help='seconds between two printed joint_states (default 0.25)')
    parser.add_argument('--rate', type=float, default=0.0, metavar='HZ',
                        help='publish the command again at this rate while printing (default: '
                        'once)')
    parser.add_argument('--driver', default='dxl_servo_driver',
                        help="the driver node's name (default dxl_servo_driver)")
    parser.add_argument('--timeout', type=float, default=10.0,
                        help='seconds to wait for the driver and its joint_states (default 10)')
    args = parser.parse_args(remove_ros_args(argv)[1:])
    if args.rate < 0:
        parser.error('--rate must be 0 (once) or above')
    return args


def line(elapsed_s: float, msg: JointState) -> str:
    """Return one printed line: the time since the command and each joint's position."""
    positions = '  '.join(f'{name}={position:+.3f}'
                          for name, position in zip(msg.name, msg.position))
    return f'{elapsed_s:5.2f} s  {positions}'


def move_and_echo(node: Node, args: argparse.Namespace) -> int:
    """Publish the command once the driver listens, print joint_states; return the exit code."""
    publisher = node.create_publisher(JointCommand, f'{args.driver}/commands/{args.kind}', 10)
    latest: List[Optional[JointState]] = [None]

    def keep(msg: JointState) -> None:
        latest[0] = msg
    node.create_subscription(JointState, 'joint_states', keep, 10)

    deadline = time.monotonic() + args.timeout
    while publisher.get_subscription_count() < 1:
        if time.monotonic() > deadline:
            print(f'no driver subscribes to {publisher.topic_name} within {args.timeout:g} s '
                  '(is it running, in this namespace and ROS_DOMAIN_ID?)', file=sys.stderr)
            return 1
        rclpy.spin_once(node, timeout_sec=0.05)
    command = JointCommand(name=[args.joint], value=[args.value])
    publisher.publish(command)
    again = f', again at {args.rate:g} Hz' if args.rate else ''
    print(f'published {args.joint} {args.value:g} {UNITS[args.kind]} on {publisher.topic_name}'
          f'{again}; positions from {node.resolve_topic_name("joint_states")}:', flush=True)

    start = time.monotonic()
    due = start + args.every
    resend = start + (1.0 / args.rate if args.rate else float('inf'))
    printed = 0
    while printed < args.count:
        rclpy.spin_once(node, timeout_sec=0.02)
        now = time.monotonic()
        if now >= resend:
            publisher.publish(command)
            resend += 1.0 / args.rate
        if latest[0] is None:
            if now - start > args.timeout:
                print(f'no joint_states within {args.timeout:g} s', file=sys.stderr)
                return 1
            continue
        if now >= due:
            print(line(now - start, latest[0]), flush=True)
            printed += 1
            due += args.every
    return 0


def main(argv: Optional[List[str]] = None) -> int:
    """Run the script; return its exit code."""
    argv = sys.argv if argv is None else argv
    args = parse_args(argv)
    rclpy.init(args=argv)
    node = rclpy.create_node('move_and_echo')
    try:
        return move_and_echo(node, args)
    except KeyboardInterrupt:
        return 130
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
