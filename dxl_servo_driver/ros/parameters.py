"""
The node's parameters on the ROS side: declarations, coercion, which change is taken when.

Runtime parameters (loop_rate, state_rate, command_timeout, thresholds) change while the node
runs. The others are read at configure: they may be set while the node is unconfigured (after
cleanup), and the next configure uses them; while configured they are refused with the reason.
`joints` fixes which joint parameters exist: it needs a restart.
"""

from typing import Any, Dict, List, Mapping

from dxl_servo_driver import config as cfg
from dxl_servo_driver.errors import Refused
from rcl_interfaces.msg import (
    FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType)
from rclpy.exceptions import InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

_PARAM_TYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
                float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING,
                list: ParameterType.PARAMETER_STRING_ARRAY}
AT_CONFIGURE = ' Read at configure (settable while unconfigured).'


def descriptor(spec: cfg.ParamSpec) -> ParameterDescriptor:
    """Return the descriptor `ros2 param describe` shows for a parameter of the table."""
    text = spec.description + (f' [{spec.unit}]' if spec.unit else '')
    if spec.restart:
        text += ' Fixed until a restart.'
    elif not spec.runtime:
        text += AT_CONFIGURE
    if spec.choices:
        text += f' One of: {", ".join(str(c) for c in spec.choices)}.'
    result = ParameterDescriptor(description=text, type=_PARAM_TYPES[spec.kind],
                                 read_only=spec.restart)
    if spec.choices:
        result.additional_constraints = f'one of {list(spec.choices)}'
    if spec.minimum is not None and spec.maximum is not None:
        if spec.kind is float:
            result.floating_point_range = [FloatingPointRange(
                from_value=float(spec.minimum), to_value=float(spec.maximum))]
        elif spec.kind is int:
            result.integer_range = [IntegerRange(
                from_value=int(spec.minimum), to_value=int(spec.maximum))]
    return result


def _redeclare(node: Node, name: str, value: Any, desc: ParameterDescriptor) -> None:
    if node.has_parameter(name):
        node.undeclare_parameter(name)
    node.declare_parameter(name, value, desc, ignore_override=True)


def declare(node: Node, config: cfg.DriverConfig) -> None:
    """
    Re-declare every parameter with its value, description and range (ros2 param describe).

    A value the configuration leaves to the servo (the torque constant of the model it answers
    with) is declared once it is known (show_from_servos).
    """
    for spec in cfg.PARAMS:
        value = getattr(config, cfg.field_of(spec.name)) if spec.name != 'joints' else [
            joint.name for joint in config.joints]
        _redeclare(node, spec.name, value, descriptor(spec))
    for joint in config.joints:
        values = _joint_values(joint)
        for spec in cfg.JOINT_PARAMS:
            if spec.only_for and values.get(spec.only_for) in (None, False, -1):
                continue
            value = values[spec.name]
            if value is not None:   # else a value only the servo gives: declared once known
                _redeclare(node, f'{joint.name}.{spec.name}', value, descriptor(spec))
        for family, given in (('registers', joint.registers),
                              ('secondary_registers', joint.secondary_registers)):
            whose = ' to the second servo' if family == 'secondary_registers' else ''
            for register, value in given:
                item = cfg.describe_register(joint, register)
                _redeclare(node, f'{joint.name}.{family}.{register}', value, ParameterDescriptor(
                    description=f'{item.description} at address {item.address}, raw '
                                f'[{item.unit or "count"}], {item.minimum}..{item.maximum}, '
                                f'{item.area.upper()}; applied at configure{whose}.'
                                + AT_CONFIGURE,
                    type=ParameterType.PARAMETER_INTEGER))


def show_from_servos(node: Node, values: Mapping[str, Any]) -> None:
    """
    Declare the values in use that the configuration left to the servos (by full name).

    A value outside its parameter's range (a gripper's multi-turn reach in radians, say) is
    not shown: ros2 param get then says it is not set, and nothing else changes.
    """
    for name, value in values.items():
        try:
            _redeclare(node, name, value,
                       descriptor(cfg.JOINT_PARAMS_BY_NAME[name.split('.')[-1]]))
        except InvalidParameterValueException:
            node.get_logger().info(f'{name} in use is {value:g}, outside what the parameter '
                                   'can show')


def _joint_values(joint: cfg.JointConfig) -> Dict[str, Any]:
    """Return a joint's configured value of each JOINT_PARAMS key (None: left to the servo)."""
    return {'id': joint.servo_id, 'operating_mode': joint.operating_mode,
            'protocol': joint.protocol,
            'model': joint.model.name if joint.model is not None else '',
            'torque_constant': joint.torque_constant_nm_per_a, 'gripper': joint.gripper,
            'gripper_open': joint.gripper_open, 'gripper_closed': joint.gripper_closed,
            'path_tolerance': joint.path_tolerance, 'goal_tolerance': joint.goal_tolerance,
            'offset': joint.offset, 'reverse': joint.reverse, 'ratio': joint.ratio,
            'min_position': joint.min_position, 'max_position': joint.max_position,
            'secondary_id': -1 if joint.secondary_id is None else joint.secondary_id,
            'secondary_reverse': joint.secondary_reverse,
            'secondary_offset': (joint.offset if joint.secondary_offset is None
                                 else joint.secondary_offset),
            'secondary_tolerance': joint.secondary_tolerance,
            'torque': joint.torque, 'trigger': joint.trigger,
            'trigger_position': joint.trigger_position, 'trigger_current': joint.trigger_current,
            'follow': joint.follow or '', 'follow_open': joint.follow_open,
            'follow_closed': joint.follow_closed}


def coerce(params: List[Parameter]) -> List[Parameter]:
    """Return the parameters with integers given to double parameters made doubles."""
    # `ros2 param set ... loop_rate 50` sends an integer: a number is a number.
    out = []
    for param in params:
        spec = cfg.PARAMS_BY_NAME.get(param.name)
        if spec is not None and spec.kind is float and param.type_ == Parameter.Type.INTEGER:
            param = Parameter(param.name, Parameter.Type.DOUBLE, float(param.value))
        out.append(param)
    return out


def check_changes(params: List[Parameter], lifecycle_state: str,
                  thresholds: Mapping[str, float]) -> Dict[str, Any]:
    """
    Return the runtime changes of a parameter set; DriverError (nothing changes) when refused.

    Unconfigured, any parameter but `joints` is accepted as it is given (configure checks
    the whole configuration and says what is wrong); otherwise only runtime ones, checked.
    """
    changes: Dict[str, Any] = {}
    for param in params:
        spec = cfg.PARAMS_BY_NAME.get(param.name)
        if spec is not None and spec.restart:
            raise Refused(f'{param.name} cannot be changed while the node runs (restart it)')
        if spec is None or not spec.runtime:
            if lifecycle_state == 'unconfigured':
                continue
            raise Refused(f'{param.name} is read at configure: change it while the node is '
                          f'unconfigured (it is {lifecycle_state}; cleanup first), or restart it')
        changes[param.name] = cfg.check_spec(spec, param.value)
    merged = dict(thresholds)
    merged.update({k: v for k, v in changes.items() if k in merged})
    cfg.check_thresholds(merged)
    return changes
