"""
Launch a leader-follower pair: two driver nodes, each on its bus and in its namespace.

  ros2 launch dxl_servo_driver teleop.launch.py                      (both arms simulated)
  ros2 launch dxl_servo_driver teleop.launch.py leader_port:=/dev/ttyACM0 \
      follower_port:=/dev/ttyACM1

The leader (namespace `leader`, config/koch_leader.yaml by default) publishes its joints'
positions on /leader/joint_states; the follower (namespace `follower`,
config/koch_follower.yaml) copies them in its own cycle: its follow.topic is set here to the
leader's joint_states. Ports default to `sim` (each node's simulated servos); the OMX pair is
leader_params:=.../omx_leader.yaml follower_params:=.../omx_follower.yaml.
docs/teleoperation.md says how a pair works.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    """Return the launch description: the ports, files and namespaces, and both nodes."""
    config = os.path.join(get_package_share_directory('dxl_servo_driver'), 'config')
    arguments = [
        DeclareLaunchArgument('leader_port', default_value='sim',
                              description="The leader's serial device (sim: simulated)."),
        DeclareLaunchArgument('follower_port', default_value='sim',
                              description="The follower's serial device (sim: simulated)."),
        DeclareLaunchArgument('leader_params',
                              default_value=os.path.join(config, 'koch_leader.yaml'),
                              description="The leader's parameter file."),
        DeclareLaunchArgument('follower_params',
                              default_value=os.path.join(config, 'koch_follower.yaml'),
                              description="The follower's parameter file."),
        DeclareLaunchArgument('leader_namespace', default_value='leader',
                              description="The leader node's namespace."),
        DeclareLaunchArgument('follower_namespace', default_value='follower',
                              description="The follower node's namespace."),
    ]
    leader = Node(
        package='dxl_servo_driver', executable='node',
        namespace=LaunchConfiguration('leader_namespace'),
        parameters=[LaunchConfiguration('leader_params'),
                    {'port': LaunchConfiguration('leader_port')}],
        output='screen', emulate_tty=True)
    follower = Node(
        package='dxl_servo_driver', executable='node',
        namespace=LaunchConfiguration('follower_namespace'),
        parameters=[LaunchConfiguration('follower_params'),
                    {'port': LaunchConfiguration('follower_port'),
                     # The leader's joint_states, wherever its namespace puts them.
                     'follow.topic': ['/', LaunchConfiguration('leader_namespace'),
                                      '/joint_states']}],
        output='screen', emulate_tty=True)
    return LaunchDescription([*arguments, leader, follower])
