"""
The MoveIt files of the simulated arm agree with its parameter file and with the node's actions.

config/moveit/ holds what a MoveIt user needs to try the whole path without hardware: a URDF and
SRDF of config/arm_sim.yaml's arm and a complete moveit_controllers.yaml. A joint named or
limited otherwise than the parameter file says gives INVALID_JOINTS or refused goals; a
controller whose name and action_ns are not where the node serves its actions is never found.
"""

import pathlib
from typing import Any, Dict, List, Tuple
import xml.etree.ElementTree as ElementTree

from control_msgs.action import FollowJointTrajectory, ParallelGripperCommand
from dxl_servo_driver.config import validate
from dxl_servo_driver.tool.yaml_edit import flatten
from node_harness import NodeHarness
import pytest
from rclpy.action import ActionClient
import yaml

CONFIG = pathlib.Path(__file__).resolve().parents[2] / 'config'
MOVEIT = CONFIG / 'moveit'


def arm_params() -> Dict[str, Any]:
    return flatten(yaml.safe_load((CONFIG / 'arm_sim.yaml').read_text())['/**']['ros__parameters'])


def urdf_joints() -> Dict[str, Tuple[str, str, str, float, float]]:
    """Return {joint: (type, parent, child, lower, upper)} of the URDF."""
    root = ElementTree.parse(MOVEIT / 'arm_sim.urdf').getroot()
    joints = {}
    for joint in root.iter('joint'):
        limit = joint.find('limit')
        low, high = ((float(limit.get('lower', 'nan')), float(limit.get('upper', 'nan')))
                     if limit is not None else (float('nan'), float('nan')))
        parent, child = joint.find('parent'), joint.find('child')
        assert parent is not None and child is not None
        joints[joint.get('name', '')] = (joint.get('type', ''), parent.get('link', ''),
                                         child.get('link', ''), low, high)
    return joints


def chain(joints: Dict[str, Tuple[str, str, str, float, float]], base: str,
          tip: str) -> List[str]:
    """Return the movable joints from base to tip, in order."""
    by_child = {child: (name, parent) for name, (_, parent, child, _, _) in joints.items()}
    names = []
    link = tip
    while link != base:
        name, link = by_child[link]
        names.append(name)
    return [name for name in reversed(names) if joints[name][0] != 'fixed']


def test_the_urdf_has_the_parameter_files_joints_and_limits() -> None:
    config = validate(arm_params())
    joints = urdf_joints()
    movable = {name for name, (kind, *_) in joints.items() if kind != 'fixed'}
    assert movable == {joint.name for joint in config.joints}
    for joint in config.joints:
        low, high = joint.position_limits()
        assert joints[joint.name][3:] == (low, high), joint.name


def test_the_srdf_groups_are_what_the_controllers_drive() -> None:
    config = validate(arm_params())
    joints = urdf_joints()
    srdf = ElementTree.parse(MOVEIT / 'arm_sim.srdf').getroot()
    groups = {group.get('name'): group for group in srdf.iter('group')}
    arm_chain = groups['arm'].find('chain')
    assert arm_chain is not None
    arm = chain(joints, arm_chain.get('base_link', ''), arm_chain.get('tip_link', ''))
    hand = [joint.get('name') for joint in groups['hand'].iter('joint')]
    grippers = [joint.name for joint in config.joints if joint.gripper]
    assert arm == [joint.name for joint in config.joints if not joint.gripper]
    assert hand == grippers
    # Every named state is inside the limits the driver enforces.
    limits = {joint.name: joint.position_limits() for joint in config.joints}
    for state in srdf.iter('group_state'):
        for joint in state.iter('joint'):
            low, high = limits[joint.get('name', '')]
            value = float(joint.get('value', 'nan'))
            assert low is not None and high is not None and low <= value <= high, (
                state.get('name'), joint.get('name'))
    controllers = yaml.safe_load((MOVEIT / 'moveit_controllers.yaml').read_text())
    manager = controllers['moveit_simple_controller_manager']
    by_type = {manager[name]['type']: manager[name] for name in manager['controller_names']}
    assert by_type['FollowJointTrajectory']['joints'] == arm
    assert by_type['ParallelGripperCommand']['joints'] == grippers


@pytest.mark.parametrize('kind, action', [('FollowJointTrajectory', FollowJointTrajectory),
                                          ('ParallelGripperCommand', ParallelGripperCommand)])
def test_each_controller_finds_the_nodes_action(kind: str, action: Any) -> None:
    controllers = yaml.safe_load((MOVEIT / 'moveit_controllers.yaml').read_text())
    manager = controllers['moveit_simple_controller_manager']
    name = next(name for name in manager['controller_names'] if manager[name]['type'] == kind)
    params = arm_params()
    with NodeHarness(params) as h:
        assert h.client is not None
        # MoveIt looks for <controller name>/<action_ns>, under the node's namespace.
        client = ActionClient(h.client.node, action,
                              f'{h.namespace}/{name}/{manager[name]["action_ns"]}')
        assert client.wait_for_server(timeout_sec=10.0), name
