"""
Physics, controllers and profiles of one simulated servo of any supported model.

The servo (servo.SimServo) owns the control table and calls ServoDynamics: advance() runs the
controllers and the motor for a time span, the on_* hooks react to writes. The model (the XM430
manual's 1030 by default) gives the motor (motor.motor_for), the units of the registers, the
hardware error bits, the position it starts at (its zero, mid-turn) and the supply (its nominal
voltage). Choices where the XM430 manual is silent or ambiguous (see also motor.py and
velocity_profile.py):

* Control period 1 ms: advance() runs whole periods and carries the remainder to the next call.
  While the servo is frozen (horn stuck by friction or load, constant output, no profile running,
  integrators idle) the rest of a span is jumped in one go, so an idle hour costs microseconds.
* Gain conversions of the manual (KpP = P/128, KpI = I/65536, KpD = D/16, Kff1 = FF1/4,
  Kff2 = FF2/4, KvP = P/128, KvI = I/65536; the manual's "65563" is read as 65536); every output
  is in PWM raw units (the model's pwm_full_raw, 885, is 100 %). Position error in pulses, its
  derivative in pulses per 1 ms sample (the manual: "the constant in each equation includes
  sampling time"), the velocity feed-forward in the profile's velocity units
  (velocity_profile.py), the acceleration feed-forward in its acceleration units,
  integrals sum the error once per 1 ms sample. Per sample, the XL430's default D gain (4000)
  damps it near critically (zeta ~1.2); in velocity units, 64 times stronger, it would make the
  loop unstable at a 1 ms sample. The velocity loop takes its error in pulse/s
  (velocity units times beta = 15.63, the manual's "conversion coefficient of position and
  velocity"), which makes the default gains (P 50, I 1920) settle in tens of ms.
* Anti-windup: an integrator does not integrate while the output is saturated in the direction
  of the error, and its contribution is clamped to the output limit.
* Current-based position (mode 5): the PID + feed-forward output is a voltage command (as in mode
  3); it is turned into the current it would drive at the present speed, limited by goal_current,
  and the current loop (an exact inverse of the coreless motor's resistive model) produces the
  PWM, limited by goal_pwm. Unsaturated, mode 5 thus moves exactly like mode 3.
* Moving Status: following error (0x08) when |position_trajectory - present_position| exceeds
  FOLLOWING_ERROR_PULSE (1/16 turn) during or after a non-step profile (with a step profile the
  trajectory is the goal itself, so the distance is travel, not a tracking failure); in-position
  (0x01) when no profile is running and the horn is within IN_POSITION_PULSE of the (limited)
  goal. Both only with torque on in position modes; 0x02 only for position profiles; the profile
  type bits keep the type of the last profile (velocity mode: 0x30 when Profile Acceleration is
  set, else 0x00). With torque off Moving Status is 0.
* Overload (0x20): the controller demands more than its output limit (PWM limit, or Goal PWM in
  PWM mode at the PWM limit) while the motor is loaded (current above half the stall current at
  the present supply), continuously for more than OVERLOAD_TIME_S. Current limiting by Goal
  Current in mode 5 is regulation, not overload.
* Torque on holds the present position (the trajectory restarts there); a goal written with
  torque off is not acted on. Torque off is free-run: the windings are open, no current flows,
  the horn coasts until friction and load stop it.
* Models without current sensing (XL430, XC430 and their two-axis versions) report Present Load
  instead of Present Current: the motor's torque at the horn (K_t i) as a share of the stall
  torque of the simulated motor at the present supply, in 0.1 % and within +-100 %, so a full-PWM
  stall reads 1000 at any supply. They have no Goal Current nor Current Limit: nothing but the
  PWM limits their current.

* A hand on the horn (turn): with torque off it turns the horn at constant speed to a
  position and lets go; Present Velocity shows the hand's speed meanwhile, the windings being
  open no current flows, and the horn stays where it is left (friction). Torque on ends a turn:
  the motor holds the horn where the hand had it. An unpowered servo's horn turns too (nothing
  is published until it is powered: then Present Position is re-initialised from it).
* Mechanical end stops (set_stops): the horn never passes them. Motion into a stop ends there
  with the speed at 0; a motor pushing into it is a stalled motor, drawing the current its
  output drives at zero speed (the PWM limit's stall current, or Goal Current in the current
  modes, whose current loop knows the horn cannot move). Hand and stops are fixed on the horn:
  positions given in servo radians are turned into horn pulses through Present Position as it
  is counted when they are given (its turns and the Homing Offset).

* Drive Mode (drive_mode_bits): bit 0 (reverse) mirrors the servo's whole register frame
  against the horn: the dynamics run in the frame the registers count in (horn_position_pulse
  is the encoder's count in the present direction, every goal, present value, trajectory,
  limit, hand and stop in it), and physical_position_pulse is the horn as an unreversed servo
  would count it; a write of the bit flips the frame (torque is off then: EEPROM). The
  e-manual names Goal and Present Position as reversed on the X430 and Position, Velocity,
  Current and PWM on the X540/XW/MX(2.0): a servo counting its position one way and its
  velocity the other would contradict its own profile, so every signed value turns with the
  position here. The MX-106's and EX-106+'s Protocol 1.0 exception (no reverse in wheel mode) is
  not modelled. Bit 2 (time-based profile) makes Profile Velocity the time of a move and
  Profile Acceleration its acceleration time, in ms (velocity_profile.plan_timed; in velocity
  mode the goal is reached in Profile Acceleration ms).

One span of advance() (_run) is the motor, gearbox and overload timer of every mode, and one
small controller per operating mode (_PositionControl for the three position modes,
_VelocityControl, _CurrentControl, _PwmControl; _Free with torque off) gives the output each
1 ms period. The loop keeps the motor's state in local variables (it runs a thousand times per
simulated second per servo); the controllers take the integrators, the profile and the
trajectory from ServoDynamics for a span and hand them back, which keeps them in this module.
"""

