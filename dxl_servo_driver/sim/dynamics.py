"""
Physics of one simulated servo of any supported model: its motor and horn through time.

The servo (servo.SimServo) owns the control table and calls ServoDynamics: advance() runs the
controllers and the motor for a time span, the on_* hooks react to writes. The model (the XM430
manual's 1030 by default) gives the motor (motor.motor_for), the units of the registers, the
hardware error bits, the position it starts at (its zero, mid-turn) and the supply (its nominal
voltage). Choices where the XM430 manual is silent or ambiguous (see also motor.py,
control_modes.py for the controllers, present_registers.py for what the registers report and
velocity_profile.py):

* Control period 1 ms: advance() runs whole periods and carries the remainder to the next call.
  While the servo is frozen (horn stuck by friction or load, constant output, no profile running,
  integrators idle) the rest of a span is jumped in one go, so an idle hour costs microseconds.
* Overload (0x20): the controller demands more than its output limit (PWM limit, or Goal PWM in
  PWM mode at the PWM limit) while the motor is loaded (current above half the stall current at
  the present supply), continuously for more than OVERLOAD_TIME_S. Current limiting by Goal
  Current in mode 5 is regulation, not overload.
* Torque on holds the present position (the trajectory restarts there); a goal written with
  torque off is not acted on. Torque off is free-run: the windings are open, no current flows,
  the horn coasts until friction and load stop it.

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

One span of advance() (_run) is the motor, gearbox (plant.Plant) and overload timer of every
mode, and the controller of the operating mode (control_modes.ModeControllers.select: position
for the three position modes, velocity, current, PWM; free with torque off) gives the output
each 1 ms period. The loop keeps the motor's state in local variables (it runs a thousand times
per simulated second per servo); the controllers keep their own integrators, profile and
trajectory.
"""

import math
from typing import Optional

from dxl_servo_driver.models import Model
from dxl_servo_driver.models.xm430 import INT32_MAX, INT32_MIN
from dxl_servo_driver.sim import motor
from dxl_servo_driver.sim.control_modes import (
    MODE_POSITION, ModeControllers, POSITION_MODES, profile_units)
from dxl_servo_driver.sim.memory import MANUAL_MODEL
from dxl_servo_driver.sim.plant import CONTROL_PERIOD_S, Plant
from dxl_servo_driver.sim.present_registers import (
    clamp_int, homing_offset, PresentRegisters, RegisterStore)

OVERLOAD_TIME_S = 1.0
OVERLOAD_CURRENT_FRACTION = 0.5


