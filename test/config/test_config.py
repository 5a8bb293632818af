"""Configuration validation: every invalid case names its key; the parameter table is one."""

import dataclasses
from typing import Any, Dict

from dxl_servo_driver.config import (
    ConfigError, DriverConfig, field_of, JOINT_PARAMS, JOINT_PARAMS_BY_NAME, PARAMS,
    RUNTIME_PARAMS, THRESHOLDS, validate)
from dxl_servo_driver.models.names import OTHER_MODELS
from dxl_servo_driver.tool.yaml_edit import flatten
import pytest

# A model still refused (by its name), whichever names.py has left.
REFUSED = min(OTHER_MODELS)


def base() -> Dict[str, Any]:
    return {
        'port': 'sim', 'baud_rate': 1000000, 'joints': ['arm', 'wheel'],
        'arm.id': 1, 'arm.operating_mode': 'position',
        'arm.registers.profile_velocity': 100, 'arm.registers.return_delay_time': 0,
        'wheel.id': 2, 'wheel.operating_mode': 'velocity',
    }


def test_a_valid_file_gives_its_joints_in_order() -> None:
    config = validate(base())
    assert [j.name for j in config.joints] == ['arm', 'wheel']
    assert config.joint('arm').servo_id == 1
    assert config.joint('arm').register_dict() == {'profile_velocity': 100,
                                                   'return_delay_time': 0}
    assert config.joint('wheel').operating_mode == 'velocity'
    assert config.baud_rate == 1000000
    assert config.loop_rate == 100.0       # default


def test_integer_loop_rate_is_accepted_as_a_number() -> None:
    params = base()
    params['loop_rate'] = 250
    assert validate(params).loop_rate == 250.0


def test_operating_mode_defaults_to_position() -> None:
    params = base()
    del params['arm.operating_mode']
    assert validate(params).joint('arm').operating_mode == 'position'


@pytest.mark.parametrize('change, key, words', [
    # duplicate id
    ({'wheel.id': 1}, 'wheel.id', 'already used'),
    # duplicate name
    ({'joints': ['arm', 'arm']}, 'joints', 'twice'),
    # id out of range
    ({'arm.id': 253}, 'arm.id', '0..252'),
    ({'arm.id': -1}, 'arm.id', '0..252'),
    # unknown mode
    ({'arm.operating_mode': 'torque'}, 'arm.operating_mode', 'unknown operating mode'),
    # unknown register
    ({'arm.registers.goal_speed': 3}, 'arm.registers.goal_speed', 'unknown register'),
    # read-only register
    ({'arm.registers.present_position': 3}, 'arm.registers.present_position', 'read-only'),
    # register the driver owns
    ({'arm.registers.torque_enable': 1}, 'arm.registers.torque_enable', 'managed by the driver'),
    # value out of the register's range
    ({'arm.registers.return_delay_time': 255}, 'arm.registers.return_delay_time', 'range'),
    ({'arm.registers.position_p_gain': 40000}, 'arm.registers.position_p_gain', 'range'),
    # a value beyond its limit register in the same file
    ({'arm.registers.velocity_limit': 50}, 'arm.registers.profile_velocity', 'exceeds'),
    # baud not in the table
    ({'baud_rate': 250001}, 'baud_rate', 'not one of'),
    # missing id
    ({'arm.id': None}, 'arm.id', 'no id'),
    # wrong types
    ({'arm.id': 'one'}, 'arm.id', 'integer'),
    ({'loop_rate': 'fast'}, 'loop_rate', 'number'),
    ({'torque_on_start': 'yes'}, 'torque_on_start', 'true or false'),
    ({'arm.registers.profile_velocity': 1.5}, 'arm.registers.profile_velocity', 'integer'),
    # ranges of the node's own parameters
    ({'loop_rate': 0.0}, 'loop_rate', 'minimum'),
    ({'command_timeout': -1.0}, 'command_timeout', 'minimum'),
    ({'missing_servo': 'ignore'}, 'missing_servo', 'not one of'),
    # empty or unknown joints
    ({'joints': []}, 'joints', 'no joints'),
    ({'joints': ['arm', '']}, 'joints', 'invalid joint name'),
    ({'elbow.id': 3}, 'elbow.id', 'unknown parameter'),
    ({'arm.gain': 3}, 'arm.gain', 'unknown joint parameter'),
    ({'arm.torque_constant': 0.0}, 'arm.torque_constant', 'positive'),
    # position limits crossed, a homing offset position mode ignores
    ({'arm.registers.min_position_limit': 3000, 'arm.registers.max_position_limit': 1000},
     'arm.registers.min_position_limit', 'above'),
    ({'arm.registers.homing_offset': 2000}, 'arm.registers.homing_offset', '1024'),
    # models: unknown names and numbers, modes and registers the named model lacks
    ({'arm.model': 'XM999-W1'}, 'arm.model', 'no supported model is named'),
    ({'arm.model': REFUSED}, 'arm.model', OTHER_MODELS[REFUSED][0]),
    ({'arm.model': True}, 'arm.model', 'model name'),
    ({'wheel.model': 'XL430-W250', 'wheel.operating_mode': 'current'}, 'wheel.operating_mode',
     'has no current mode'),
    ({'wheel.model': 'XL430-W250', 'wheel.registers.current_limit': 100},
     'wheel.registers.current_limit', 'unknown register'),
    # a protocol the model cannot speak (it has no Protocol Type register to switch)
    ({'wheel.model': 'AX-12A', 'wheel.protocol': 2.0}, 'wheel.protocol',
     'AX-12A speaks Protocol 1.0 only'),
    ({'wheel.model': 'H54-200-S500-R', 'wheel.protocol': 1.0}, 'wheel.protocol',
     'H54-200-S500-R speaks Protocol 2.0 only'),
    ({'arm.registers.external_port_mode_9': 1}, 'arm.registers.external_port_mode_9',
     'unknown register'),
    # grippers hold with a limited current: current_based_position only
    ({'arm.gripper': True}, 'arm.gripper', 'current_based_position'),
    ({'arm.gripper_closed': 1.0}, 'arm.gripper_closed', 'only a gripper'),
    ({'arm.gripper': 'yes'}, 'arm.gripper', 'true or false'),
])
def test_invalid_configuration_names_the_key(change: Dict[str, Any], key: str,
                                             words: str) -> None:
    params = base()
    for name, value in change.items():
        if value is None:
            params.pop(name)
        else:
            params[name] = value
    with pytest.raises(ConfigError) as info:
        validate(params)
    assert info.value.key == key
    assert key in str(info.value)
    assert words in str(info.value)