import math
import struct
from typing import Callable, Optional, Protocol, Union

from dxl_servo_driver.models import Model, modes
from dxl_servo_driver.models.xm430 import INT32_MAX, INT32_MIN
from dxl_servo_driver.sim import motor
from dxl_servo_driver.sim.memory import MANUAL_MODEL, table_for
from dxl_servo_driver.sim.velocity_profile import (
    plan_position, plan_timed, PositionProfile, PROFILE_STEP, PROFILE_TRAPEZOIDAL, ProfileUnits,
    ramp_timed, ramp_velocity, X_UNITS)

CONTROL_PERIOD_S = 0.001
_PERIOD_MS = CONTROL_PERIOD_S * 1000.0
FOLLOWING_ERROR_PULSE = 256
IN_POSITION_PULSE = 20
OVERLOAD_TIME_S = 1.0
OVERLOAD_CURRENT_FRACTION = 0.5

# The register values of the modes (models.modes is their one table).
MODE_CURRENT = modes.BY_NAME['current'].number
MODE_VELOCITY = modes.BY_NAME['velocity'].number
MODE_POSITION = modes.BY_NAME['position'].number
MODE_CURRENT_BASED_POSITION = modes.BY_NAME['current_based_position'].number
MODE_PWM = modes.BY_NAME['pwm'].number
POSITION_MODES = modes.POSITION_NUMBERS

MOVING_STATUS_FOLLOWING_ERROR = 0x08
MOVING_STATUS_PROFILE_ONGOING = 0x02
MOVING_STATUS_IN_POSITION = 0x01


def profile_units(model: Model) -> ProfileUnits:
    """
    Return a model's profile units in pulses and ms.

    The X series' are the XM430 manual's rounding (1/64 pulse/ms, 1/4096 pulse/ms^2: its travel
    time formulas use them); any other family's come from its own units, unrounded.
    """
    if (model.velocity_unit_rpm, model.pulses_per_rev, model.acceleration_unit_rpm2) == (
            0.229, 4096, 214.577):
        return X_UNITS
    per_rev = float(model.pulses_per_rev)
    return ProfileUnits(model.velocity_unit_rpm * per_rev / 60_000.0,
                        model.acceleration_unit_rpm2 * per_rev / 3.6e9)


class RegisterStore(Protocol):
    """Raw access to a servo's control table by snake_case name (provided by the servo)."""

    def get(self, name: str) -> int:
        """Return the register value (signed per the item)."""
        ...

    def set(self, name: str, value: int) -> None:  # noqa: A003 (register store protocol)
        """Store a register value, bypassing access and range checks."""
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


_GAINS = ('position_p_gain', 'position_i_gain', 'position_d_gain', 'feedforward_1st_gain',
          'feedforward_2nd_gain', 'velocity_p_gain', 'velocity_i_gain')


def gain_factors(model: Model) -> dict[str, float]:
    """
    Return what each gain of a model is multiplied by in the XM430 manual's conversions.

    Those conversions are written for the manual's units (4,096 pulses a turn, 0.229 rpm,
    214.577 rev/min^2, PWM 885 = 100 %): 1 for every gain of a model with those units. Another
    family's errors are turned into them and its outputs back into its own PWM, scaled by how
    much faster its motor turns at full output than the manual's (a Y turns 120 times faster:
    the same error needs that much less output); and since the e-manual gives no conversion of
    its gains, its default gains are taken to act as the XM430 manual's defaults do (a
    simulator choice: the loops settle as an X's would).
    """
    manual = MANUAL_MODEL
    position = manual.pulses_per_rev / model.pulses_per_rev
    output = model.pwm_full_raw / manual.pwm_full_raw
    speed = (manual.physics.nominal.no_load_speed_rpm
             / model.physics.nominal.no_load_speed_rpm)
    units = {
        'position_p_gain': position, 'position_i_gain': position, 'position_d_gain': position,
        'feedforward_1st_gain': model.velocity_unit_rpm / manual.velocity_unit_rpm,
        'feedforward_2nd_gain': model.acceleration_unit_rpm2 / manual.acceleration_unit_rpm2,
        'velocity_p_gain': position, 'velocity_i_gain': position}
    if all(math.isclose(factor, 1.0) for factor in units.values()) and math.isclose(output, 1.0):
        return dict.fromkeys(_GAINS, 1.0)
    factors = {}
    for name in _GAINS:
        ratio = 1.0
        if model.has(name) and model.item(name).initial and manual.item(name).initial:
            ratio = manual.item(name).initial / model.item(name).initial
        factors[name] = units[name] * output * speed * ratio
    return factors


def _homing_offset(regs: 'RegisterStore', ignored: int | None) -> int:
    """Return the homing offset in effect: position mode ignores one beyond `ignored`."""
    offset = regs.get('homing_offset')
    if ignored is not None and regs.get('operating_mode') == MODE_POSITION and \
            abs(offset) > ignored:
        return 0
    return offset


def _clamp_int(value: float, low: int, high: int) -> int:
    if value != value:  # NaN never reaches a register
        return 0
    if value < low:
        return low
    if value > high:
        return high
    return int(round(value))


def _integrated(integral: float, error: float, demand: float, gain: float,
                out_limit: float) -> float | None:
    """
    Return a PI integral after this step's error, or None when it does not move.

    Conditional integration: not while the output saturates in the error's direction, and
    bounded so the integral term alone never exceeds the output limit (no wind-up).
    """
    saturated = abs(demand) > out_limit
    if gain == 0.0 or error == 0.0 or (saturated and (error > 0.0) == (demand > 0.0)):
        return None
    bound = out_limit / gain
    return max(-bound, min(bound, integral + error))


