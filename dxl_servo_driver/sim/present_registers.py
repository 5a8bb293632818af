"""
What one simulated servo reports of its physics: the present registers and the detected errors.

ServoDynamics (dynamics.py) calls PresentRegisters.publish at the end of every advance(): the
horn, the motor and the controllers' trajectories turned into the model's register values
(Moving .. Present Temperature) and the Hardware Error Status bits the physics detects (input
voltage, overheating, overload). Choices where the XM430 manual is silent or ambiguous:

* Moving Status: following error (0x08) when |position_trajectory - present_position| exceeds
  FOLLOWING_ERROR_PULSE (1/16 turn) during or after a non-step profile (with a step profile the
  trajectory is the goal itself, so the distance is travel, not a tracking failure); in-position
  (0x01) when no profile is running and the horn is within IN_POSITION_PULSE of the (limited)
  goal. Both only with torque on in position modes; 0x02 only for position profiles; the profile
  type bits keep the type of the last profile (velocity mode: 0x30 when Profile Acceleration is
  set, else 0x00). With torque off Moving Status is 0.
* Models without current sensing (XL430, XC430 and their two-axis versions) report Present Load
  instead of Present Current: the motor's torque at the horn (K_t i) as a share of the stall
  torque of the simulated motor at the present supply, in 0.1 % and within +-100 %, so a full-PWM
  stall reads 1000 at any supply. They have no Goal Current nor Current Limit: nothing but the
  PWM limits their current.
"""

import struct
from typing import Optional, Protocol

from dxl_servo_driver.models import Model
from dxl_servo_driver.models.xm430 import INT32_MAX, INT32_MIN
from dxl_servo_driver.sim import motor
from dxl_servo_driver.sim.control_modes import (
    MODE_POSITION, MODE_VELOCITY, ModeControllers, POSITION_MODES, profile_units)
from dxl_servo_driver.sim.memory import table_for
from dxl_servo_driver.sim.velocity_profile import PROFILE_STEP, PROFILE_TRAPEZOIDAL

FOLLOWING_ERROR_PULSE = 256
IN_POSITION_PULSE = 20

MOVING_STATUS_FOLLOWING_ERROR = 0x08
MOVING_STATUS_PROFILE_ONGOING = 0x02
MOVING_STATUS_IN_POSITION = 0x01


class RegisterStore(Protocol):
    """Raw access to a servo's control table by snake_case name (provided by the servo)."""

    def get(self, name: str) -> int:
        """Return the register value (signed per the item)."""
        ...

    def set(self, name: str, value: int) -> None:  # noqa: A003 (register store protocol)
        """Store a register value, bypassing access and range checks."""
        ...


class HornState(Protocol):
    """The physical state publish() reads (ServoDynamics')."""

    horn_position_pulse: float
    omega_rad_s: float
    current_a: float
    duty: float
    input_voltage_v: float
    temperature_c: float
    motor: motor.Motor
    controllers: ModeControllers
    turn_offset_pulse: int

    @property
    def motor_torque_nm(self) -> float:
        """Electromagnetic torque at the horn (before friction and load)."""
        ...

    def present_position_raw(self, homing: int) -> int:
        """Return Present Position for the horn and a homing offset."""
        ...


# The registers advance() publishes, in the order of the values it computes (and of the XM430
# manual's table: Moving .. Present Temperature).
_PRESENT_NAMES = ('moving', 'moving_status', 'present_pwm', 'present_current',
                  'present_velocity', 'present_position', 'velocity_trajectory',
                  'position_trajectory', 'present_input_voltage', 'present_temperature')


def _present_names(model: Model) -> tuple[str, ...]:
    """Return the present registers of a model, Present Load in place of Present Current."""
    if model.has('present_current'):
        return _PRESENT_NAMES
    return tuple('present_load' if name == 'present_current' else name
                 for name in _PRESENT_NAMES)


def _present_block(model: Model, names: tuple[str, ...]) -> tuple[struct.Struct, int] | None:
    """
    Return (the struct, the start address) of the present registers as one run of the table.

    None when the model does not keep them one after the other in this order (then they are
    set one by one). The struct's formats are the items' own (size and sign), from the table.
    """
    if not all(model.has(name) for name in names):
        return None
    items = [model.item(name) for name in names]
    for before, after in zip(items, items[1:]):
        if after.address != before.address + before.size:
            return None
    structs = table_for(model).structs
    layout = '<' + ''.join(structs[item.name].format[1:] for item in items)
    return struct.Struct(layout), items[0].address


def homing_offset(regs: RegisterStore, ignored: int | None) -> int:
    """Return the homing offset in effect: position mode ignores one beyond `ignored`."""
    offset = regs.get('homing_offset')
    if ignored is not None and regs.get('operating_mode') == MODE_POSITION and \
            abs(offset) > ignored:
        return 0
    return offset


def clamp_int(value: float, low: int, high: int) -> int:
    """Return value rounded to an integer within low..high (NaN: 0)."""
    if value != value:  # NaN never reaches a register
        return 0
    if value < low:
        return low
    if value > high:
        return high
    return int(round(value))


