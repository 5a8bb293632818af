"""
Velocity profiles of the XM430 manual's "Profile Velocity(112)" section, as pure functions.

Units (from the manual's formulas t1 = 64 * V / A ms and t2 = 64 * dPos / V ms):

* one velocity unit (0.229 rpm = 0.01563 pulse/ms) is taken as exactly 1/64 pulse per ms, so a
  profile velocity V moves V / 64 pulses per ms (0.05 % off the true unit; the manual's formulas
  use the same rounding);
* one acceleration unit is 1/64 velocity unit per ms, so A adds A / 64 velocity units per ms, that
  is A / 4096 pulses per ms^2.

Derivation of the triangular case (start at rest, accelerate at a = A / 4096 pulse/ms^2 to a peak
v_p, decelerate at a back to 0): dPos = v_p^2 / a, so v_p = sqrt(a * dPos) pulse/ms; in velocity
units V_tri = 64 * v_p = sqrt(A * dPos). The manual uses the triangular profile when
V_tri <= V. Its travel time is t3 = 2 * v_p / a = 2 * 64 * V_tri / A = 128 * sqrt(dPos / A) ms.
The trapezoid accelerates for t1 = 64 * V / A ms, cruises and decelerates for t1, and takes
t3 = t1 + t2 with t2 = 64 * dPos / V ms.

Jerk smoothing is not modelled (the manual says the real travel time may be longer than t3); the
simulated trajectory ends exactly at t3.

A time-based profile (Drive Mode bit 2, the e-manual's "Profile Configuration") counts both
registers in ms: Profile Velocity is the time of the whole move (t3), Profile Acceleration the
time it accelerates (t1, and again to decelerate), at most half of t3 (the e-manual: it "will
not exceed" 50 %: a larger one is taken as half here). 0 ms of acceleration is the rectangular
profile, exactly half the triangular one, anything between the trapezoidal; Profile Velocity 0
is the step, as velocity-based. plan_timed keeps the velocity override: from a start velocity
v0 the move accelerates linearly to a cruise speed for t1, cruises, and decelerates to rest for
t1, with the cruise speed that makes it end at the goal at t3 exactly (v0 t1 / 2 + vc (t3 - t1)
is the distance). In velocity mode t1 is the time to reach Goal Velocity (ramp_timed).

Other families count profiles in other units (the P series: 0.01 rpm and 1 rev/min^2): plan
and ramp take a ProfileUnits, the X series' (the manual's rounding above) unless told.
"""

from dataclasses import dataclass
import math

# Moving Status (123) profile type bits; the manual's table repeats "Rectangular" for 0x00, which
# is the Step profile (no profile).
PROFILE_STEP = 0x00
PROFILE_RECTANGULAR = 0x10
PROFILE_TRIANGULAR = 0x20
PROFILE_TRAPEZOIDAL = 0x30

VELOCITY_UNIT_PULSE_MS = 1.0 / 64.0       # one profile velocity unit in pulse/ms
ACCELERATION_UNIT_PULSE_MS2 = 1.0 / 4096.0  # one profile acceleration unit in pulse/ms^2


@dataclass(frozen=True)
class ProfileUnits:
    """One profile velocity unit in pulse/ms and one acceleration unit in pulse/ms^2."""

    velocity_pulse_ms: float = VELOCITY_UNIT_PULSE_MS
    acceleration_pulse_ms2: float = ACCELERATION_UNIT_PULSE_MS2

    @property
    def velocity_units_per_ms(self) -> float:
        """Return the velocity units one acceleration unit adds per ms (1/64 on the X)."""
        return self.acceleration_pulse_ms2 / self.velocity_pulse_ms


X_UNITS = ProfileUnits()


@dataclass(frozen=True)
class Segment:
    """A span of constant acceleration: start time, position, velocity, acceleration, length."""

    start_ms: float
    start_pulse: float
    start_velocity_pulse_ms: float
    acceleration_pulse_ms2: float
    duration_ms: float


