"""
The controllers of one simulated servo: one per operating mode, each keeping its own state.

ServoDynamics (dynamics.py) holds a ModeControllers; each advance() span, select() gives it the
controller of the mode with the gains and limits the registers hold then, and its loop calls that
controller's step() once per 1 ms control period. The position and velocity controllers keep
their integrators, profile and trajectory across spans; the goal hooks plan on them. Choices
where the XM430 manual is silent or ambiguous (see also velocity_profile.py):

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

step(omega, pos) runs once per control period on the horn's speed (rad/s) and position (pulses)
and returns (duty in [-1, 1], output saturated, still changing): the last says an integrator, a
ramp or a profile moved, which keeps advance()'s idle fast path off.
"""

import math
from typing import Callable, Optional, Union

from dxl_servo_driver.models import Model, modes
from dxl_servo_driver.sim.memory import MANUAL_MODEL
from dxl_servo_driver.sim.plant import CONTROL_PERIOD_S, Plant
from dxl_servo_driver.sim.velocity_profile import (
    plan_position, plan_timed, PositionProfile, PROFILE_STEP, ProfileUnits, ramp_timed,
    ramp_velocity, X_UNITS)

_PERIOD_MS = CONTROL_PERIOD_S * 1000.0

# The register values of the modes (models.modes is their one table).
MODE_CURRENT = modes.BY_NAME['current'].number
MODE_VELOCITY = modes.BY_NAME['velocity'].number
MODE_POSITION = modes.BY_NAME['position'].number
MODE_CURRENT_BASED_POSITION = modes.BY_NAME['current_based_position'].number
MODE_PWM = modes.BY_NAME['pwm'].number
POSITION_MODES = modes.POSITION_NUMBERS

Step = tuple[float, bool, bool]


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


class FreeControl:
    """Torque off (or a mode without a controller): the windings are open, no drive."""

    __slots__ = ()

    def step(self, omega: float, pos: float) -> Step:
        """Return no drive."""
        return 0.0, False, False


class PwmControl:
    """PWM mode: Goal PWM, within PWM Limit, is the output."""

    __slots__ = ('_out',)

    def __init__(self) -> None:
        self._out: Step = (0.0, False, False)

    def begin(self, goal_pwm: float, pwm_limit: int, full: float) -> 'PwmControl':
        """Take the output of a span; return self."""
        self._out = (goal_pwm / full, pwm_limit > 0 and abs(goal_pwm) >= pwm_limit, False)
        return self

    def step(self, omega: float, pos: float) -> Step:
        """Return the constant output."""
        return self._out


class CurrentControl:
    """Current mode: the output that drives Goal Current (within the limits) at this speed."""

    __slots__ = ('_plant', '_goal_a', '_out_limit', '_full')

    def begin(self, plant: Plant, goal_current_a: float, out_limit: float,
              full: float) -> 'CurrentControl':
        """Take the plant, the goal and the limit of a span; return self."""
        self._plant = plant
        self._goal_a = goal_current_a
        self._out_limit = out_limit
        self._full = full
        return self

    def step(self, omega: float, pos: float) -> Step:
        """Return the output for Goal Current."""
        out_limit = self._out_limit
        demand = self._plant.duty_for(self._goal_a, omega, self._full, pos)
        return (max(-out_limit, min(out_limit, demand)) / self._full,
                abs(demand) > out_limit, False)