class PresentRegisters:
    """The present registers of one model: their names, units, layout and error bits."""

    def __init__(self, model: Model) -> None:
        self._homing_ignored = model.homing_position_mode_limit
        self._velocity_raw_per_pulse_ms = 1.0 / profile_units(model).velocity_pulse_ms
        self._velocity_unit_per_rad_s = motor.rad_s_to_rpm(1.0) / model.velocity_unit_rpm
        self._pwm_full_raw = model.pwm_full_raw
        self._volt_per_unit = model.voltage_unit_v
        # Current sensing (A per count), or None: Present Load (share of the stall torque).
        self._ampere_per_unit = model.current_unit_a
        self._load_per_unit = model.load_unit_ratio
        self._present_names = _present_names(model)
        self._present_block = _present_block(model, self._present_names)
        # Those the table has (the Y has no Moving): the others are computed, not stored.
        self._has_present = frozenset(name for name in self._present_names if model.has(name))
        # Input voltage against the limits, in the limits' unit (the Y: 0.01 V and 0.1 V).
        self._voltage_to_limit = model.voltage_unit_v / model.voltage_limit_unit_v
        # The Hardware Error Status bits the physics detects, the model's.
        error_bits = table_for(model).error_bits
        self._error_input_voltage = error_bits['input_voltage']
        self._error_overheating = error_bits['overheating']
        self._error_overload = error_bits['overload']

    def _load_raw(self, state: HornState) -> int:
        """Return Present Load: the motor's torque over the stall torque at the present supply."""
        ratio = self._load_per_unit or 0.001
        full = round(1.0 / ratio)
        stall_nm = state.motor.stall_torque_nm(state.input_voltage_v)
        if stall_nm <= 0.0:
            return 0  # no supply worth the name: no torque to be a share of
        return clamp_int(state.motor_torque_nm / stall_nm / ratio, -full, full)

    def publish(self, regs: RegisterStore, state: HornState, mode: Optional[int],
                torque_on: bool, overloaded_span: bool) -> int:
        """Write the present registers; return the detected error bits."""
        get = regs.get
        homing = homing_offset(regs, self._homing_ignored)
        offset = state.turn_offset_pulse + homing
        velocity_raw = clamp_int(state.omega_rad_s * self._velocity_unit_per_rad_s,
                                 INT32_MIN, INT32_MAX)
        position_raw = state.present_position_raw(homing)
        if self._ampere_per_unit is not None:
            current_raw = clamp_int(state.current_a / self._ampere_per_unit, -32768, 32767)
        else:
            current_raw = self._load_raw(state)
        pwm_raw = clamp_int(state.duty * self._pwm_full_raw, -32768, 32767)
        voltage_raw = clamp_int(state.input_voltage_v / self._volt_per_unit, 0, 65535)
        temperature_raw = clamp_int(state.temperature_c, 0, 255)

        position_mode = mode in POSITION_MODES
        position = state.controllers.position
        horn_pulse = state.horn_position_pulse
        profile_on = position_mode and torque_on and position.profile is not None
        status = 0
        position_trajectory = get('position_trajectory')
        if position_mode:
            velocity_trajectory = clamp_int(
                position.traj_vel_pulse_ms * self._velocity_raw_per_pulse_ms,
                INT32_MIN, INT32_MAX)
            position_trajectory = clamp_int(position.traj_pulse + offset, INT32_MIN, INT32_MAX)
            if torque_on:
                status = position.profile_kind
                if profile_on:
                    status |= MOVING_STATUS_PROFILE_ONGOING
                elif abs(position.target_pulse - horn_pulse) <= IN_POSITION_PULSE:
                    status |= MOVING_STATUS_IN_POSITION
                if position.profile_kind != PROFILE_STEP and \
                        abs(position.traj_pulse - horn_pulse) > FOLLOWING_ERROR_PULSE:
                    status |= MOVING_STATUS_FOLLOWING_ERROR
        elif mode == MODE_VELOCITY:
            velocity_trajectory = clamp_int(
                state.controllers.velocity.target if torque_on else 0.0, INT32_MIN, INT32_MAX)
            if torque_on and get('profile_acceleration') > 0:
                status = PROFILE_TRAPEZOIDAL
        else:
            velocity_trajectory = 0
        moving = 1 if profile_on or abs(velocity_raw) > get('moving_threshold') else 0
        values = (moving, status, pwm_raw, current_raw, velocity_raw, position_raw,
                  velocity_trajectory, position_trajectory, voltage_raw, temperature_raw)
        raw = getattr(regs, 'raw', None)
        block = self._present_block
        if block is not None and isinstance(raw, bytearray):
            # Moving .. Present Temperature are one contiguous run of the table: one pack
            # instead of ten register writes (this runs for every servo, every 1 ms).
            block[0].pack_into(raw, block[1], *values)
        else:
            for name, value in zip(self._present_names, values):
                if name in self._has_present:
                    regs.set(name, value)

        errors = 0
        voltage_limit_raw = voltage_raw * self._voltage_to_limit
        if voltage_limit_raw < get('min_voltage_limit') or \
                voltage_limit_raw > get('max_voltage_limit'):
            errors |= self._error_input_voltage
        if temperature_raw > get('temperature_limit'):
            errors |= self._error_overheating
        if overloaded_span:
            errors |= self._error_overload
        return errors
