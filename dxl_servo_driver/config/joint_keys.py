"""
One joint's keys (`<joint>.<key>`, `<joint>.registers.<name>`) read into a JointConfig, checked.

Each check raises ConfigError naming the key at fault: the joint's own keys against
JOINT_PARAMS, against each other (a gripper's travel, a trigger's current, a second servo's
registers), and against the model the joint names (else the XM430 manual's table).
"""

import dataclasses
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

from dxl_servo_driver import models
from dxl_servo_driver.config.checks import check_spec, check_type, ConfigError
from dxl_servo_driver.config.driver_config import JointConfig
from dxl_servo_driver.config.model_fit import check_registers
from dxl_servo_driver.config.params import JOINT_PARAMS_BY_NAME
from dxl_servo_driver.errors import BadRequest
from dxl_servo_driver.models import xm430
from dxl_servo_driver.protocol import FRAMERS


def _joint_value(params: Mapping[str, Any], name: str, key: str) -> Any:
    """Return `<name>.<key>` checked against its JOINT_PARAMS spec, or the spec's default."""
    spec = JOINT_PARAMS_BY_NAME[key]
    full = f'{name}.{key}'
    if full not in params:
        return spec.default
    return check_spec(spec, params[full], full)


def read_joint(params: Mapping[str, Any], name: str) -> JointConfig:
    """Return the joint its keys describe (its protocol: with_protocol); ConfigError if wrong."""
    if f'{name}.id' not in params:
        raise ConfigError(f'{name}.id', f'joint {name!r} has no id')
    servo_id = _joint_value(params, name, 'id')
    key = f'{name}.model'
    wanted: Optional[models.Model] = None
    if params.get(key, '') != '':   # empty: any supported model
        wanted = _model(key, params[key])
    key = f'{name}.operating_mode'
    mode = _joint_value(params, name, 'operating_mode')
    if key not in params and params.get(f'{name}.trigger') is True:
        mode = 'current_based_position'   # a trigger's, unless the file says another
    if wanted is not None and mode not in wanted.modes:
        raise ConfigError(key, f'{wanted.name} has no {mode} mode (its modes: '
                          f'{", ".join(wanted.modes)})')
    torque_constant: Optional[float] = _joint_value(params, name, 'torque_constant')
    if torque_constant is not None and torque_constant <= 0.0:
        raise ConfigError(f'{name}.torque_constant', f'must be positive, got {torque_constant}')
    gripper = _joint_value(params, name, 'gripper')
    if gripper and mode != 'current_based_position':
        raise ConfigError(f'{name}.gripper', 'a gripper holds with a limited current: its '
                          f'operating_mode must be current_based_position, not {mode}')
    ends = []
    for key in ('gripper_open', 'gripper_closed'):
        if f'{name}.{key}' in params and not gripper:
            raise ConfigError(f'{name}.{key}', f'only a gripper (`{name}.gripper: true`) has '
                              'this')
        ends.append(_joint_value(params, name, key))
    if gripper and ends[0] == ends[1]:
        raise ConfigError(f'{name}.gripper_closed', f'equals gripper_open ({ends[0]:g}): a '
                          'gripper needs its travel (gripper_open .. gripper_closed, joint units)')
    registers = _register_values(params, f'{name}.registers.')
    joint = JointConfig(name, servo_id, mode, torque_constant, tuple(registers), wanted,
                        gripper, ends[0], ends[1], _joint_value(params, name, 'path_tolerance'),
                        _joint_value(params, name, 'goal_tolerance'),
                        *_frame_and_limits(params, name, registers),
                        *_secondary(params, name))
    own = _register_values(params, f'{name}.secondary_registers.')
    joint = dataclasses.replace(joint, secondary_registers=tuple(own))
    limits = [register for register, _ in own
              if register in ('min_position_limit', 'max_position_limit')]
    if limits and (joint.min_position is not None or joint.max_position is not None):
        raise ConfigError(f'{name}.secondary_registers.{limits[0]}', 'give the limits once: '
                          f'{name}.min_position/max_position (joint units) set them for both '
                          'servos, each through its own frame')
    joint = _torque_and_trigger(params, joint, wanted)
    joint = dataclasses.replace(joint, **_follow(params, name, gripper, ends))
    low, high = joint.position_limits()
    if low is not None and high is not None and not low < high:
        raise ConfigError(f'{name}.min_position', 'min_position..max_position leave nothing '
                          f"of the gripper's travel {joint.gripper_open:g}.."
                          f'{joint.gripper_closed:g} (gripper_open..gripper_closed)')
    # Without a model the XM430 manual's table judges the file now (a register only other
    # models have is judged at configure, against the model the servo answers with).
    table = wanted or models.model_for(xm430.MODEL_NUMBER)
    check_registers(joint, table, lenient=wanted is None)
    if joint.secondary_id is not None:
        # What the second servo gets: the joint's registers, its own in their place.
        check_registers(joint.secondary(), table, lenient=wanted is None)
    return joint


