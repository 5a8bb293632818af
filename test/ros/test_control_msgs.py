"""
control_msgs meets the real one on the wire: the type hashes (RIHS01) of ROS 2 Jazzy's.

Where `make setup` built the stand-in (compat/control_msgs, PyPI has no control_msgs) these are
its hashes; on a ROS 2 install, the real package's. Either way they must be control_msgs 5.x's
(Jazzy): a MoveIt on another machine checks them before it talks to the driver.
"""

import json
import pathlib
import time
from typing import Dict

from ament_index_python.packages import get_package_share_directory
import pytest
import rclpy

# The real control_msgs 5.8.0 (jazzy), built from its own sources.
JAZZY_HASHES = {
    'control_msgs/action/FollowJointTrajectory':
        'RIHS01_738ebcb7a2d7cfa42f9f1001cc99ce3a4383d1cfe508015d9be8485e4b1c66f6',
    'control_msgs/action/GripperCommand':
        'RIHS01_e17c0e644eccf14bea84a0a93e0977182872c2eb7873ca6694900059b46dbc84',
    'control_msgs/msg/JointTolerance':
        'RIHS01_c254f9cece0f3b733017b6990fd46d1326e25242d6b8844398c97d9a88e7d648',
}


def hashes_of(interface: str) -> Dict[str, str]:
    """Return every type hash the installed package lists for one interface file."""
    share = pathlib.Path(get_package_share_directory('control_msgs'))
    described = json.loads((share / f'{interface}.json').read_text())
    return {entry['type_name']: entry['hash_string'] for entry in described['type_hashes']}


@pytest.mark.parametrize('type_name', sorted(JAZZY_HASHES))
def test_the_installed_types_have_jazzys_hashes(type_name: str) -> None:
    interface = type_name.split('/', 1)[1]
    assert hashes_of(interface)[type_name] == JAZZY_HASHES[type_name]


def test_the_fields_the_driver_uses_are_there() -> None:
    from control_msgs.action import FollowJointTrajectory, GripperCommand
    goal = FollowJointTrajectory.Goal.get_fields_and_field_types()
    assert goal['trajectory'] == 'trajectory_msgs/JointTrajectory'
    assert goal['path_tolerance'] == 'sequence<control_msgs/JointTolerance>'
    assert goal['goal_time_tolerance'] == 'builtin_interfaces/Duration'
    result = FollowJointTrajectory.Result
    assert (result.SUCCESSFUL, result.INVALID_GOAL, result.INVALID_JOINTS,
            result.OLD_HEADER_TIMESTAMP, result.PATH_TOLERANCE_VIOLATED,
            result.GOAL_TOLERANCE_VIOLATED) == (0, -1, -2, -3, -4, -5)
    assert GripperCommand.Goal.get_fields_and_field_types() == {
        'command': 'control_msgs/GripperCommand'}
    assert set(GripperCommand.Result.get_fields_and_field_types()) == {
        'position', 'effort', 'stalled', 'reached_goal'}


def test_the_middleware_announces_those_hashes() -> None:
    """An action server's feedback topic carries the hash discovery compares."""
    from control_msgs.action import FollowJointTrajectory
    from rclpy.action import ActionServer
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('hash_probe', context=context)
    try:
        server = ActionServer(node, FollowJointTrajectory, 'probe',
                              execute_callback=lambda handle: FollowJointTrajectory.Result())
        want = hashes_of('action/FollowJointTrajectory')[
            'control_msgs/action/FollowJointTrajectory_FeedbackMessage']
        deadline = time.monotonic() + 10.0
        infos = []
        while not infos and time.monotonic() < deadline:
            infos = node.get_publishers_info_by_topic('/probe/_action/feedback')
            if not infos:
                time.sleep(0.05)
        assert infos, 'the feedback publisher was never listed'
        assert str(infos[0].topic_type_hash) == want
        server.destroy()
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)