class PositionProfile:
    """A planned position trajectory: constant-acceleration segments ending at rest at the goal."""

    def __init__(self, kind: int, start_pulse: float, goal_pulse: float,
                 segments: list[Segment]) -> None:
        self.kind = kind
        self.start_pulse = start_pulse
        self.goal_pulse = goal_pulse
        self.segments = segments
        self.duration_ms = (segments[-1].start_ms + segments[-1].duration_ms) if segments else 0.0
        self._index = 0

    def sample(self, t_ms: float) -> tuple[float, float, float]:
        """Return (position pulse, velocity pulse/ms, acceleration pulse/ms^2) at t_ms."""
        if t_ms >= self.duration_ms:
            return self.goal_pulse, 0.0, 0.0
        segments = self.segments
        index = self._index
        if segments[index].start_ms > t_ms:
            index = 0  # time went back (not expected): search from the start
        while segments[index].start_ms + segments[index].duration_ms <= t_ms:
            index += 1
        self._index = index
        seg = segments[index]
        tau = t_ms - seg.start_ms
        acc = seg.acceleration_pulse_ms2
        vel = seg.start_velocity_pulse_ms + acc * tau
        pos = seg.start_pulse + (seg.start_velocity_pulse_ms + 0.5 * acc * tau) * tau
        return pos, vel, acc


def classify(profile_velocity_raw: int, profile_acceleration_raw: int, delta_pulse: float) -> int:
    """Return the profile type the manual's selection table gives for a start at rest."""
    if profile_velocity_raw == 0:
        return PROFILE_STEP
    if profile_acceleration_raw == 0:
        return PROFILE_RECTANGULAR
    v_tri = math.sqrt(profile_acceleration_raw * abs(delta_pulse))
    return PROFILE_TRIANGULAR if v_tri <= profile_velocity_raw else PROFILE_TRAPEZOIDAL


def travel_time_ms(profile_velocity_raw: int, profile_acceleration_raw: int,
                   delta_pulse: float) -> float:
    """Return the manual's travel time t3 (ms) of a move starting at rest."""
    kind = classify(profile_velocity_raw, profile_acceleration_raw, delta_pulse)
    distance = abs(delta_pulse)
    if kind == PROFILE_STEP:
        return 0.0
    t2_ms = 64.0 * distance / profile_velocity_raw
    if kind == PROFILE_RECTANGULAR:
        return t2_ms
    if kind == PROFILE_TRIANGULAR:
        return 128.0 * math.sqrt(distance / profile_acceleration_raw)
    return 64.0 * profile_velocity_raw / profile_acceleration_raw + t2_ms


def plan_position(start_pulse: float, start_velocity_pulse_ms: float, goal_pulse: float,
                  profile_velocity_raw: int, profile_acceleration_raw: int,
                  units: ProfileUnits = X_UNITS) -> PositionProfile:
    """
    Plan a move from (start, start velocity) to rest at goal.

    A non-zero start velocity is the manual's velocity override: the new profile continues from the
    present trajectory velocity (decelerating first when moving away from the goal or too fast to
    stop before it).
    """
    if profile_velocity_raw <= 0:
        return PositionProfile(PROFILE_STEP, start_pulse, goal_pulse, [])
    vmax = profile_velocity_raw * units.velocity_pulse_ms
    segments: list[Segment] = []
    if profile_acceleration_raw <= 0:
        # Infinite acceleration: the velocity jumps to V and back to 0.
        distance = goal_pulse - start_pulse
        if distance != 0.0:
            direction = 1.0 if distance > 0.0 else -1.0
            segments.append(Segment(0.0, start_pulse, direction * vmax, 0.0,
                                    abs(distance) / vmax))
        return PositionProfile(PROFILE_RECTANGULAR, start_pulse, goal_pulse, segments)

    acc = profile_acceleration_raw * units.acceleration_pulse_ms2
    t_ms = 0.0
    pos = start_pulse
    vel = start_velocity_pulse_ms

    def add(accel: float, duration_ms: float) -> None:
        nonlocal t_ms, pos, vel
        if duration_ms <= 0.0:
            return
        segments.append(Segment(t_ms, pos, vel, accel, duration_ms))
        pos += (vel + 0.5 * accel * duration_ms) * duration_ms
        vel += accel * duration_ms
        t_ms += duration_ms

    kind = PROFILE_TRAPEZOIDAL
    for _ in range(3):  # at most: stop, (reverse) plan; the loop bound guards float corner cases
        distance = goal_pulse - pos
        if distance == 0.0 and vel == 0.0:
            break
        direction = 1.0 if distance > 0.0 or (distance == 0.0 and vel > 0.0) else -1.0
        speed = direction * vel          # >= 0 when moving towards the goal
        remaining = abs(distance)
        if speed < 0.0 or speed * speed / (2.0 * acc) > remaining:
            # Moving away, or too fast to stop in time: brake to rest first, then plan again.
            add(-acc if vel > 0.0 else acc, abs(vel) / acc)
            vel = 0.0
            continue
        if speed > vmax:
            decel_ms = (speed - vmax) / acc
            d1 = (speed * speed - vmax * vmax) / (2.0 * acc)
            d3 = vmax * vmax / (2.0 * acc)
            add(-direction * acc, decel_ms)
            add(0.0, max(0.0, remaining - d1 - d3) / vmax)
            add(-direction * acc, vmax / acc)
            kind = PROFILE_TRAPEZOIDAL
        else:
            d1 = (vmax * vmax - speed * speed) / (2.0 * acc)
            d3 = vmax * vmax / (2.0 * acc)
            if d1 + d3 < remaining:
                add(direction * acc, (vmax - speed) / acc)
                add(0.0, (remaining - d1 - d3) / vmax)
                add(-direction * acc, vmax / acc)
                kind = PROFILE_TRAPEZOIDAL
            else:
                peak = math.sqrt((2.0 * acc * remaining + speed * speed) / 2.0)
                add(direction * acc, (peak - speed) / acc)
                add(-direction * acc, peak / acc)
                kind = PROFILE_TRIANGULAR
        break
    return PositionProfile(kind, start_pulse, goal_pulse, segments)


