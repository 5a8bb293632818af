"""Velocity profiles: the XM430 manual's selection table and timing formulas, in the servo too."""

import math

from dxl_servo_driver.sim.velocity_profile import (
    classify, plan_position, PROFILE_RECTANGULAR, PROFILE_STEP, PROFILE_TRAPEZOIDAL,
    PROFILE_TRIANGULAR, ramp_velocity, travel_time_ms)
from hypothesis import given, settings, strategies as st
import pytest
from sim_rig import Rig

velocities = st.integers(min_value=1, max_value=1023)
accelerations = st.integers(min_value=1, max_value=32767)
distances = st.integers(min_value=-1_000_000, max_value=1_000_000).filter(lambda d: d != 0)
# The Hypothesis profile's budget (test/conftest.py): 100 examples in make test, 2000 in fuzz.
EXAMPLES = settings.default.max_examples


# ---------------------------------------------------------------------------- pure profiles
def test_selection_table_examples() -> None:
    assert classify(0, 0, 100) == PROFILE_STEP
    assert classify(0, 50, 100) == PROFILE_STEP
    assert classify(10, 0, 100) == PROFILE_RECTANGULAR
    assert classify(100, 20, 2000) == PROFILE_TRAPEZOIDAL   # V_tri = 200 > 100
    assert classify(150, 30, 500) == PROFILE_TRIANGULAR     # V_tri = 122.5 <= 150
    assert classify(100, 25, 400) == PROFILE_TRIANGULAR     # V_tri == V: triangular per the manual
    assert travel_time_ms(100, 20, 2000) == pytest.approx(320.0 + 1280.0)
    assert travel_time_ms(60, 0, -600) == pytest.approx(640.0)
    assert travel_time_ms(150, 30, 500) == pytest.approx(128.0 * math.sqrt(500 / 30))


@settings(max_examples=3 * EXAMPLES)
@given(velocities, accelerations, distances, st.integers(-5000, 5000))
def test_plan_from_rest_matches_formulas(v_raw: int, a_raw: int, delta: int, start: int) -> None:
    profile = plan_position(float(start), 0.0, float(start + delta), v_raw, a_raw)
    assert profile.kind == classify(v_raw, a_raw, delta)
    assert profile.duration_ms == pytest.approx(travel_time_ms(v_raw, a_raw, delta), rel=1e-9)
    vmax = v_raw / 64.0
    amax = a_raw / 4096.0
    previous = float(start)
    for i in range(1, 41):
        pos, vel, acc = profile.sample(profile.duration_ms * i / 40.0)
        assert abs(vel) <= vmax * (1 + 1e-9)
        assert abs(acc) <= amax * (1 + 1e-9)
        assert (pos - previous) * delta >= -1e-6  # never moves backwards
        previous = pos
    end = profile.sample(profile.duration_ms)
    assert end == (float(start + delta), 0.0, 0.0)
    last = profile.sample(profile.duration_ms * (1 - 1e-12))
    assert last[0] == pytest.approx(start + delta, abs=1e-3 + 1e-9 * abs(delta))


@settings(max_examples=3 * EXAMPLES)
@given(st.integers(1, 400), st.integers(1, 500), st.integers(-50_000, 50_000),
       st.floats(-2.0, 2.0))
def test_override_keeps_velocity_continuous_and_ends_at_goal(
        v_raw: int, a_raw: int, delta: int, v0_fraction: float) -> None:
    vmax = v_raw / 64.0
    v0 = v0_fraction * vmax
    profile = plan_position(100.0, v0, 100.0 + delta, v_raw, a_raw)
    assert profile.kind in (PROFILE_TRIANGULAR, PROFILE_TRAPEZOIDAL)
    pos0, vel0, _ = profile.sample(0.0)
    assert pos0 == pytest.approx(100.0)
    if profile.duration_ms > 0:
        assert vel0 == pytest.approx(v0)
    amax = a_raw / 4096.0
    limit = max(vmax, abs(v0)) * (1 + 1e-9)
    previous_pos, previous_vel = pos0, vel0
    dt_ms = profile.duration_ms / 200.0
    for i in range(1, 201):
        pos, vel, acc = profile.sample(dt_ms * i)
        assert abs(vel) <= limit
        assert abs(acc) <= amax * (1 + 1e-9)
        assert abs(vel - previous_vel) <= amax * dt_ms * (1 + 1e-6) + 1e-9
        assert abs(pos - previous_pos) <= limit * dt_ms + 1e-6
        previous_pos, previous_vel = pos, vel
    assert profile.sample(profile.duration_ms) == (100.0 + delta, 0.0, 0.0)


@settings(max_examples=2 * EXAMPLES)
@given(st.integers(-1023, 1023), st.integers(-1023, 1023), st.integers(1, 32767))
def test_velocity_ramp_takes_t1(start: int, target: int, a_raw: int) -> None:
    value = float(start)
    steps = 0
    while value != target:
        value = ramp_velocity(value, float(target), a_raw, 1.0)
        steps += 1
        assert steps < 200_000
    assert steps == math.ceil(64.0 * abs(target - start) / a_raw - 1e-9)
    assert ramp_velocity(float(start), float(target), 0, 1.0) == target