class _Plant:
    """
    The motor and gearbox over one advance() span: its constants at this supply and load.

    The loop integrates the horn implicitly in the linear terms (stable at 1 ms whatever the
    motor), with stiction at rest; the current loops predict the speed from the same terms.
    """

    __slots__ = ('r_ohm', 'kt', 'ke', 'viscous', 'c1', 'ktr', 'denominator', 'friction', 'volts',
                 'volts_eff', 'low', 'high')

    def __init__(self, fitted: motor.Motor, load_nm: float, torque_on: bool,
                 volts: float, low: float = -math.inf, high: float = math.inf) -> None:
        self.r_ohm = fitted.resistance_ohm
        self.kt = fitted.torque_constant_nm_a
        self.ke = fitted.back_emf_v_s_rad
        self.viscous = fitted.viscous_friction_nm_s_rad
        self.c1 = CONTROL_PERIOD_S / fitted.inertia_kg_m2
        self.ktr = self.kt / self.r_ohm
        # The back-EMF brakes only through a driven winding: torque off is free-run.
        damping = (self.kt * self.ke / self.r_ohm + self.viscous) if torque_on else self.viscous
        self.denominator = 1.0 + self.c1 * damping
        self.friction = fitted.coulomb_friction_nm + load_nm
        self.volts = volts
        self.volts_eff = volts if volts > 1e-6 else 1e-6
        self.low = low     # the end stops, in horn pulses (+-inf: none)
        self.high = high

    def predict_omega(self, omega: float, current_a: float, pos: float) -> float:
        """
        Speed at the end of the period if current_a flows (current loop's back-EMF estimate).

        A real current loop runs far faster than the 1 ms period; anticipating the speed change
        keeps the held current exact while the horn accelerates, and at an end stop it knows
        the horn pushed into it stays put.
        """
        predicted = self._predict_free(omega, current_a)
        if (predicted > 0.0 and pos >= self.high) or (predicted < 0.0 and pos <= self.low):
            return 0.0
        return predicted

    def _predict_free(self, omega: float, current_a: float) -> float:
        """Speed at the end of the period if current_a flows and nothing stops the horn."""
        friction_nm = self.friction
        torque = self.kt * current_a - self.viscous * omega
        if omega > 0.0:
            torque -= friction_nm
        elif omega < 0.0:
            torque += friction_nm
        elif abs(torque) <= friction_nm:
            return 0.0
        else:
            torque -= math.copysign(friction_nm, torque)
        return omega + self.c1 * torque

    def duty_for(self, current_a: float, omega: float, full: float, pos: float) -> float:
        """Return the output (PWM raw units) that drives current_a at the predicted speed."""
        return (self.r_ohm * current_a + self.ke * self.predict_omega(omega, current_a, pos)) \
            / self.volts_eff * full


# ---- one controller per operating mode -------------------------------------------------------
# step(omega, pos) runs once per control period on the horn's speed (rad/s) and position
# (pulses) and returns (duty in [-1, 1], output saturated, still changing): the last says an
# integrator, a ramp or a profile moved, which keeps advance()'s idle fast path off. store()
# hands the controller's state back to the dynamics at the end of the span.
_Step = tuple[float, bool, bool]


class _Free:
    """Torque off (or a mode without a controller): the windings are open, no drive."""

    def step(self, omega: float, pos: float) -> _Step:
        """Return no drive."""
        return 0.0, False, False

    def store(self, dynamics: 'ServoDynamics') -> None:
        """Keep nothing: there is no state."""


class _PwmControl:
    """PWM mode: Goal PWM, within PWM Limit, is the output."""

    __slots__ = ('_out',)

    def __init__(self, goal_pwm: float, pwm_limit: int, full: float) -> None:
        self._out = (goal_pwm / full, pwm_limit > 0 and abs(goal_pwm) >= pwm_limit, False)

    def step(self, omega: float, pos: float) -> _Step:
        """Return the constant output."""
        return self._out

    def store(self, dynamics: 'ServoDynamics') -> None:
        """Keep nothing: there is no state."""


class _CurrentControl:
    """Current mode: the output that drives Goal Current (within the limits) at this speed."""

    __slots__ = ('_plant', '_goal_a', '_out_limit', '_full')

    def __init__(self, plant: _Plant, goal_current_a: float, out_limit: float,
                 full: float) -> None:
        self._plant = plant
        self._goal_a = goal_current_a
        self._out_limit = out_limit
        self._full = full

    def step(self, omega: float, pos: float) -> _Step:
        """Return the output for Goal Current."""
        out_limit = self._out_limit
        demand = self._plant.duty_for(self._goal_a, omega, self._full, pos)
        return (max(-out_limit, min(out_limit, demand)) / self._full,
                abs(demand) > out_limit, False)

    def store(self, dynamics: 'ServoDynamics') -> None:
        """Keep nothing: there is no state."""