def ramp_velocity(velocity_raw: float, target_raw: float, acceleration_raw: int,
                  dt_ms: float, units: ProfileUnits = X_UNITS) -> float:
    """
    Velocity-mode profile: move velocity_raw towards target_raw for dt_ms.

    Profile acceleration A adds A / 64 velocity units per ms (so t1 = 64 * goal_velocity / A ms);
    A = 0 is the step profile (the target applies at once).
    """
    if acceleration_raw <= 0:
        return target_raw
    step = acceleration_raw * dt_ms * units.velocity_units_per_ms
    if velocity_raw < target_raw:
        return min(target_raw, velocity_raw + step)
    return max(target_raw, velocity_raw - step)


def plan_timed(start_pulse: float, start_velocity_pulse_ms: float, goal_pulse: float,
               total_ms: int, acceleration_ms: int) -> PositionProfile:
    """Plan a time-based move: rest at goal after total_ms, accelerating for acceleration_ms."""
    if total_ms <= 0:
        return PositionProfile(PROFILE_STEP, start_pulse, goal_pulse, [])
    t3 = float(total_ms)
    t1 = min(float(max(acceleration_ms, 0)), t3 / 2.0)
    v0 = start_velocity_pulse_ms if t1 > 0.0 else 0.0
    cruise = (goal_pulse - start_pulse - 0.5 * v0 * t1) / (t3 - t1)
    segments: list[Segment] = []
    t_ms, pos, vel = 0.0, start_pulse, v0
    for accel, duration in (((cruise - v0) / t1 if t1 else 0.0, t1),
                            (0.0, t3 - 2.0 * t1),
                            (-cruise / t1 if t1 else 0.0, t1)):
        if duration <= 0.0:
            continue
        if not segments and t1 == 0.0:
            vel = cruise   # rectangular: the speed jumps to the cruise speed
        segments.append(Segment(t_ms, pos, vel, accel, duration))
        pos += (vel + 0.5 * accel * duration) * duration
        vel += accel * duration
        t_ms += duration
    if t1 == 0.0:
        kind = PROFILE_RECTANGULAR
    elif 2.0 * t1 >= t3:
        kind = PROFILE_TRIANGULAR
    else:
        kind = PROFILE_TRAPEZOIDAL
    if goal_pulse == start_pulse and v0 == 0.0:
        segments = []
    return PositionProfile(kind, start_pulse, goal_pulse, segments)


def ramp_timed(velocity_raw: float, target_raw: float, rate_raw_per_ms: float,
               dt_ms: float) -> float:
    """Velocity mode, time-based: move towards target at the rate its goal was given (units/ms)."""
    if rate_raw_per_ms <= 0.0:
        return target_raw
    step = rate_raw_per_ms * dt_ms
    if velocity_raw < target_raw:
        return min(target_raw, velocity_raw + step)
    return max(target_raw, velocity_raw - step)