def _register_values(params: Mapping[str, Any], prefix: str) -> List[Tuple[str, int]]:
    """Return the (register, raw value) pairs of the keys under prefix, sorted by name."""
    values = []
    for key in sorted(k for k in params if k.startswith(prefix)):
        values.append((key[len(prefix):], check_type(key, params[key], int)))
    return values


def _follow(params: Mapping[str, Any], name: str, gripper: bool,
            ends: Sequence[float]) -> Dict[str, Any]:
    """Return a joint's follow, follow_open and follow_closed (a gripper's: its own ends)."""
    leader: Optional[str] = _joint_value(params, name, 'follow')
    values: Dict[str, Any] = {'follow': name if leader is None else (leader or None)}
    for key in ('follow_open', 'follow_closed'):
        if f'{name}.{key}' in params and not gripper:
            raise ConfigError(f'{name}.{key}', f'only a gripper (`{name}.gripper: true`) has '
                              'this')
        values[key] = _joint_value(params, name, key)
    if (values['follow_open'] is None) != (values['follow_closed'] is None):
        given = 'follow_open' if values['follow_closed'] is None else 'follow_closed'
        raise ConfigError(f'{name}.{given}', 'give both follow_open and follow_closed (the '
                          "leader gripper's travel), or neither")
    if values['follow_open'] is not None and values['follow_open'] == values['follow_closed']:
        raise ConfigError(f'{name}.follow_closed', f'equals follow_open '
                          f"({values['follow_open']:g}): the leader's travel maps onto this "
                          "gripper's")
    if gripper and values['follow_open'] is None:
        values['follow_open'], values['follow_closed'] = ends   # the same travel
    return values


def _torque_and_trigger(params: Mapping[str, Any], joint: JointConfig,
                        wanted: Optional[models.Model]) -> JointConfig:
    """Return the joint with its torque and trigger keys, checked (ConfigError if wrong)."""
    name = joint.name
    torque = _joint_value(params, name, 'torque')
    trigger = _joint_value(params, name, 'trigger')
    for key in ('trigger_position', 'trigger_current'):
        if f'{name}.{key}' in params and not trigger:
            raise ConfigError(f'{name}.{key}', f'only a trigger (`{name}.trigger: true`) has '
                              'this')
    if not trigger:
        return dataclasses.replace(joint, torque=torque)
    if not torque:
        raise ConfigError(f'{name}.torque', 'a trigger is torqued (its motor is the spring): '
                          'leave torque out (true), or make the joint passive without trigger')
    mode = joint.operating_mode
    if f'{name}.operating_mode' not in params:
        mode = 'current_based_position'   # what a trigger runs in; another one given: refused
        if wanted is not None and mode not in wanted.modes:
            raise ConfigError(f'{name}.trigger', 'a trigger runs in current_based_position, '
                              f'which the {wanted.name} has not (its modes: '
                              f'{", ".join(wanted.modes)})')
    elif mode != 'current_based_position':
        raise ConfigError(f'{name}.operating_mode', 'a trigger springs back with a limited '
                          'current: its operating_mode must be current_based_position, not '
                          f'{mode}')
    if joint.secondary_id is not None:
        raise ConfigError(f'{name}.secondary_id', 'a trigger has one servo')
    values = []
    for key in ('trigger_position', 'trigger_current'):
        value = _joint_value(params, name, key)
        if value is None:
            raise ConfigError(f'{name}.{key}', f'a trigger needs {key} (joint {name!r})')
        values.append(value)
    rest, current = values
    low, high = joint.position_limits()
    if (low is not None and rest < low) or (high is not None and rest > high):
        raise ConfigError(f'{name}.trigger_position', f"{rest:g} is beyond the joint's limits "
                          f'{"-inf" if low is None else f"{low:g}"}..'
                          f'{"inf" if high is None else f"{high:g}"}')
    # Against the file's Current Limit, else the pinned model's (the servo's own at configure).
    table = wanted or models.model_for(xm430.MODEL_NUMBER)
    if table.current_unit_a is None or not table.has('goal_current'):
        raise ConfigError(f'{name}.trigger', f'the {table.name} has no current control: a '
                          'trigger needs current_based_position')
    given = joint.register_dict().get('current_limit')
    if given is not None or wanted is not None:
        raw = given if given is not None else table.item('current_limit').maximum
        limit_a = raw * table.current_unit_a
        if current > limit_a + 1e-9:
            where = (f'{name}.registers.current_limit {raw}' if given is not None
                     else f"the {table.name}'s Current Limit")
            raise ConfigError(f'{name}.trigger_current', f'{current:g} A is above {where} '
                              f'({limit_a:.4g} A)')
    return dataclasses.replace(joint, operating_mode=mode, trigger=True, trigger_position=rest,
                               trigger_current=current)


