"""
Launch the dxl_servo_driver node on one bus.

  ros2 launch dxl_servo_driver dxl_servo_driver.launch.py params_file:=/path/to/bus.yaml
      namespace:=arm

params_file defaults to the installed config/sim.yaml (simulated servos, no hardware needed).
One node drives one bus: launch this once per bus, each in its own namespace.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    """Return the launch description: two arguments and the driver node."""
    default_params = os.path.join(get_package_share_directory('dxl_servo_driver'), 'config',
                                  'sim.yaml')
    return LaunchDescription([
        DeclareLaunchArgument(
            'params_file', default_value=default_params,
            description='Parameter file of the node (port, baud_rate, joints, ...); '
                        '`scan --output FILE` writes one for the servos it finds.'),
        DeclareLaunchArgument(
            'namespace', default_value='',
            description='Namespace of the node (one node per bus; give each bus its own).'),
        Node(
            package='dxl_servo_driver',
            executable='node',
            namespace=LaunchConfiguration('namespace'),
            parameters=[LaunchConfiguration('params_file')],
            output='screen',
            emulate_tty=True,
        ),
    ])
