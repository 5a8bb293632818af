"""
The validated configuration: DriverConfig (a field per parameter of PARAMS) and its JointConfigs.

DriverConfig is checked against PARAMS when this module is imported: a parameter in one and not
the other fails at once, by name.
"""

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Dict, Optional, Tuple

from dxl_servo_driver import models
from dxl_servo_driver.config.params import PARAMS


@dataclass(frozen=True)
class JointConfig:
    """One configured joint."""

    name: str
    servo_id: int
    operating_mode: str
    # None: the model's datasheet value (stall torque / stall current at its nominal voltage).
    torque_constant_nm_per_a: Optional[float] = None
    registers: Tuple[Tuple[str, int], ...] = ()
    # The model the servo must be (`<joint>.model`); None: any supported model.
    model: Optional[models.Model] = None
    # A gripper (current_based_position): ~/gripper commands, grasp detection; a ratio goal
    # runs from gripper_open (0) to gripper_closed (1), in rad.
    gripper: bool = False
    gripper_open: float = 0.0
    gripper_closed: float = 0.0
    # Trajectory tolerances of this joint (rad); 0: path not checked, goal the top-level one.
    path_tolerance: float = 0.0
    goal_tolerance: float = 0.0
    # The joint as the robot sees it (models.units.JointFrame) and its limits in joint units
    # (None: the servo's).
    offset: float = 0.0
    reverse: bool = False
    ratio: float = 1.0
    min_position: Optional[float] = None
    max_position: Optional[float] = None
    # A second servo on the joint: its id, whether it turns against the joint, its own offset
    # (None: the joint's), and how far the two may disagree (joint units).
    secondary_id: Optional[int] = None
    secondary_reverse: bool = False
    secondary_offset: Optional[float] = None
    secondary_tolerance: float = 0.1
    # The second servo's own register values, in place of the joint's (`secondary_registers`).
    secondary_registers: Tuple[Tuple[str, int], ...] = ()
    # Set on the secondary's own configuration: the joint it belongs to.
    secondary_of: str = ''
    # The protocol its servo speaks (resolved: the joint's, else its model's, else the bus's).
    protocol: float = 2.0
    # False: passive (read, never torqued). A trigger is held at trigger_position (joint units)
    # with trigger_current (A) in current_based_position; the operator moves it, not ROS.
    torque: bool = True
    trigger: bool = False
    trigger_position: float = 0.0
    trigger_current: float = 0.0
    # A follower's: the leader joint it copies (None: not followed), the leader gripper's
    # travel (None: this gripper's own ends).
    follow: Optional[str] = None
    follow_open: Optional[float] = None
    follow_closed: Optional[float] = None

    def refusal(self) -> str:
        """Return why this joint takes no command ('' when it does): passive, or a trigger."""
        if not self.torque:
            return f'joint {self.name!r} is passive (torque: false)'
        if self.trigger:
            return (f'joint {self.name!r} is a trigger (trigger: true): the operator moves it, '
                    'not ROS')
        return ''

    def secondary(self) -> 'JointConfig':
        """Return the configuration of the joint's second servo (secondary_id must be set)."""
        assert self.secondary_id is not None
        offset = self.offset if self.secondary_offset is None else self.secondary_offset
        own = dict(self.registers)
        own.update(self.secondary_registers)
        return dataclasses.replace(
            self, name=f'{self.name} (secondary)', servo_id=self.secondary_id,
            offset=offset, reverse=self.secondary_reverse, gripper=False, secondary_id=None,
            secondary_of=self.name, registers=tuple(sorted(own.items())))

    def register_dict(self) -> Dict[str, int]:
        """Return the configured registers as a dictionary."""
        return dict(self.registers)

    def register_key(self, register: str) -> str:
        """Return the parameter that sets a register of this servo (for error messages)."""
        if self.secondary_of:
            family = ('secondary_registers' if register in dict(self.secondary_registers)
                      else 'registers')
            return f'{self.secondary_of}.{family}.{register}'
        return f'{self.name}.registers.{register}'

    def position_limits(self) -> Tuple[Optional[float], Optional[float]]:
        """
        Return the lowest and highest position the joint may be sent to (joint units).

        min_position/max_position, narrowed for a gripper to its travel (gripper_open ..
        gripper_closed): in current_based_position the servo takes multi-turn goals, so a
        gripper goal beyond its travel would turn the claw through the mechanism. None: no
        end configured (the servo's own limits apply).
        """
        low, high = self.min_position, self.max_position
        if self.gripper:
            travel_low = min(self.gripper_open, self.gripper_closed)
            travel_high = max(self.gripper_open, self.gripper_closed)
            low = travel_low if low is None else max(low, travel_low)
            high = travel_high if high is None else min(high, travel_high)
        return low, high


@dataclass(frozen=True)
class DriverConfig:
    """A validated configuration: a field for each of PARAMS (defaults there), the joints."""

    port: str
    baud_rate: int
    protocol: float
    loop_rate: float
    state_rate: float
    torque_on_start: bool
    torque_off_on_shutdown: bool
    command_timeout: float
    autostart: bool
    latency_timer: float
    ping_retries: int
    missing_servo: str
    read_retries: int
    read_mode: str
    write_mode: str
    cycle_driver: str
    executor: str
    hardware_error_recovery: bool
    recovery_interval: float
    goal_tolerance: float
    goal_time_tolerance: float
    action_monitor_rate: float
    temperature_warn: float
    temperature_error: float
    voltage_low: float
    voltage_high: float
    follow_topic: str
    follow_engaged: bool
    follow_timeout: float
    follow_max_step: float
    follow_ramp_velocity: float
    follow_engage_tolerance: float
    follow_block_error: float
    follow_block_time: float
    trace: str = ''
    joints: Tuple[JointConfig, ...] = field(default_factory=tuple)

    def joint(self, name: str) -> JointConfig:
        """Return the joint with this name."""
        for joint in self.joints:
            if joint.name == name:
                return joint
        raise KeyError(name)


def field_of(name: str) -> str:
    """Return the DriverConfig field of a parameter (follow.topic is follow_topic)."""
    return name.replace('.', '_')


def replace(config: DriverConfig, **changes: Any) -> DriverConfig:
    """Return the configuration with some top-level values changed (runtime parameters)."""
    return dataclasses.replace(config, **changes)


def _agrees_with_the_table() -> None:
    """
    Raise TypeError at import when DriverConfig's fields and PARAMS disagree.

    PARAMS is the one home of a parameter; DriverConfig is written out field by field so that
    type checkers and readers see each one's type (a class made from the table at run time
    would be Any to mypy). validate() fills it from PARAMS alone, and this check makes a
    parameter added to one and not the other fail at once, by name.
    """
    fields = [(f.name, f.type) for f in dataclasses.fields(DriverConfig) if f.name != 'joints']
    # `joints`, a list of names in the table, is the joints themselves here.
    table = [(field_of(spec.name), spec.kind.__name__) for spec in PARAMS
             if spec.name != 'joints']
    written = [(name, kind if isinstance(kind, str) else kind.__name__) for name, kind in fields]
    apart = sorted(set(table) ^ set(written))
    if apart:
        raise TypeError(f'DriverConfig and config.PARAMS disagree (name or type): {apart}')


_agrees_with_the_table()
