"""
The node's parameters as `ros2 param list/get/describe` show them: every one, with its value.

Every parameter of the table (config.PARAMS, config.JOINT_PARAMS) is declared with its
description; a value the configuration leaves to the servo (the torque constant of the model it
answers with) is shown once configured, and stays the servo's across a reconfigure unless
someone sets it.
"""

from typing import Any, Dict

from dxl_servo_driver.config import JOINT_PARAMS, PARAMS
from dxl_servo_driver.models import model_for, xm430
from lifecycle_msgs.msg import Transition
from node_harness import NodeHarness, sim_params
import pytest

DATASHEET_NM_PER_A = model_for(xm430.MODEL_NUMBER).torque_constant_nm_per_a
JOINTS: Dict[str, Dict[str, Any]] = {
    'arm': {'id': 1, 'operating_mode': 'position', 'registers': {'profile_velocity': 50}},
    'wrist': {'id': 2, 'operating_mode': 'velocity', 'torque_constant': 2.0},
    'hand': {'id': 3, 'operating_mode': 'current_based_position', 'gripper': True,
             'gripper_closed': 1.0},
}


def transitions(h: NodeHarness, *ids: int) -> None:
    for transition in ids:
        assert h.call('change_state', transition=Transition(id=transition)).success


def test_every_parameter_is_listed_with_its_value_and_description() -> None:
    with NodeHarness(sim_params(JOINTS)) as h:
        assert h.node is not None
        node = h.node
        for spec in PARAMS:
            assert node.has_parameter(spec.name), spec.name
            assert node.describe_parameter(spec.name).description.startswith(spec.description)
        for joint, keys in JOINTS.items():
            for spec in JOINT_PARAMS:
                name = f'{joint}.{spec.name}'
                present = not spec.only_for or keys.get(spec.only_for)
                assert node.has_parameter(name) == bool(present), name
            for register, value in keys.get('registers', {}).items():
                assert node.get_parameter(f'{joint}.registers.{register}').value == value
        # The torque constant in use: the datasheet's where the file leaves it to the model.
        assert node.get_parameter('arm.torque_constant').value == pytest.approx(
            DATASHEET_NM_PER_A)
        assert node.get_parameter('wrist.torque_constant').value == 2.0
        assert node.get_parameter('arm.model').value == ''   # any supported model


def test_a_value_shown_from_the_servo_stays_the_servos_until_someone_sets_it() -> None:
    with NodeHarness(sim_params(JOINTS)) as h:
        assert h.node is not None
        h.joint_states.wait(lambda m: len(m.name) == len(JOINTS))
        transitions(h, Transition.TRANSITION_DEACTIVATE, Transition.TRANSITION_CLEANUP,
                    Transition.TRANSITION_CONFIGURE)
        # Configured again: still left to the servo (not taken as the file's value).
        assert h.node.config.joint('arm').torque_constant_nm_per_a is None
        assert h.node.config.joint('wrist').torque_constant_nm_per_a == 2.0
        transitions(h, Transition.TRANSITION_CLEANUP)
        assert h.set_parameter('arm.torque_constant', 1.5).successful
        transitions(h, Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE)
        assert h.node.config.joint('arm').torque_constant_nm_per_a == 1.5
        assert h.node.manager.servos['arm'].units.torque_constant_nm_per_a == 1.5
        assert h.node.get_parameter('arm.torque_constant').value == 1.5


def test_every_runtime_parameter_has_a_change_hook_and_is_set_while_active() -> None:
    """A runtime parameter without its hook once fell through to the diagnostics thresholds."""
    with NodeHarness(sim_params(JOINTS)) as h:
        assert h.node is not None
        h.joint_states.wait(lambda m: len(m.name) == len(JOINTS))
        runtime = {spec.name for spec in PARAMS if spec.runtime}
        assert set(h.node.runtime.hooks()) == runtime
        for spec in PARAMS:
            if not spec.runtime:
                continue
            value = h.node.get_parameter(spec.name).value
            result = h.set_parameter(spec.name, value)
            assert result.successful, (spec.name, result.reason)
        assert h.set_parameter('state_rate', 5.0).successful
        assert h.node.config.state_rate == 5.0
        # A name the table does not have is refused while active (by rclpy: undeclared).
        assert not h.set_parameter('no_such_parameter', 1.0).successful