class PositionControl:
    """
    The position modes (position, extended position, current-based position): PID + FF.

    The profile is sampled every period and the PID with the two feed-forwards acts on its
    trajectory. In current-based position the output is turned into the current it would drive,
    limited by Goal Current, and back into the output that drives that current. The profile,
    the trajectory and the goal are in horn pulses (without turn or homing offset).
    """

    __slots__ = ('_factors', '_units', '_pulse_per_rad_ms', '_velocity_raw_per_pulse_ms',
                 '_acceleration_raw_per_pulse_ms2', '_kpp', '_kpi', '_kpd', '_kff1', '_kff2',
                 '_plant', '_out_limit', '_full', '_current_limit_a', 'integral', 'profile',
                 'profile_t_ms', 'profile_kind', 'traj_pulse', 'traj_vel_pulse_ms',
                 'traj_acc_pulse_ms2', 'target_pulse')

    def __init__(self, factors: dict[str, float], units: ProfileUnits, pulse_per_rad: float,
                 horn_pulse: float) -> None:
        self._factors = (factors['position_p_gain'], factors['position_i_gain'],
                         factors['position_d_gain'], factors['feedforward_1st_gain'],
                         factors['feedforward_2nd_gain'])
        self._units = units
        self._pulse_per_rad_ms = pulse_per_rad / 1000.0
        self._velocity_raw_per_pulse_ms = 1.0 / units.velocity_pulse_ms
        self._acceleration_raw_per_pulse_ms2 = 1.0 / units.acceleration_pulse_ms2
        self.reset(horn_pulse)

    def reset(self, horn_pulse: float) -> None:
        """Clear the integral and the profile; the trajectory holds horn_pulse."""
        self.integral = 0.0
        self.profile: Optional[PositionProfile] = None
        self.profile_t_ms = 0.0
        self.profile_kind = PROFILE_STEP
        self.follow(horn_pulse)

    def follow(self, horn_pulse: float) -> None:
        """Put the trajectory and the goal on the horn at rest (torque off: it follows)."""
        self.traj_pulse = horn_pulse
        self.traj_vel_pulse_ms = 0.0
        self.traj_acc_pulse_ms2 = 0.0
        self.target_pulse = horn_pulse

    def plan(self, goal_pulse: float, get: Callable[[str], int], timed: bool) -> None:
        """Plan a profile to goal_pulse from the present trajectory (timed: Drive Mode bit 2)."""
        if timed:
            profile = plan_timed(self.traj_pulse, self.traj_vel_pulse_ms, goal_pulse,
                                 get('profile_velocity'), get('profile_acceleration'))
        else:
            profile = plan_position(self.traj_pulse, self.traj_vel_pulse_ms, goal_pulse,
                                    get('profile_velocity'), get('profile_acceleration'),
                                    self._units)
        self.profile = profile
        self.profile_t_ms = 0.0
        self.profile_kind = profile.kind
        self.target_pulse = goal_pulse
        if profile.duration_ms <= 0.0:
            self.traj_pulse = goal_pulse
            self.traj_vel_pulse_ms = 0.0
            self.traj_acc_pulse_ms2 = 0.0

    def begin(self, get: Callable[[str], int], plant: Plant, out_limit: float, full: float,
              current_limit_a: float | None) -> 'PositionControl':
        """Take the gains and limits of a span (current_limit_a: mode 5 only); return self."""
        kpp, kpi, kpd, kff1, kff2 = self._factors
        self._kpp = get('position_p_gain') / 128.0 * kpp
        self._kpi = get('position_i_gain') / 65536.0 * kpi
        self._kpd = get('position_d_gain') / 16.0 * kpd
        self._kff1 = get('feedforward_1st_gain') / 4.0 * kff1
        self._kff2 = get('feedforward_2nd_gain') / 4.0 * kff2
        self._plant = plant
        self._out_limit = out_limit
        self._full = full
        self._current_limit_a = current_limit_a
        return self

    def step(self, omega: float, pos: float) -> Step:
        """Follow the profile one period; return the PID + feed-forward output."""
        profile = self.profile
        if profile is not None:
            self.profile_t_ms += _PERIOD_MS
            self.traj_pulse, self.traj_vel_pulse_ms, self.traj_acc_pulse_ms2 = \
                profile.sample(self.profile_t_ms)
            if self.profile_t_ms >= profile.duration_ms:
                profile = self.profile = None
        full = self._full
        out_limit = self._out_limit
        traj_v = self.traj_vel_pulse_ms
        error = self.traj_pulse - pos
        traj_v_raw = traj_v * self._velocity_raw_per_pulse_ms
        demand = self._kpp * error + self._kpi * self.integral \
            + self._kpd * (traj_v - omega * self._pulse_per_rad_ms) \
            + self._kff1 * traj_v_raw \
            + self._kff2 * self.traj_acc_pulse_ms2 * self._acceleration_raw_per_pulse_ms2
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