# ---------------------------------------------------------------------------- inside the servo
@pytest.mark.parametrize('v_raw, a_raw, delta, kind', [
    (100, 20, 2000, 0x30),
    (150, 30, -500, 0x20),
    (60, 0, 600, 0x10),
])
def test_move_reaches_goal_in_t3(v_raw: int, a_raw: int, delta: int, kind: int) -> None:
    rig = Rig(mode=4)
    start = rig.reg('present_position')
    rig.write(torque_enable=1, profile_velocity=v_raw, profile_acceleration=a_raw)
    rig.write(goal_position=start + delta)
    t3_ms = travel_time_ms(v_raw, a_raw, delta)
    elapsed_ms = 0
    while rig.reg('moving_status') & 0x02 or elapsed_ms == 0:
        rig.step()
        elapsed_ms += 1
        status = rig.reg('moving_status')
        if status & 0x02:
            assert status & 0x30 == kind
            assert status & 0x08 == 0
            assert rig.reg('moving') == 1
        assert elapsed_ms < 3 * t3_ms
    assert abs(elapsed_ms - t3_ms) <= 0.05 * t3_ms
    assert rig.reg('velocity_trajectory') == 0
    assert rig.reg('position_trajectory') == start + delta
    for _ in range(300):
        rig.step()
    assert abs(rig.reg('present_position') - (start + delta)) <= 20
    assert rig.reg('moving_status') == kind | 0x01
    assert rig.reg('moving') == 0


def test_step_move() -> None:
    rig = Rig(mode=4)
    start = rig.reg('present_position')
    rig.write(torque_enable=1)
    rig.write(goal_position=start + 1000)
    rig.step()
    assert rig.reg('position_trajectory') == start + 1000
    assert rig.reg('moving_status') & 0x33 == 0x00  # step: no profile running, not in position
    elapsed_ms = 1
    while not rig.reg('moving_status') & 0x01:
        rig.step()
        elapsed_ms += 1
        assert elapsed_ms < 1000
    # Limited only by the motor: 1000 pulses at up to ~3150 pulse/s plus acceleration.
    assert elapsed_ms > 1000 / 3300 * 1000
    assert rig.reg('moving_status') == 0x01


def test_velocity_override_is_continuous() -> None:
    rig = Rig(mode=4)
    start = rig.reg('present_position')
    rig.write(torque_enable=1, profile_velocity=100, profile_acceleration=20)
    rig.write(goal_position=start + 3000)
    trace = []
    for _ in range(500):
        rig.step()
        trace.append(rig.reg('velocity_trajectory'))
    assert trace[-1] == 100
    rig.write(goal_position=start)  # reverse in mid-move: brake from the present velocity
    for _ in range(3000):
        rig.step()
        trace.append(rig.reg('velocity_trajectory'))
    steps = [abs(b - a) for a, b in zip(trace, trace[1:])]
    assert max(steps) <= 1  # 20 / 64 velocity units per ms, no jump at the override
    assert min(trace) == -100
    assert rig.reg('position_trajectory') == start
    # A new goal in the same direction keeps cruising instead of restarting from rest.
    rig.write(goal_position=start + 3000)
    for _ in range(600):
        rig.step()
    rig.write(goal_position=start + 4000)
    rig.step()
    assert rig.reg('velocity_trajectory') == 100


def test_velocity_mode_acceleration_time_t1() -> None:
    rig = Rig(mode=1)
    rig.write(torque_enable=1, profile_acceleration=50)
    rig.write(goal_velocity=100)
    t1_ms = 64 * 100 / 50
    elapsed_ms = 0
    while rig.reg('velocity_trajectory') != 100:
        rig.step()
        elapsed_ms += 1
        assert rig.reg('moving_status') & 0x30 == 0x30
        assert elapsed_ms < 1000
    assert abs(elapsed_ms - t1_ms) <= 0.05 * t1_ms
    for _ in range(300):
        rig.step()
    assert rig.reg('velocity_trajectory') == 100
    assert abs(rig.reg('present_velocity') - 100) <= 1
    # Override mid-ramp continues from the present trajectory velocity.
    rig.write(goal_velocity=-100)
    previous = rig.reg('velocity_trajectory')
    for _ in range(400):
        rig.step()
        value = rig.reg('velocity_trajectory')
        assert abs(value - previous) <= 1
        previous = value
    assert previous == -100


def test_velocity_mode_step_without_acceleration() -> None:
    rig = Rig(mode=1)
    rig.write(torque_enable=1)
    rig.write(goal_velocity=150)
    rig.step()
    assert rig.reg('velocity_trajectory') == 150
    assert rig.reg('moving_status') == 0x00
    for _ in range(300):
        rig.step()
    assert abs(rig.reg('present_velocity') - 150) <= 1
