"""
The node's parameters on the ROS side: declarations, coercion, which change is taken when.

Runtime parameters (loop_rate, state_rate, command_timeout, thresholds) change while the node
runs. The others are read at configure: they may be set while the node is unconfigured (after
cleanup), and the next configure uses them; while configured they are refused with the reason.
`joints` fixes which joint parameters exist: it needs a restart.
"""

from typing import Any, Dict, List, Mapping, Optional, Tuple

from dxl_servo_driver import config as cfg
from dxl_servo_driver.models import modes
from rcl_interfaces.msg import (
    FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType)
from rclpy.node import Node
from rclpy.parameter import Parameter

# Parameters that may change while the node runs; the others are read at configure.
RUNTIME_PARAMS = ('loop_rate', 'state_rate', 'command_timeout', 'goal_tolerance',
                  'temperature_warn', 'temperature_error', 'voltage_low', 'voltage_high')
THRESHOLDS = RUNTIME_PARAMS[4:]
RESTART_PARAMS = ('joints',)
_PARAM_TYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
                float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING,
                list: ParameterType.PARAMETER_STRING_ARRAY}


def descriptor(spec: cfg.ParamSpec, read_only: bool) -> ParameterDescriptor:
    """Return the descriptor `ros2 param describe` shows for a top-level parameter."""
    text = spec.description + (f' [{spec.unit}]' if spec.unit else '')
    if spec.name not in RUNTIME_PARAMS and not read_only:
        text += ' Read at configure (settable while unconfigured).'
    if spec.choices:
        text += f' One of: {", ".join(str(c) for c in spec.choices)}.'
    result = ParameterDescriptor(description=text, type=_PARAM_TYPES[spec.kind],
                                 read_only=read_only)
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
    """Re-declare every parameter with its description and range (ros2 param describe)."""
    for spec in cfg.PARAMS:
        value = getattr(config, spec.name) if spec.name != 'joints' else [
            joint.name for joint in config.joints]
        _redeclare(node, spec.name, value, descriptor(spec, spec.name in RESTART_PARAMS))
    for joint in config.joints:
        entries = [
            ('id', joint.servo_id, "Dynamixel id of the joint's servo (0..252).",
             ParameterType.PARAMETER_INTEGER),
            ('operating_mode', joint.operating_mode,
             f'Operating mode at start: one of {", ".join(modes.NAMES)}.',
             ParameterType.PARAMETER_STRING),
        ]
        if joint.torque_constant_nm_per_a is not None:
            entries.append(
                ('torque_constant', joint.torque_constant_nm_per_a,
                 "Effort = current x this [N*m/A]; unset: the model's datasheet stall "
                 'torque / stall current (seed: 4.1 N*m at 2.3 A).',
                 ParameterType.PARAMETER_DOUBLE))
        if joint.gripper:
            entries += [
                ('gripper', True, 'A gripper: ~/gripper commands, grasp detection.',
                 ParameterType.PARAMETER_BOOL),
                ('gripper_open', joint.gripper_open, 'Position of ratio 0 (open), rad.',
                 ParameterType.PARAMETER_DOUBLE),
                ('gripper_closed', joint.gripper_closed, 'Position of ratio 1 (closed), rad.',
                 ParameterType.PARAMETER_DOUBLE)]
        if joint.model is not None:
            entries.append(
                ('model', joint.model.name,
                 'The model the servo must be (name or number); another is refused.',
                 ParameterType.PARAMETER_STRING))
        for register, value in joint.registers:
            item = cfg.describe_register(joint, register)
            entries.append((f'registers.{register}', value,
                            f'{item.description} at address {item.address}, raw '
                            f'[{item.unit or "count"}], {item.minimum}..{item.maximum}, '
                            f'{item.area.upper()}; applied at configure.',
                            ParameterType.PARAMETER_INTEGER))
        for key, value, text, kind in entries:
            _redeclare(node, f'{joint.name}.{key}', value, ParameterDescriptor(
                description=text + ' Read at configure (settable while unconfigured).',
                type=kind))


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
                  thresholds: Mapping[str, float]
                  ) -> Tuple[Optional[str], Dict[str, Any]]:
    """
    Return (reason, runtime changes): a reason when the set is refused (nothing changes).

    Unconfigured, any parameter but `joints` is accepted as it is given (configure checks
    the whole configuration and says what is wrong); otherwise only runtime ones, checked.
    """
    changes: Dict[str, Any] = {}
    for param in params:
        if param.name in RESTART_PARAMS:
            return f'{param.name} cannot be changed while the node runs (restart it)', {}
        if param.name not in RUNTIME_PARAMS:
            if lifecycle_state == 'unconfigured':
                continue
            return (f'{param.name} is read at configure: change it while the node is '
                    f'unconfigured (it is {lifecycle_state}; cleanup first), or restart it'), {}
        spec = cfg.PARAMS_BY_NAME[param.name]
        try:
            changes[param.name] = cfg.check_spec(spec, param.value)
        except cfg.ConfigError as exc:
            return str(exc), {}
    merged = dict(thresholds)
    merged.update({k: v for k, v in changes.items() if k in merged})
    try:
        cfg.check_thresholds(merged)
    except cfg.ConfigError as exc:
        return str(exc), {}
    return None, changes
