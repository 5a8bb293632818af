"""
Drive Mode in the simulated servo: bit 0 reverses its frame, bit 2 times its profiles.

The e-manual's Drive Mode (10): bit 0 Normal/Reverse (Goal Position and Present Position count
the other way), bit 2 Profile Configuration (time-based: Profile Velocity is the time of the
whole move, Profile Acceleration the time it accelerates, both in ms, the second at most half
the first). Judged on the servo's own clock (the rig's 1 ms steps), never the wall clock.
"""

from dxl_servo_driver.protocol import ErrorCode
from dxl_servo_driver.sim import velocity_profile
from dxl_servo_driver.sim.control_modes import MODE_POSITION, MODE_VELOCITY
from dxl_servo_driver.sim.velocity_profile import (
    PROFILE_RECTANGULAR, PROFILE_TRAPEZOIDAL, PROFILE_TRIANGULAR)
import pytest
from sim_rig import Rig

PROFILE_ONGOING = 0x02


def move_time_ms(rig: Rig, goal: int) -> int:
    """Write a goal; return the ms (servo steps) its profile ran."""
    rig.write(goal_position=goal)
    steps = 0
    while True:
        rig.step()
        steps += 1
        if not rig.reg('moving_status') & PROFILE_ONGOING:
            return steps
        assert steps < 40_000, 'the profile never ended'


@pytest.mark.parametrize('rise_ms, kind', [(300, PROFILE_TRAPEZOIDAL), (0, PROFILE_RECTANGULAR),
                                           (1000, PROFILE_TRIANGULAR)])
def test_a_time_based_move_takes_profile_velocity_ms(rise_ms: int, kind: int) -> None:
    rig = Rig(MODE_POSITION)
    # 2000 ms is beyond this table's 0..1023 and its Velocity Limit: a time, not a speed.
    rig.write(drive_mode=4, profile_velocity=2000, profile_acceleration=rise_ms,
              torque_enable=1)
    start = rig.reg('present_position')
    for distance in (1000, -300):
        assert move_time_ms(rig, start + distance) == 2000
        assert rig.reg('moving_status') & 0x30 == kind
        rig.run(0.3)
        assert rig.reg('present_position') == pytest.approx(start + distance, abs=3)
        start = rig.reg('present_position')


def test_time_based_acceleration_lasts_profile_acceleration_ms() -> None:
    plan_timed = velocity_profile.plan_timed
    profile = plan_timed(0.0, 0.0, 1700.0, 2000, 300)
    cruise = 1700.0 / (2000 - 300)
    assert profile.sample(150.0)[1] == pytest.approx(cruise / 2)
    assert profile.sample(300.0)[1] == pytest.approx(cruise)
    assert profile.sample(1700.0)[1] == pytest.approx(cruise)
    assert profile.sample(1850.0)[1] == pytest.approx(cruise / 2)
    # More than half is taken as half (the e-manual: it does not exceed 50 %).
    assert plan_timed(0.0, 0.0, 100.0, 2000, 1500).kind == PROFILE_TRIANGULAR
    # A new goal while moving keeps the velocity and still ends on time at the goal.
    override = plan_timed(500.0, cruise, 0.0, 2000, 300)
    assert override.sample(0.0)[1] == pytest.approx(cruise)
    assert override.duration_ms == 2000.0
    assert override.sample(1999.999)[0] == pytest.approx(0.0, abs=1e-3)


def test_time_based_velocity_mode_reaches_its_goal_in_profile_acceleration_ms() -> None:
    rig = Rig(MODE_VELOCITY)
    rig.write(drive_mode=4, profile_acceleration=500, torque_enable=1, goal_velocity=100)
    rig.run(0.25)
    assert rig.reg('velocity_trajectory') == pytest.approx(50, abs=1)
    rig.run(0.25)
    assert rig.reg('velocity_trajectory') == 100


def test_the_table_takes_times_only_under_bit_2() -> None:
    rig = Rig(MODE_POSITION)
    assert rig.attempt('profile_velocity', 2000) == ErrorCode.DATA_RANGE
    rig.write(drive_mode=4)
    assert rig.attempt('profile_velocity', 32767) == 0
    assert rig.attempt('profile_velocity', 32768) == ErrorCode.DATA_RANGE


def test_the_reverse_bit_mirrors_the_positions() -> None:
    rig = Rig(MODE_POSITION, start_pulse=2048 + 500)
    assert rig.reg('present_position') == 2548
    rig.write(drive_mode=1)
    # The horn has not moved; the servo counts it the other way round the turn's middle.
    assert rig.dyn.physical_position_pulse == 2548
    assert rig.reg('present_position') == 2048 - 500
    rig.write(torque_enable=1, profile_velocity=100, profile_acceleration=20)
    rig.write(goal_position=2048 - 200)   # up by 300 in the servo's count
    rig.run(0.3)
    assert rig.reg('present_velocity') > 0   # counting up ...
    rig.run(3.0)
    assert rig.reg('present_position') == pytest.approx(2048 - 200, abs=3)
    # ... while the horn turned down, to the mirror of the goal.
    assert rig.dyn.physical_position_pulse == pytest.approx(2048 + 200, abs=3)
    # Back to normal (torque off: EEPROM): the same horn reads as it is.
    rig.write(torque_enable=0, drive_mode=0)
    assert rig.reg('present_position') == pytest.approx(2048 + 200, abs=3)
    assert rig.dyn.physical_position_pulse == pytest.approx(2048 + 200, abs=3)


def test_the_reverse_bit_turns_velocity_mode_too() -> None:
    rig = Rig(MODE_VELOCITY)
    rig.write(drive_mode=1, torque_enable=1, goal_velocity=50)
    before = rig.dyn.physical_position_pulse
    rig.run(0.5)
    assert rig.reg('present_velocity') == pytest.approx(50, abs=3)
    # The servo counts up while its horn turns down.
    assert rig.dyn.physical_position_pulse < before - 50
