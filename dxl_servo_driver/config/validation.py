"""
validate(): the flat parameter dictionary of a ROS parameter file made a DriverConfig, or refused.

It takes `joints`, `<joint>.id`, `<joint>.registers.<name>`, ... and returns a DriverConfig, or
raises ConfigError naming the offending key. It runs before the bus is touched, so a bad file
never moves a servo.
"""

from typing import Any, Dict, List, Mapping

from dxl_servo_driver.config.checks import check_spec, check_thresholds, ConfigError
from dxl_servo_driver.config.driver_config import DriverConfig, field_of
from dxl_servo_driver.config.joint_keys import read_joint, with_protocol
from dxl_servo_driver.config.params import (
    JOINT_KEYS, PARAMS, PARAMS_BY_NAME, REGISTER_FAMILIES, ROS_PARAMS)


def validate(params: Mapping[str, Any]) -> DriverConfig:
    """Return the configuration these parameters describe; ConfigError names the bad key."""
    values: Dict[str, Any] = {}
    for spec in PARAMS:
        if spec.name in params:
            values[field_of(spec.name)] = check_spec(spec, params[spec.name])
        else:
            values[field_of(spec.name)] = spec.default
    joint_names: List[str] = values.pop('joints')
    if not joint_names:
        raise ConfigError('joints', 'no joints configured (a list of joint names is required)')
    seen_names = set()
    for name in joint_names:
        if not name or '.' in name or name.strip() != name:
            raise ConfigError('joints', f'invalid joint name {name!r}')
        if name in seen_names:
            raise ConfigError('joints', f'joint {name!r} is listed twice')
        seen_names.add(name)
    check_thresholds(values)
    _reject_unknown_keys(params, seen_names)
    joints = []
    ids: Dict[int, str] = {}
    for name in joint_names:
        joint = with_protocol(read_joint(params, name), params, values['protocol'])
        for key, servo_id in (('id', joint.servo_id), ('secondary_id', joint.secondary_id)):
            if servo_id is None:
                continue
            if servo_id in ids:
                raise ConfigError(f'{name}.{key}', f'id {servo_id} is already used by joint '
                                  f'{ids[servo_id]!r}')
            ids[servo_id] = name
        if joint.secondary_id is None:
            given = [key for key in params if key.startswith(f'{name}.secondary_registers.')]
            for key in ('secondary_reverse', 'secondary_offset', 'secondary_tolerance'):
                if f'{name}.{key}' in params:
                    given.insert(0, f'{name}.{key}')
            if given:
                raise ConfigError(given[0], f'only a joint with a {name}.secondary_id has this')
        elif joint.gripper:
            raise ConfigError(f'{name}.secondary_id', 'a gripper has one servo')
        joints.append(joint)
    return DriverConfig(joints=tuple(joints), **values)


def _reject_unknown_keys(params: Mapping[str, Any], joint_names: set) -> None:
    for key in params:
        if key in PARAMS_BY_NAME or key in ROS_PARAMS or key.startswith('qos_overrides.'):
            continue
        head, _, rest = key.partition('.')
        if head not in joint_names:
            raise ConfigError(key, 'unknown parameter (not a driver parameter, and '
                              f'{head!r} is not in joints)')
        if rest in JOINT_KEYS or any(rest.startswith(f'{family}.')
                                     for family, _ in REGISTER_FAMILIES):
            continue
        raise ConfigError(key, f'unknown joint parameter {rest!r} (expected one of '
                          f'{list(JOINT_KEYS)}, registers.<name> or '
                          'secondary_registers.<name>)')