def with_protocol(joint: JointConfig, params: Mapping[str, Any],
                  bus_protocol: float) -> JointConfig:
    """Return the joint with the protocol its servo speaks; ConfigError if its model cannot."""
    key = f'{joint.name}.protocol'
    given: Optional[float] = _joint_value(params, joint.name, 'protocol')
    model = joint.model
    protocol = given if given is not None else (
        1.0 if model is not None and model.protocol == 1.0 else bus_protocol)
    # A model speaks the protocol of its table, and another only through its Protocol Type
    # register (protocol_version).
    if model is not None and protocol != model.protocol and not model.has('protocol_version'):
        raise ConfigError(key if given is not None else 'protocol',
                          f'{model.name} speaks Protocol {model.protocol} only '
                          f'(joint {joint.name!r})')
    # A register the protocol's packets cannot address (1.0's one-byte addresses) is refused now.
    framer = FRAMERS[protocol]
    table = model or models.model_for(xm430.MODEL_NUMBER)
    for register, _ in joint.registers:
        if not table.has(register):
            continue
        item = table.item(register)
        try:
            framer.address_param(item.address, item.size)
        except BadRequest:
            raise ConfigError(f'{joint.name}.registers.{register}',
                              f'address {item.address} is beyond the reach of Protocol '
                              f'{protocol} (one-byte addresses)') from None
    return dataclasses.replace(joint, protocol=protocol)


def _secondary(params: Mapping[str, Any], name: str) -> Tuple[Any, ...]:
    """Return (secondary_id or None, reverse, offset, tolerance) of a joint."""
    servo_id = _joint_value(params, name, 'secondary_id')
    return (None if servo_id == -1 else servo_id,
            *[_joint_value(params, name, key)
              for key in ('secondary_reverse', 'secondary_offset', 'secondary_tolerance')])


def _frame_and_limits(params: Mapping[str, Any], name: str,
                      registers: Sequence[Tuple[str, int]]) -> Tuple[Any, ...]:
    """Return (offset, reverse, ratio, min_position, max_position) of a joint, checked."""
    values = [_joint_value(params, name, key)
              for key in ('offset', 'reverse', 'ratio', 'min_position', 'max_position')]
    low, high = values[3], values[4]
    if low is not None and high is not None and not low < high:
        raise ConfigError(f'{name}.min_position', f'{low} is not below max_position {high}')
    if low is not None or high is not None:
        given = [register for register, _ in registers
                 if register in ('min_position_limit', 'max_position_limit')]
        if given:
            raise ConfigError(f'{name}.registers.{given[0]}', 'give the limits once: '
                              f'{name}.min_position/max_position (joint units) set them')
    return tuple(values)


def _model(key: str, value: Any) -> models.Model:
    """Return the model a `<joint>.model` value names (a name such as XL430-W250, or a number)."""
    if isinstance(value, bool) or not isinstance(value, (int, str)):
        raise ConfigError(key, f'expected a model name (e.g. XL430-W250) or number, got {value!r}')
    try:
        if isinstance(value, int) or value.strip().isdigit():
            return models.model_for(int(value))
        return models.model_named(value)
    except models.ModelError as exc:
        raise ConfigError(key, str(exc)) from None