def test_models_and_grippers_are_read() -> None:
    params = base()
    params.update({'wheel.model': 'xl430-w250-t', 'arm.model': 1120,
                   'arm.registers.external_port_mode_1': 1,
                   'arm.operating_mode': 'current_based_position', 'arm.gripper': True,
                   'arm.gripper_closed': 1.2})
    config = validate(params)
    assert config.joint('wheel').model.name == 'XL430-W250'
    arm = config.joint('arm')
    assert arm.model.name == 'XM540-W270' and arm.register_dict()['external_port_mode_1'] == 1
    assert (arm.gripper, arm.gripper_open, arm.gripper_closed) == (True, 0.0, 1.2)
    assert arm.torque_constant_nm_per_a is None   # the model's datasheet value at configure
    # A register only other models have passes the file without a model (judged at configure).
    params = base()
    params['arm.registers.external_port_mode_1'] = 1
    assert validate(params).joint('arm').register_dict()['external_port_mode_1'] == 1


def test_every_parameter_has_a_description_and_a_valid_default() -> None:
    for spec in PARAMS:
        assert len(spec.description) > 20, spec.name
        if spec.choices:
            assert spec.default in spec.choices, spec.name
        if spec.minimum is not None:
            assert spec.minimum <= spec.default <= spec.maximum, spec.name


@pytest.mark.parametrize('name', ['sim.yaml', 'example.yaml', 'arm_sim.yaml'])
def test_shipped_parameter_files_are_valid(name: str) -> None:
    import pathlib
    import yaml
    path = pathlib.Path(__file__).resolve().parents[2] / 'config' / name
    tree = yaml.safe_load(path.read_text())
    config = validate(flatten(tree['/**']['ros__parameters']))
    assert len(config.joints) >= 3
    modes = {joint.operating_mode for joint in config.joints}
    if name != 'arm_sim.yaml':   # an arm: position joints and a gripper
        assert len(modes) == len(config.joints), 'the shipped files show one mode per joint'


def test_the_configuration_has_a_field_for_each_parameter_of_the_table() -> None:
    fields = {field.name for field in dataclasses.fields(DriverConfig)}
    # A dotted name (follow.topic) is the field follow_topic.
    assert fields == {field_of(spec.name) for spec in PARAMS}
    # What is taken when comes from the table too.
    assert set(RUNTIME_PARAMS) >= set(THRESHOLDS) and 'loop_rate' in RUNTIME_PARAMS
    assert [spec.name for spec in PARAMS if spec.restart] == ['joints']


def test_joint_parameters_are_checked_by_their_specs() -> None:
    for spec in JOINT_PARAMS:
        assert len(spec.description) > 20, spec.name
    assert validate(base()).joint('arm').operating_mode == JOINT_PARAMS_BY_NAME[
        'operating_mode'].default
    params = base()
    params['arm.model'] = ''   # empty: any model, as the node declares it when unset
    assert validate(params).joint('arm').model is None


def test_a_parameter_in_the_table_and_not_in_driverconfig_fails_by_name(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from dxl_servo_driver.config import driver_config
    driver_config._agrees_with_the_table()   # as imported: they agree
    last = driver_config.PARAMS[-1]
    monkeypatch.setattr(driver_config, 'PARAMS', driver_config.PARAMS[:-1])
    with pytest.raises(TypeError, match=last.name):
        driver_config._agrees_with_the_table()