class ServoDynamics:
    """
    Motor, gearbox and thermal model of one servo, driven by its controllers.

    The controllers (control_modes.ModeControllers) are objects of their own; this holds the one
    state of a horn (its motor, position, velocity, temperature, the hand on it and its stops)
    that every step of every mode advances together.
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
        self._pulse_per_rad = model.pulses_per_rev / (2.0 * math.pi)
        self._velocity_unit_per_rad_s = motor.rad_s_to_rpm(1.0) / model.velocity_unit_rpm
        self._present = PresentRegisters(model)
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
        self.omega_rad_s = 0.0
        self.turn_offset_pulse = 0
        self._mode: Optional[int] = None
        self._torque_on = False
        self._remainder_s = 0.0
        # A hand turning the horn: pulses left to go, their sign, pulses per control period.
        self._hand_left_pulse = 0.0
        self._hand_sign = 1.0
        self._hand_step_pulse = 0.0
        # Drive Mode: the frame's direction against the horn (-1: reversed, bit 0) and what
        # makes profiles times (bit 2); their bits on this model (None: it has no such bit).
        self._direction = 1.0
        self._reverse_bit = model.reverse_bit
        self._time_bit = model.time_profile_bit
        # The mechanical end stops, in horn pulses (+-inf: none).
        self.stop_low_pulse = -math.inf
        self.stop_high_pulse = math.inf
        self.controllers = ModeControllers(model, profile_units(model), self._pulse_per_rad,
                                           self._velocity_unit_per_rad_s,
                                           self.horn_position_pulse)
        # The controllers that keep a state across spans (the goal and torque hooks set it).
        self._position = self.controllers.position
        self._velocity = self.controllers.velocity
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
        return raw - self.turn_offset_pulse - homing_offset(regs, self._homing_ignored)

    def rad_of(self, horn_pulse: float, regs: RegisterStore) -> float:
        """Return the servo radians Present Position reads at a horn position (pulses)."""
        raw = horn_pulse + self.turn_offset_pulse + homing_offset(regs, self._homing_ignored)
        return (raw - self.model.position_zero_raw) / self._pulse_per_rad

    def start_turn(self, rad: float, seconds: float, regs: RegisterStore) -> None:
        """
        Turn the horn by hand to rad (servo radians) at constant speed over seconds (0: at once).

        The caller has checked that torque is off; the horn stops at an end stop on the way.
        """
        target = min(max(self.horn_pulse_of(rad, regs), self.stop_low_pulse),
                     self.stop_high_pulse)
        distance = target - self.horn_position_pulse
        self.omega_rad_s = 0.0
        periods = seconds / CONTROL_PERIOD_S
        if periods < 1.0 or distance == 0.0:
            self.horn_position_pulse = target
            self._hand_left_pulse = 0.0
            # Torque is off: the trajectory follows the horn (as _run keeps it).
            self._position.traj_pulse = self._position.target_pulse = target
            return
        self._hand_sign = 1.0 if distance > 0.0 else -1.0
        self._hand_left_pulse = abs(distance)
        self._hand_step_pulse = abs(distance) / periods

    def stop_hand(self) -> None:
        """Let go of the horn: it stays where it is."""
        if self._hand_left_pulse > 0.0:
            self._hand_left_pulse = 0.0
            self.omega_rad_s = 0.0

    def hand_coast(self, dt_s: float) -> None:
        """Move the horn of an unpowered servo as the hand turns it for dt_s (no registers)."""
        if self._hand_left_pulse <= 0.0 or dt_s <= 0.0:
            return
        step = min(self._hand_step_pulse * dt_s / CONTROL_PERIOD_S, self._hand_left_pulse)
        self._hand_left_pulse -= step
        self.horn_position_pulse += self._hand_sign * step
        if self._hand_left_pulse <= 0.0:
            self._hand_left_pulse = 0.0
            self.omega_rad_s = 0.0

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
        self._overload_s = 0.0
        self.controllers.reset(self.horn_position_pulse)

    def on_torque(self, enabled: bool, regs: RegisterStore) -> None:
        """Torque enable changed: restart the controllers from the present state."""
        self._torque_on = bool(enabled)
        if self._torque_on:
            self.stop_hand()   # the motor holds the horn where the hand had it
        self.reset_controllers()
        if self._torque_on:
            self._velocity.target = self.omega_rad_s * self._velocity_unit_per_rad_s
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
        homing = homing_offset(regs, self._homing_ignored)
        goal_pulse = float(goal - self.turn_offset_pulse - homing)
        self._position.plan(goal_pulse, regs.get, self._timed(regs))

    def on_goal_velocity(self, regs: RegisterStore) -> None:
        """Goal velocity written: the ramp reads it every period (so override is built in)."""
        if self._mode != regs.get('operating_mode'):
            self._sync_mode_and_torque(regs)
        self._velocity.aim(regs.get, self._timed(regs))

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
        self.omega_rad_s = -self.omega_rad_s
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
        self.turn_offset_pulse = int(round(-self._pulses_per_rev * turns))
        homing = homing_offset(regs, self._homing_ignored)
        regs.set('present_position', self.present_position_raw(homing))

    # ----------------------------------------------------------------- simulation
    def _sync_mode_and_torque(self, regs: RegisterStore) -> None:
        mode = regs.get('operating_mode')
        torque = bool(regs.get('torque_enable'))
        if mode != self._mode:
            self._mode = mode
            self.on_torque(torque, regs)
        elif torque != self._torque_on:
            self.on_torque(torque, regs)

    def present_position_raw(self, homing: int) -> int:
        """Return Present Position for the horn where it is and a homing offset."""
        value = self.horn_position_pulse + self.turn_offset_pulse + homing
        return clamp_int(value, INT32_MIN, INT32_MAX)

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
        return self._present.publish(regs, self, mode, torque_on, overloaded_span)

    def _run(self, steps: int, regs: RegisterStore, mode: Optional[int], torque_on: bool,
             volts: float) -> tuple[float, bool]:
        """
        Run whole control periods; return (sum of i^2 over the periods, overload seen).

        The mode's controller gives the output each period; the motor, the gearbox and the
        overload timer are the same in every mode.
        """
        low = self.stop_low_pulse
        high = self.stop_high_pulse
        plant = Plant(self.motor, self.load_nm, torque_on, volts, low, high)
        control = self.controllers.select(regs.get, mode, torque_on, plant).step
        dt = CONTROL_PERIOD_S
        r_ohm = plant.r_ohm
        ke = plant.ke
        c1 = plant.c1
        ktr = plant.ktr
        denominator = plant.denominator
        friction = plant.friction
        pulse_per_rad_dt = self._pulse_per_rad * dt
        overload_current = OVERLOAD_CURRENT_FRACTION * volts / r_ohm

        omega = self.omega_rad_s
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

        self.omega_rad_s = omega
        self.horn_position_pulse = pos
        self._hand_left_pulse = hand_left
        self.duty = duty
        self.current_a = current
        self._overload_s = overload_s
        if not torque_on:
            self._position.follow(pos)
        return sum_i2, overload_seen
