"""
Launch two leader-follower pairs (four buses, four driver nodes): a bimanual setup.

  ros2 launch dxl_servo_driver bimanual.launch.py                    (all four simulated)
  ros2 launch dxl_servo_driver bimanual.launch.py \
      left_leader_port:=/dev/serial/by-id/<its adapter> left_follower_port:=... \
      right_leader_port:=... right_follower_port:=...

Namespaces left_leader, left_follower, right_leader, right_follower; each follower copies its
side's leader (/left_leader/joint_states, /right_leader/joint_states). Both sides use
leader_params and follower_params (config/koch_leader.yaml, koch_follower.yaml by default).
One node per bus: each has its own cycle thread, and a slow bus never slows another
(docs/teleoperation.md, the four-arm launch).
"""

import os
from typing import List

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

SIDES = ('left', 'right')


def _pair(side: str) -> List[Node]:
    """Return one side's leader and follower nodes."""
    leader_ns = f'{side}_leader'
    leader = Node(
        package='dxl_servo_driver', executable='node', namespace=leader_ns,
        parameters=[LaunchConfiguration('leader_params'),
                    {'port': LaunchConfiguration(f'{side}_leader_port')}],
        output='screen', emulate_tty=True)
    follower = Node(
        package='dxl_servo_driver', executable='node', namespace=f'{side}_follower',
        parameters=[LaunchConfiguration('follower_params'),
                    {'port': LaunchConfiguration(f'{side}_follower_port'),
                     'follow.topic': f'/{leader_ns}/joint_states'}],
        output='screen', emulate_tty=True)
    return [leader, follower]


def generate_launch_description() -> LaunchDescription:
    """Return the launch description: four ports, the two files, four nodes."""
    config = os.path.join(get_package_share_directory('dxl_servo_driver'), 'config')
    arguments = [
        DeclareLaunchArgument(f'{side}_{role}_port', default_value='sim',
                              description=f'The {side} {role} serial device (sim: simulated).')
        for side in SIDES for role in ('leader', 'follower')]
    arguments += [
        DeclareLaunchArgument('leader_params',
                              default_value=os.path.join(config, 'koch_leader.yaml'),
                              description="Both leaders' parameter file."),
        DeclareLaunchArgument('follower_params',
                              default_value=os.path.join(config, 'koch_follower.yaml'),
                              description="Both followers' parameter file."),
    ]
    nodes = [node for side in SIDES for node in _pair(side)]
    return LaunchDescription([*arguments, *nodes])