class VelocityControl:
    """Velocity mode: a PI on the speed, its target ramped by Profile Acceleration."""

    __slots__ = ('_kvp_factor', '_kvi_factor', '_beta', '_units', '_unit_per_rad_s', '_kvp',
                 '_kvi', '_goal', '_acceleration_raw', '_out_limit', '_full', 'integral',
                 'target', 'timed_rate')

    def __init__(self, factors: dict[str, float], units: ProfileUnits, beta: float,
                 unit_per_rad_s: float) -> None:
        self._kvp_factor = factors['velocity_p_gain']
        self._kvi_factor = factors['velocity_i_gain']
        self._beta = beta                   # pulse/s per velocity unit
        self._units = units
        self._unit_per_rad_s = unit_per_rad_s
        self.reset()

    def reset(self) -> None:
        """Clear the integral; the target is 0 and no time-based rate is set."""
        self.integral = 0.0
        self.target = 0.0                   # the ramped goal, in velocity units
        # A time-based profile: the rate its goal was given (None: velocity-based).
        self.timed_rate: Optional[float] = None

    def aim(self, get: Callable[[str], int], timed: bool) -> None:
        """Goal Velocity written; timed (Drive Mode bit 2): reach it Profile Acceleration ms on."""
        if timed:
            rise_ms = get('profile_acceleration')
            change = abs(get('goal_velocity') - self.target)
            self.timed_rate = change / rise_ms if rise_ms > 0 else 0.0
        else:
            self.timed_rate = None

    def begin(self, get: Callable[[str], int], out_limit: float,
              full: float) -> 'VelocityControl':
        """Take the gains, the goal and the limit of a span; return self."""
        beta = self._beta
        self._kvp = get('velocity_p_gain') / 128.0 * beta * self._kvp_factor
        self._kvi = get('velocity_i_gain') / 65536.0 * beta * self._kvi_factor
        self._goal = float(get('goal_velocity'))
        self._acceleration_raw = get('profile_acceleration')
        self._out_limit = out_limit
        self._full = full
        return self

    def step(self, omega: float, pos: float) -> Step:
        """Ramp the target one period; return the PI output."""
        changing = False
        if self.target != self._goal:
            if self.timed_rate is None:
                self.target = ramp_velocity(self.target, self._goal, self._acceleration_raw,
                                            _PERIOD_MS, self._units)
            else:
                self.target = ramp_timed(self.target, self._goal, self.timed_rate, _PERIOD_MS)
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


Controller = Union[FreeControl, PwmControl, CurrentControl, PositionControl, VelocityControl]


class ModeControllers:
    """One servo's controllers, one per operating mode, and which of them acts in a span."""

    def __init__(self, model: Model, units: ProfileUnits, pulse_per_rad: float,
                 velocity_unit_per_rad_s: float, horn_pulse: float) -> None:
        factors = gain_factors(model)
        # beta: pulse/s per velocity unit, used by the velocity loop.
        beta = model.velocity_unit_rpm * model.pulses_per_rev / 60.0
        self.free = FreeControl()
        self.pwm = PwmControl()
        self.current = CurrentControl()
        self.position = PositionControl(factors, units, pulse_per_rad, horn_pulse)
        self.velocity = VelocityControl(factors, units, beta, velocity_unit_per_rad_s)
        self._pwm_full_raw = model.pwm_full_raw
        # Goal PWM caps the output in every mode (the XM430 manual) of a model that has a PWM
        # mode; a model without one (the Y) has it as a plain register, capped by PWM Limit.
        self._goal_pwm_caps = 'pwm' in model.modes
        # A per count of Goal Current, or None: no Goal Current nor Current Limit (nor the
        # modes that use them) on this model.
        self._ampere_per_unit = model.current_unit_a

    def reset(self, horn_pulse: float) -> None:
        """Clear every integrator, profile and ramp; the position trajectory holds horn_pulse."""
        self.position.reset(horn_pulse)
        self.velocity.reset()

    def select(self, get: Callable[[str], int], mode: Optional[int], torque_on: bool,
               plant: Plant) -> Controller:
        """Return the controller of the mode, with the limits and gains the registers hold now."""
        if not torque_on:
            return self.free
        full = float(self._pwm_full_raw)
        pwm_limit = max(0, get('pwm_limit'))
        if mode == MODE_PWM:
            return self.pwm.begin(float(max(-pwm_limit, min(pwm_limit, get('goal_pwm')))),
                                  pwm_limit, full)
        out_limit = float(min(abs(get('goal_pwm')), pwm_limit) if self._goal_pwm_caps
                          else pwm_limit)
        ampere_per_unit = self._ampere_per_unit
        if ampere_per_unit is None:
            current_limit_a = math.inf
            goal_current_a = 0.0
        else:
            current_limit_a = min(abs(get('goal_current')), max(0, get('current_limit'))) \
                * ampere_per_unit
            goal_current_a = max(-current_limit_a, min(current_limit_a, get('goal_current')
                                                       * ampere_per_unit))
        if mode == MODE_CURRENT:
            return self.current.begin(plant, goal_current_a, out_limit, full)
        if mode in POSITION_MODES:
            return self.position.begin(
                get, plant, out_limit, full,
                current_limit_a if mode == MODE_CURRENT_BASED_POSITION else None)
        if mode == MODE_VELOCITY:
            return self.velocity.begin(get, out_limit, full)
        return self.free