class _PositionControl:
    """
    The position modes (position, extended position, current-based position): PID + FF.

    The profile is sampled every period and the PID with the two feed-forwards acts on its
    trajectory. In current-based position the output is turned into the current it would drive,
    limited by Goal Current, and back into the output that drives that current.
    """

    __slots__ = ('_kpp', '_kpi', '_kpd', '_kff1', '_kff2', '_plant', '_out_limit', '_full',
                 '_current_limit_a', '_pulse_per_rad_ms', '_velocity_raw_per_pulse_ms',
                 '_acceleration_raw_per_pulse_ms2', 'integral', 'profile', 'profile_t',
                 'traj_p', 'traj_v', 'traj_a')

    def __init__(self, dynamics: 'ServoDynamics', get: Callable[[str], int], plant: _Plant,
                 out_limit: float, full: float, current_limit_a: float | None) -> None:
        self._kpp = get('position_p_gain') / 128.0 * dynamics._kpp
        self._kpi = get('position_i_gain') / 65536.0 * dynamics._kpi
        self._kpd = get('position_d_gain') / 16.0 * dynamics._kpd
        self._kff1 = get('feedforward_1st_gain') / 4.0 * dynamics._kff1
        self._kff2 = get('feedforward_2nd_gain') / 4.0 * dynamics._kff2
        self._plant = plant
        self._out_limit = out_limit
        self._full = full
        self._current_limit_a = current_limit_a   # current-based position only
        self._pulse_per_rad_ms = dynamics._pulse_per_rad / 1000.0
        self._velocity_raw_per_pulse_ms = dynamics._velocity_raw_per_pulse_ms
        self._acceleration_raw_per_pulse_ms2 = 1.0 / dynamics._profile_units.acceleration_pulse_ms2
        self.integral = dynamics._pos_integral
        self.profile = dynamics._profile
        self.profile_t = dynamics._profile_t_ms
        self.traj_p = dynamics._traj_pulse
        self.traj_v = dynamics._traj_vel_pulse_ms
        self.traj_a = dynamics._traj_acc_pulse_ms2

    def step(self, omega: float, pos: float) -> _Step:
        """Follow the profile one period; return the PID + feed-forward output."""
        profile = self.profile
        if profile is not None:
            self.profile_t += _PERIOD_MS
            self.traj_p, self.traj_v, self.traj_a = profile.sample(self.profile_t)
            if self.profile_t >= profile.duration_ms:
                profile = self.profile = None
        full = self._full
        out_limit = self._out_limit
        traj_v = self.traj_v
        error = self.traj_p - pos
        traj_v_raw = traj_v * self._velocity_raw_per_pulse_ms
        demand = self._kpp * error + self._kpi * self.integral \
            + self._kpd * (traj_v - omega * self._pulse_per_rad_ms) \
            + self._kff1 * traj_v_raw \
            + self._kff2 * self.traj_a * self._acceleration_raw_per_pulse_ms2
        limit_a = self._current_limit_a
        if limit_a is not None:
            plant = self._plant
            target_a = (demand / full * plant.volts - plant.ke * omega) / plant.r_ohm
            if target_a > limit_a:
                target_a = limit_a
            elif target_a < -limit_a:
                target_a = -limit_a
            demand = plant.duty_for(target_a, omega, full, pos)
        moved = _integrated(self.integral, error, demand, self._kpi, out_limit)
        if moved is not None:
            self.integral = moved
        return (max(-out_limit, min(out_limit, demand)) / full, abs(demand) > out_limit,
                moved is not None or profile is not None)

    def store(self, dynamics: 'ServoDynamics') -> None:
        """Hand the integral, the profile and the trajectory back."""
        dynamics._pos_integral = self.integral
        dynamics._profile = self.profile
        dynamics._profile_t_ms = self.profile_t
        dynamics._traj_pulse = self.traj_p
        dynamics._traj_vel_pulse_ms = self.traj_v
        dynamics._traj_acc_pulse_ms2 = self.traj_a


class _VelocityControl:
    """Velocity mode: a PI on the speed, its target ramped by Profile Acceleration."""

    __slots__ = ('_kvp', '_kvi', '_goal', '_acceleration_raw', '_units', '_unit_per_rad_s',
                 '_out_limit', '_full', '_timed_rate', 'integral', 'target')

    def __init__(self, dynamics: 'ServoDynamics', get: Callable[[str], int], out_limit: float,
                 full: float) -> None:
        beta = dynamics._beta_pulse_s_per_unit
        self._kvp = get('velocity_p_gain') / 128.0 * beta * dynamics._kvp
        self._kvi = get('velocity_i_gain') / 65536.0 * beta * dynamics._kvi
        self._goal = float(get('goal_velocity'))
        self._acceleration_raw = get('profile_acceleration')
        # A time-based profile: the rate its goal was given (None: velocity-based).
        self._timed_rate = dynamics._vel_rate_raw_ms
        self._units = dynamics._profile_units
        self._unit_per_rad_s = dynamics._velocity_unit_per_rad_s
        self._out_limit = out_limit
        self._full = full
        self.integral = dynamics._vel_integral
        self.target = dynamics._vel_traj_raw

    def step(self, omega: float, pos: float) -> _Step:
        """Ramp the target one period; return the PI output."""
        changing = False
        if self.target != self._goal:
            if self._timed_rate is None:
                self.target = ramp_velocity(self.target, self._goal, self._acceleration_raw,
                                            _PERIOD_MS, self._units)
            else:
                self.target = ramp_timed(self.target, self._goal, self._timed_rate, _PERIOD_MS)
            changing = True
        out_limit = self._out_limit
        error = self.target - omega * self._unit_per_rad_s
        demand = self._kvp * error + self._kvi * self.integral
        moved = _integrated(self.integral, error, demand, self._kvi, out_limit)
        if moved is not None:
            self.integral = moved
            changing = True
        return (max(-out_limit, min(out_limit, demand)) / self._full, abs(demand) > out_limit,
                changing)

    def store(self, dynamics: 'ServoDynamics') -> None:
        """Hand the integral and the ramped target back."""
        dynamics._vel_integral = self.integral
        dynamics._vel_traj_raw = self.target


_Controller = Union[_Free, _PwmControl, _CurrentControl, _PositionControl, _VelocityControl]


