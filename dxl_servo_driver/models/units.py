"""
SI conversions of one model's registers (REP 103 on the ROS side), as pure arithmetic.

Every conversion comes as a pair (raw -> SI, SI -> raw) so the two can never drift apart.
Effort is what the servo can tell of its output torque: Present Current times the torque
constant where it senses current, Present Load (a share of the stall torque) where that is
all it has (XL430/XC430).

A joint need not be the servo's angle: `JointFrame` (offset, reverse, ratio) turns the servo's
radians into the joint's units, joint = (-1 if reverse else 1) * ratio * (servo - offset), and
every position, velocity and effort conversion of a joint's Units goes through it; currents,
PWM and voltages stay the servo's.
"""

from dataclasses import dataclass, field
import math
from typing import Callable

from dxl_servo_driver.models.base import Model

__all__ = ['CommandKind', 'JointFrame', 'Units', 'units_for']

_RPM_TO_RAD_S = 2.0 * math.pi / 60.0


@dataclass(frozen=True)
class CommandKind:
    """One kind of goal a joint accepts: its register, SI unit and conversions."""

    name: str
    register: str
    unit: str
    to_raw: Callable[[float], int]
    to_si: Callable[[int], float]


@dataclass(frozen=True)
class JointFrame:
    """Where a joint's 0 is in the servo's radians, whether it turns against it, its ratio."""

    offset_rad: float = 0.0
    reverse: bool = False
    # Joint units (rad or m) per servo radian: a 1:3 gearbox 1/3, a rack and pinion in m/rad.
    ratio: float = 1.0

    @property
    def scale(self) -> float:
        """Return joint units per servo radian, signed."""
        return -self.ratio if self.reverse else self.ratio


IDENTITY = JointFrame()


@dataclass(frozen=True)
class Units:
    """The unit of each register of one model, and the effort scale of one joint."""

    model: Model
    torque_constant_nm_per_a: float
    rad_per_pulse: float
    zero_raw: int
    pulses_per_rev: float
    rad_s_per_velocity_raw: float
    a_per_current_raw: float | None
    pwm_full_raw: int
    v_per_voltage_raw: float
    effort_register: str
    effort_nm_per_raw: float   # the joint's effort (N*m, or N on a linear joint) per raw
    frame: JointFrame = IDENTITY
    kinds: dict[str, CommandKind] = field(default_factory=dict, compare=False, hash=False)

    # position ----------------------------------------------------------------------------
    def position_to_rad(self, raw: int) -> float:
        """Return a position register value (pulses) as the joint's position (rad or m)."""
        frame = self.frame
        return frame.scale * ((raw - self.zero_raw) * self.rad_per_pulse - frame.offset_rad)

    def position_from_rad(self, rad: float) -> int:
        """Return the position register value (pulses) nearest to a joint position."""
        frame = self.frame
        servo_rad = rad / frame.scale + frame.offset_rad
        return int(round(servo_rad / self.rad_per_pulse)) + self.zero_raw

    def reinit_position(self, present_raw: int, homing_offset: int) -> int:
        """
        Return Present Position after the servo re-initialises it (torque on, mode change).

        The XM430 manual: it becomes the position within one turn plus the Homing Offset.
        """
        return int((present_raw - homing_offset) % self.pulses_per_rev) + homing_offset

    def kept_turns(self, before_raw: int, after_raw: int) -> int:
        """Return the whole turns (in pulses) a re-initialisation took from before_raw."""
        turn = self.pulses_per_rev
        return int(round(round((before_raw - after_raw) / turn) * turn))

    # velocity, current, pwm, voltage, effort -----------------------------------------------
    def velocity_to_rad_s(self, raw: int) -> float:
        """Return a velocity register value as the joint's velocity (rad/s or m/s)."""
        return raw * self.rad_s_per_velocity_raw * self.frame.scale

    def velocity_from_rad_s(self, rad_s: float) -> int:
        """Return the velocity register value nearest to a joint velocity."""
        return int(round(rad_s / self.frame.scale / self.rad_s_per_velocity_raw))

    @property
    def joint_nm_per_a(self) -> float:
        """Return the joint's effort per ampere, signed (the servo's torque through the frame)."""
        # Power through the joint: effort_joint * v_joint = torque_servo * v_servo.
        return self.torque_constant_nm_per_a / self.frame.scale

    def current_to_a(self, raw: int) -> float:
        """Return a current register value in amperes (NaN on a model without current)."""
        if self.a_per_current_raw is None:
            return math.nan
        return raw * self.a_per_current_raw

    def current_from_a(self, amps: float) -> int:
        """Return the current register value nearest to a current in amperes."""
        if self.a_per_current_raw is None:
            raise ValueError(f'{self.model.label} senses no current')
        return int(round(amps / self.a_per_current_raw))

    def pwm_to_ratio(self, raw: int) -> float:
        """Return a PWM register value as a ratio of full output (-1..1)."""
        return raw / self.pwm_full_raw

    def pwm_from_ratio(self, ratio: float) -> int:
        """Return the PWM register value nearest to a ratio of full output."""
        return int(round(ratio * self.pwm_full_raw))

    def voltage_to_v(self, raw: int) -> float:
        """Return a voltage register value in volts."""
        return raw * self.v_per_voltage_raw

    def effort_to_nm(self, raw: int) -> float:
        """Return the effort register's value (current or load) as a torque in N*m."""
        return raw * self.effort_nm_per_raw


def units_for(model: Model, torque_constant_nm_per_a: float | None = None,
              frame: JointFrame = IDENTITY) -> Units:
    """
    Return the units of a model for a joint; the torque constant defaults to the datasheet's.

    The datasheet constant is stall torque over stall current at the nominal voltage, gear
    and friction included: what a joint's effort means at its output.
    """
    kt = (model.torque_constant_nm_per_a if torque_constant_nm_per_a is None
          else float(torque_constant_nm_per_a))
    if model.current_unit_a is not None:
        effort_register = 'present_current'
        effort_scale = model.current_unit_a * kt
    elif model.load_unit_ratio is not None:
        effort_register = 'present_load'
        effort_scale = model.load_unit_ratio * model.stall_torque_nm
    else:
        raise ValueError(f'{model.label} reports neither current nor load')
    units = Units(
        model=model, torque_constant_nm_per_a=kt,
        rad_per_pulse=2.0 * math.pi / model.pulses_per_rev, zero_raw=model.position_zero_raw,
        pulses_per_rev=model.pulses_per_rev,
        rad_s_per_velocity_raw=model.velocity_unit_rpm * _RPM_TO_RAD_S,
        a_per_current_raw=model.current_unit_a, pwm_full_raw=model.pwm_full_raw,
        v_per_voltage_raw=model.voltage_unit_v, effort_register=effort_register,
        effort_nm_per_raw=effort_scale / frame.scale, frame=frame)
    kinds = {
        'position': CommandKind('position', 'goal_position', 'rad', units.position_from_rad,
                                units.position_to_rad),
        'velocity': CommandKind('velocity', 'goal_velocity', 'rad/s', units.velocity_from_rad_s,
                                units.velocity_to_rad_s),
        'pwm': CommandKind('pwm', 'goal_pwm', 'ratio', units.pwm_from_ratio, units.pwm_to_ratio),
    }
    if model.has('goal_current') and model.current_unit_a is not None:
        kinds['current'] = CommandKind('current', 'goal_current', 'A', units.current_from_a,
                                       units.current_to_a)
    units.kinds.update(kinds)
    return units