class ServoDynamics:
    """
    Motor, gearbox, controllers, profiles and thermal model of one servo.

    About 480 lines, on purpose: the per-mode controllers are classes of their own (above), and
    what is left is the one state of a horn (its motor, position, velocity, temperature, the
    hand on it and its stops) that every step of every mode advances together; split further,
    each part would reach into the others' state every control period.
    """

    def __init__(self, input_voltage_v: float | None = None, ambient_c: float = 25.0,
                 start_position_pulse: float | None = None, model: Model | None = None) -> None:
        """
        Set up the physics of a model (the manual's by default) at rest.

        The horn starts at start_position_pulse (default: the model's zero, mid-turn) and the
        supply at input_voltage_v (default: the model's nominal voltage).
        """
        model = MANUAL_MODEL if model is None else model
        self.model = model
        self.motor = motor.motor_for(model)
        self._pulses_per_rev = model.pulses_per_rev
        self._homing_ignored = model.homing_position_mode_limit
        self._profile_units = profile_units(model)
        self._goal_pwm_caps = 'pwm' in model.modes
        gains = gain_factors(model)
        self._kpp, self._kpi, self._kpd, self._kff1, self._kff2, self._kvp, self._kvi = (
            gains[name] for name in _GAINS)
        self._velocity_raw_per_pulse_ms = 1.0 / self._profile_units.velocity_pulse_ms
        self._pulse_per_rad = model.pulses_per_rev / (2.0 * math.pi)
        self._velocity_unit_per_rad_s = motor.rad_s_to_rpm(1.0) / model.velocity_unit_rpm
        # beta: pulse/s per velocity unit, used by the velocity loop.
        self._beta_pulse_s_per_unit = model.velocity_unit_rpm * model.pulses_per_rev / 60.0
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
        if start_position_pulse is None:
            start_position_pulse = model.position_zero_raw
        self.horn_position_pulse = float(start_position_pulse)
        self.current_a = 0.0
        self.temperature_c = float(ambient_c)
        self.ambient_c = float(ambient_c)
        if input_voltage_v is None:
            input_voltage_v = model.physics.nominal_voltage_v
        self.input_voltage_v = max(0.0, float(input_voltage_v))
        self.load_nm = 0.0
        self.duty = 0.0
        self._omega_rad_s = 0.0
        self._turn_offset_pulse = 0
        self._mode: Optional[int] = None
        self._torque_on = False
        self._remainder_s = 0.0
        # Position profile state, in horn coordinates (pulses without turn or homing offset).
        self._profile: Optional[PositionProfile] = None
        # A hand turning the horn: pulses left to go, their sign, pulses per control period.
        self._hand_left_pulse = 0.0
        self._hand_sign = 1.0
        self._hand_step_pulse = 0.0
        # Drive Mode: the frame's direction against the horn (-1: reversed, bit 0) and what
        # makes profiles times (bit 2); their bits on this model (None: it has no such bit).
        self._direction = 1.0
        self._reverse_bit = model.reverse_bit
        self._time_bit = model.time_profile_bit
        # Velocity mode, time-based: the rate (velocity units per ms) of the last goal.
        self._vel_rate_raw_ms: Optional[float] = None
        # The mechanical end stops, in horn pulses (+-inf: none).
        self.stop_low_pulse = -math.inf
        self.stop_high_pulse = math.inf
        self.reset_controllers()

    # ----------------------------------------------------------------- readable physical state
    @property
    def motor_torque_nm(self) -> float:
        """Electromagnetic torque at the horn (before friction and load)."""
        return self.motor.torque_constant_nm_a * self.current_a

    @property
    def physical_position_pulse(self) -> float:
        """Return the horn's position as the servo counts it unreversed (Drive Mode bit 0 0)."""
        return self._direction * self.horn_position_pulse

    @property
    def hand_turning(self) -> bool:
        """Return whether a hand is turning the horn."""
        return self._hand_left_pulse > 0.0

    # ----------------------------------------------------------------- a hand, the end stops
    def horn_pulse_of(self, rad: float, regs: RegisterStore) -> float:
        """Return the horn position (pulses) at which Present Position reads rad (servo rad)."""
        raw = self.model.position_zero_raw + rad * self._pulse_per_rad
        return raw - self._turn_offset_pulse - _homing_offset(regs, self._homing_ignored)

    def rad_of(self, horn_pulse: float, regs: RegisterStore) -> float:
        """Return the servo radians Present Position reads at a horn position (pulses)."""
        raw = horn_pulse + self._turn_offset_pulse + _homing_offset(regs, self._homing_ignored)
        return (raw - self.model.position_zero_raw) / self._pulse_per_rad

    def start_turn(self, rad: float, seconds: float, regs: RegisterStore) -> None:
        """
        Turn the horn by hand to rad (servo radians) at constant speed over seconds (0: at once).

        The caller has checked that torque is off; the horn stops at an end stop on the way.
        """
        target = min(max(self.horn_pulse_of(rad, regs), self.stop_low_pulse),
                     self.stop_high_pulse)
        distance = target - self.horn_position_pulse
        self._omega_rad_s = 0.0
        periods = seconds / CONTROL_PERIOD_S
        if periods < 1.0 or distance == 0.0:
            self.horn_position_pulse = target
            self._hand_left_pulse = 0.0
            # Torque is off: the trajectory follows the horn (as _run keeps it).
            self._traj_pulse = self._target_pulse = target
            return
        self._hand_sign = 1.0 if distance > 0.0 else -1.0
        self._hand_left_pulse = abs(distance)
        self._hand_step_pulse = abs(distance) / periods

    def stop_hand(self) -> None:
        """Let go of the horn: it stays where it is."""
        if self._hand_left_pulse > 0.0:
            self._hand_left_pulse = 0.0
            self._omega_rad_s = 0.0

    def hand_coast(self, dt_s: float) -> None:
        """Move the horn of an unpowered servo as the hand turns it for dt_s (no registers)."""
        if self._hand_left_pulse <= 0.0 or dt_s <= 0.0:
            return
        step = min(self._hand_step_pulse * dt_s / CONTROL_PERIOD_S, self._hand_left_pulse)
        self._hand_left_pulse -= step
        self.horn_position_pulse += self._hand_sign * step
        if self._hand_left_pulse <= 0.0:
            self._hand_left_pulse = 0.0
            self._omega_rad_s = 0.0

    def set_stops(self, low_rad: float, high_rad: float, regs: RegisterStore) -> None:
        """Put end stops at low_rad..high_rad (servo radians); ValueError if the horn is not in."""
        low = self.horn_pulse_of(low_rad, regs)
        high = self.horn_pulse_of(high_rad, regs)
        horn = self.horn_position_pulse
        if not low <= horn <= high:
            raise ValueError(f'the horn is at {self.rad_of(horn, regs):.4f} rad, outside the '
                             f'stops {low_rad:g}..{high_rad:g} rad: turn it in between first')
        self.stop_low_pulse = low
        self.stop_high_pulse = high

    def clear_stops(self) -> None:
        """Take the end stops away."""
        self.stop_low_pulse = -math.inf
        self.stop_high_pulse = math.inf

    # ----------------------------------------------------------------- hooks
    def set_load(self, load_nm: float) -> None:
        """Set the resisting torque at the horn (a brake: opposes motion, holds below it)."""
        value = abs(float(load_nm))
        self.load_nm = value if math.isfinite(value) else 0.0

    def set_input_voltage(self, volts: float) -> None:
        """Set the supply voltage."""
        value = float(volts)
        self.input_voltage_v = max(0.0, value) if math.isfinite(value) else 0.0

    def reset_controllers(self) -> None:
        """Clear integrators, overload timer and profile state; hold the present position."""
        self._pos_integral = 0.0
        self._vel_integral = 0.0
        self._overload_s = 0.0
        self._profile = None
        self._profile_t_ms = 0.0
        self._profile_kind = PROFILE_STEP
        self._traj_pulse = self.horn_position_pulse
        self._traj_vel_pulse_ms = 0.0
        self._traj_acc_pulse_ms2 = 0.0
        self._target_pulse = self.horn_position_pulse
        self._vel_traj_raw = 0.0
        self._vel_rate_raw_ms = None

    def on_torque(self, enabled: bool, regs: RegisterStore) -> None:
        """Torque enable changed: restart the controllers from the present state."""
        self._torque_on = bool(enabled)
        if self._torque_on:
            self.stop_hand()   # the motor holds the horn where the hand had it
        self.reset_controllers()
        if self._torque_on:
            self._vel_traj_raw = self._omega_rad_s * self._velocity_unit_per_rad_s
        else:
            self.duty = 0.0
            self.current_a = 0.0

    def on_goal_position(self, regs: RegisterStore) -> None:
        """Goal position written: plan a new profile from the present trajectory state."""
        mode = regs.get('operating_mode')
        if mode not in POSITION_MODES or not regs.get('torque_enable'):
            return
        if self._mode != mode or not self._torque_on:
            self._sync_mode_and_torque(regs)
        goal = regs.get('goal_position')
        if mode == MODE_POSITION:
            low = regs.get('min_position_limit')
            high = regs.get('max_position_limit')
            goal = min(max(goal, low), high) if low <= high else goal
        homing = _homing_offset(regs, self._homing_ignored)
        goal_pulse = float(goal - self._turn_offset_pulse - homing)
        if self._timed(regs):
            profile = plan_timed(self._traj_pulse, self._traj_vel_pulse_ms, goal_pulse,
                                 regs.get('profile_velocity'), regs.get('profile_acceleration'))
        else:
            profile = plan_position(self._traj_pulse, self._traj_vel_pulse_ms, goal_pulse,
                                    regs.get('profile_velocity'),
                                    regs.get('profile_acceleration'), self._profile_units)
        self._profile = profile
        self._profile_t_ms = 0.0
        self._profile_kind = profile.kind
        self._target_pulse = goal_pulse
        if profile.duration_ms <= 0.0:
            self._traj_pulse = goal_pulse
            self._traj_vel_pulse_ms = 0.0
            self._traj_acc_pulse_ms2 = 0.0

    def on_goal_velocity(self, regs: RegisterStore) -> None:
        """Goal velocity written: the ramp reads it every period (so override is built in)."""
        if self._mode != regs.get('operating_mode'):
            self._sync_mode_and_torque(regs)
        if self._timed(regs):
            # Time-based: the goal is reached Profile Acceleration ms from now.
            rise_ms = regs.get('profile_acceleration')
            change = abs(regs.get('goal_velocity') - self._vel_traj_raw)
            self._vel_rate_raw_ms = change / rise_ms if rise_ms > 0 else 0.0
        else:
            self._vel_rate_raw_ms = None

    def _timed(self, regs: RegisterStore) -> bool:
        """Return whether Drive Mode makes the profile registers times (bit 2)."""
        bit = self._time_bit
        return bit is not None and bool(regs.get('drive_mode') >> bit & 1)

    def sync_direction(self, regs: RegisterStore) -> bool:
        """
        Turn the frame to what Drive Mode bit 0 says; return whether it turned.

        The horn stays where it is: its count, the trajectory, a hand and the stops change
        sign (torque is off: the bit is EEPROM), and Present Position is re-initialised.
        """
        bit = self._reverse_bit
        direction = -1.0 if bit is not None and regs.get('drive_mode') >> bit & 1 else 1.0
        if direction == self._direction:
            return False
        self._direction = direction
        self.horn_position_pulse = -self.horn_position_pulse
        self._omega_rad_s = -self._omega_rad_s
        self._hand_sign = -self._hand_sign
        self.stop_low_pulse, self.stop_high_pulse = -self.stop_high_pulse, -self.stop_low_pulse
        self.duty = -self.duty
        self.current_a = -self.current_a
        self.reset_controllers()
        self.reinit_present_position(regs)
        return True

    def reinit_present_position(self, regs: RegisterStore) -> None:
        """Present position := horn position within one turn + homing offset."""
        if self._reverse_bit is not None and self.sync_direction(regs):
            return   # re-initialised there, in the new frame
        turns = math.floor(self.horn_position_pulse / self._pulses_per_rev)
        # Whole pulses: a model whose turn is not a whole number of pulses rounds here.
        self._turn_offset_pulse = int(round(-self._pulses_per_rev * turns))
        homing = _homing_offset(regs, self._homing_ignored)
        regs.set('present_position', self._present_position_raw(homing))

    # ----------------------------------------------------------------- simulation
    def _sync_mode_and_torque(self, regs: RegisterStore) -> None:
        mode = regs.get('operating_mode')
        torque = bool(regs.get('torque_enable'))
        if mode != self._mode:
            self._mode = mode
            self.on_torque(torque, regs)
        elif torque != self._torque_on:
            self.on_torque(torque, regs)

    def _present_position_raw(self, homing_offset: int) -> int:
        value = self.horn_position_pulse + self._turn_offset_pulse + homing_offset
        return _clamp_int(value, INT32_MIN, INT32_MAX)

    def advance(self, dt_s: float, regs: RegisterStore) -> int:
        """
        Run the controllers and the motor for dt_s seconds and publish the present registers.

        Returns the Hardware Error Status bits detected in the span (not latched here).
        """
        dt_s = float(dt_s)
        if not math.isfinite(dt_s) or dt_s < 0.0:
            dt_s = 0.0
        self._sync_mode_and_torque(regs)
        mode = self._mode
        torque_on = self._torque_on
        volts = self.input_voltage_v

        total_s = self._remainder_s + dt_s
        steps = int(total_s / CONTROL_PERIOD_S + 1e-9)
        self._remainder_s = max(0.0, total_s - steps * CONTROL_PERIOD_S)

        overloaded_span = False
        if steps > 0:
            sum_i2, overloaded_span = self._run(steps, regs, mode, torque_on, volts)
            mean_i2 = sum_i2 / steps
        else:
            mean_i2 = self.current_a * self.current_a
        fitted = self.motor
        self.temperature_c = fitted.thermal_step(
            self.temperature_c, self.ambient_c, fitted.heat_power_w(mean_i2, volts), dt_s)
        return self._publish(regs, mode, torque_on, overloaded_span)

    def _controller(self, regs: RegisterStore, mode: Optional[int], torque_on: bool,
                    plant: _Plant) -> _Controller:
        """Return the controller of the mode, with the limits and gains the registers hold now."""
        if not torque_on:
            return _Free()
        get = regs.get
        full = float(self._pwm_full_raw)
        pwm_limit = max(0, get('pwm_limit'))
        if mode == MODE_PWM:
            return _PwmControl(float(max(-pwm_limit, min(pwm_limit, get('goal_pwm')))),
                               pwm_limit, full)
        # Goal PWM caps the output in every mode (the XM430 manual) of a model that has a PWM
        # mode; a model without one (the Y) has it as a plain register, capped by PWM Limit.
        out_limit = float(min(abs(get('goal_pwm')), pwm_limit) if self._goal_pwm_caps
                          else pwm_limit)
        ampere_per_unit = self._ampere_per_unit
        if ampere_per_unit is None:
            # No Goal Current nor Current Limit (nor the modes that use them) on this model.
            current_limit_a = math.inf
            goal_current_a = 0.0
        else:
            current_limit_a = min(abs(get('goal_current')), max(0, get('current_limit'))) \
                * ampere_per_unit
            goal_current_a = max(-current_limit_a, min(current_limit_a, get('goal_current')
                                                       * ampere_per_unit))
        if mode == MODE_CURRENT:
            return _CurrentControl(plant, goal_current_a, out_limit, full)
        if mode in POSITION_MODES:
            return _PositionControl(
                self, get, plant, out_limit, full,
                current_limit_a if mode == MODE_CURRENT_BASED_POSITION else None)
        if mode == MODE_VELOCITY:
            return _VelocityControl(self, get, out_limit, full)
        return _Free()

    def _run(self, steps: int, regs: RegisterStore, mode: Optional[int], torque_on: bool,
             volts: float) -> tuple[float, bool]:
        """
        Run whole control periods; return (sum of i^2 over the periods, overload seen).

        The mode's controller gives the output each period; the motor, the gearbox and the
        overload timer are the same in every mode.
        """
        low = self.stop_low_pulse
        high = self.stop_high_pulse
        plant = _Plant(self.motor, self.load_nm, torque_on, volts, low, high)
        controller = self._controller(regs, mode, torque_on, plant)
        control = controller.step
        dt = CONTROL_PERIOD_S
        r_ohm = plant.r_ohm
        ke = plant.ke
        c1 = plant.c1
        ktr = plant.ktr
        denominator = plant.denominator
        friction = plant.friction
        pulse_per_rad_dt = self._pulse_per_rad * dt
        overload_current = OVERLOAD_CURRENT_FRACTION * volts / r_ohm

        omega = self._omega_rad_s
        pos = self.horn_position_pulse
        duty = self.duty
        current = self.current_a
        overload_s = self._overload_s
        hand_left = self._hand_left_pulse
        hand_step = self._hand_step_pulse
        hand_sign = self._hand_sign
        hand_omega = hand_sign * hand_step / pulse_per_rad_dt
        sum_i2 = 0.0
        overload_seen = False
        frozen_count = 0
        step = 0
        while step < steps:
            step += 1
            previous_duty = duty
            previous_omega = omega
            duty, saturated, changing = control(omega, pos)
            if hand_left > 0.0:
                # ---- a hand turns the horn (torque is off: the controller gives nothing)
                moved = hand_step if hand_step < hand_left else hand_left
                hand_left -= moved
                pos += hand_sign * moved
                omega = hand_omega if hand_left > 0.0 else 0.0
                changing = True
            else:
                # ---- motor and gearbox (implicit in the linear terms, stiction at rest)
                drive = ktr * duty * volts if torque_on else 0.0
                if omega == 0.0:
                    if drive > friction:
                        omega = c1 * (drive - friction) / denominator
                    elif drive < -friction:
                        omega = c1 * (drive + friction) / denominator
                elif omega > 0.0:
                    omega = (omega + c1 * (drive - friction)) / denominator
                    if omega < 0.0:
                        omega = 0.0
                else:
                    omega = (omega + c1 * (drive + friction)) / denominator
                    if omega > 0.0:
                        omega = 0.0
                pos += 0.5 * (previous_omega + omega) * pulse_per_rad_dt
            # ---- the end stops: the horn stays at one it reaches, its speed 0
            if pos > high:
                pos = high
                omega = 0.0
                hand_left = 0.0
            elif pos < low:
                pos = low
                omega = 0.0
                hand_left = 0.0
            current = (duty * volts - ke * omega) / r_ohm if torque_on else 0.0
            sum_i2 += current * current
            if saturated and abs(current) > overload_current:
                overload_s += dt
                if overload_s > OVERLOAD_TIME_S:
                    overload_seen = True
            else:
                overload_s = 0.0
            # ---- idle fast path: nothing will change in the remaining periods
            if omega == 0.0 and previous_omega == 0.0 and duty == previous_duty \
                    and not changing:
                frozen_count += 1
                if frozen_count >= 2 and step < steps:
                    rest = steps - step
                    sum_i2 += current * current * rest
                    if saturated and abs(current) > overload_current:
                        overload_s += dt * rest
                        if overload_s > OVERLOAD_TIME_S:
                            overload_seen = True
                    step = steps
            else:
                frozen_count = 0

        self._omega_rad_s = omega
        self.horn_position_pulse = pos
        self._hand_left_pulse = hand_left
        self.duty = duty
        self.current_a = current
        self._overload_s = overload_s
        controller.store(self)
        if not torque_on:
            self._traj_pulse = pos
            self._traj_vel_pulse_ms = 0.0
            self._traj_acc_pulse_ms2 = 0.0
            self._target_pulse = pos
        return sum_i2, overload_seen

    def _load_raw(self) -> int:
        """Return Present Load: the motor's torque over the stall torque at the present supply."""
        ratio = self._load_per_unit or 0.001
        full = round(1.0 / ratio)
        stall_nm = self.motor.stall_torque_nm(self.input_voltage_v)
        if stall_nm <= 0.0:
            return 0  # no supply worth the name: no torque to be a share of
        return _clamp_int(self.motor_torque_nm / stall_nm / ratio, -full, full)

    def _publish(self, regs: RegisterStore, mode: Optional[int], torque_on: bool,
                 overloaded_span: bool) -> int:
        """Write the present registers; return the detected error bits."""
        get = regs.get
        homing = _homing_offset(regs, self._homing_ignored)
        offset = self._turn_offset_pulse + homing
        velocity_raw = _clamp_int(self._omega_rad_s * self._velocity_unit_per_rad_s,
                                  INT32_MIN, INT32_MAX)
        position_raw = self._present_position_raw(homing)
        if self._ampere_per_unit is not None:
            current_raw = _clamp_int(self.current_a / self._ampere_per_unit, -32768, 32767)
        else:
            current_raw = self._load_raw()
        pwm_raw = _clamp_int(self.duty * self._pwm_full_raw, -32768, 32767)
        voltage_raw = _clamp_int(self.input_voltage_v / self._volt_per_unit, 0, 65535)
        temperature_raw = _clamp_int(self.temperature_c, 0, 255)

        position_mode = mode in POSITION_MODES
        profile_on = position_mode and torque_on and self._profile is not None
        status = 0
        position_trajectory = get('position_trajectory')
        if position_mode:
            velocity_trajectory = _clamp_int(
                self._traj_vel_pulse_ms * self._velocity_raw_per_pulse_ms, INT32_MIN, INT32_MAX)
            position_trajectory = _clamp_int(self._traj_pulse + offset, INT32_MIN, INT32_MAX)
            if torque_on:
                status = self._profile_kind
                if profile_on:
                    status |= MOVING_STATUS_PROFILE_ONGOING
                elif abs(self._target_pulse - self.horn_position_pulse) <= IN_POSITION_PULSE:
                    status |= MOVING_STATUS_IN_POSITION
                if self._profile_kind != PROFILE_STEP and \
                        abs(self._traj_pulse - self.horn_position_pulse) > FOLLOWING_ERROR_PULSE:
                    status |= MOVING_STATUS_FOLLOWING_ERROR
        elif mode == MODE_VELOCITY:
            velocity_trajectory = _clamp_int(self._vel_traj_raw if torque_on else 0.0,
                                             INT32_MIN, INT32_MAX)
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
