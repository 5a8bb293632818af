"""Simulated servo physics against the XM430 manual's datasheet, controllers, thermal, errors."""

import math

from dxl_servo_driver.models import model_for, xm430
from dxl_servo_driver.protocol import ErrorCode
from dxl_servo_driver.sim import motor
import pytest
from sim_rig import Rig

# (volts, no-load rpm, stall torque N m, stall current A) from the XM430 manual's datasheet
DATASHEET = [(11.1, 43.0, 3.8, 2.1), (12.0, 46.0, 4.1, 2.3), (14.8, 57.0, 4.8, 2.7)]
TOLERANCE = 0.05
# The units of the manual's model (the Rig's servo).
MANUAL = model_for(xm430.MODEL_NUMBER)
AMPERE_PER_CURRENT_UNIT = MANUAL.current_unit_a
MOTOR = motor.MANUAL_MOTOR


def rpm(velocity_raw: int) -> float:
    return velocity_raw * MANUAL.velocity_unit_rpm


@pytest.mark.parametrize('volts, speed_rpm, torque_nm, current_a', DATASHEET)
def test_no_load_speed_matches_datasheet(volts: float, speed_rpm: float, torque_nm: float,
                                         current_a: float) -> None:
    rig = Rig(mode=16, volts=volts)
    rig.write(torque_enable=1, goal_pwm=885)
    rig.run(0.1)
    # A step reaches speed in tens of ms (mechanical time constant ~18 ms).
    assert rpm(rig.reg('present_velocity')) > 0.9 * speed_rpm
    rig.run(0.9)
    measured = rpm(rig.reg('present_velocity'))
    assert abs(measured / speed_rpm - 1.0) < TOLERANCE
    assert rig.reg('present_pwm') == 885
    assert rig.reg('present_input_voltage') == round(volts * 10)
    # The analytic steady state of the model agrees with the simulation.
    steady_rpm = motor.rad_s_to_rpm(MOTOR.no_load_speed_rad_s(volts))
    assert steady_rpm == pytest.approx(measured, abs=0.3)


@pytest.mark.parametrize('volts, speed_rpm, torque_nm, current_a', DATASHEET)
def test_stall_current_and_torque_match_datasheet(volts: float, speed_rpm: float,
                                                  torque_nm: float, current_a: float) -> None:
    rig = Rig(mode=16, volts=volts)
    rig.dyn.set_load(100.0)
    start = rig.reg('present_position')
    rig.write(torque_enable=1, goal_pwm=885)
    rig.run(0.2)
    assert rig.reg('present_position') == start
    measured_a = rig.reg('present_current') * AMPERE_PER_CURRENT_UNIT
    assert abs(measured_a / current_a - 1.0) < TOLERANCE
    delivered_nm = rig.dyn.motor_torque_nm - motor.COULOMB_FRICTION_NM
    assert abs(delivered_nm / torque_nm - 1.0) < TOLERANCE
    # The horn breaks free against a load 5 % below the datasheet torque, and holds 5 % above.
    for load_nm, moves in ((0.95 * torque_nm, True), (1.05 * torque_nm, False)):
        rig = Rig(mode=16, volts=volts)
        rig.dyn.set_load(load_nm)
        start = rig.reg('present_position')
        rig.write(torque_enable=1, goal_pwm=885)
        rig.run(0.3)
        assert (rig.reg('present_position') != start) is moves


def test_load_holds_horn_while_motor_torque_below_it() -> None:
    goal_current_raw = 300  # 0.807 A -> about 1.44 N m at the horn
    torque_nm = goal_current_raw * AMPERE_PER_CURRENT_UNIT * motor.TORQUE_CONSTANT_NM_A
    rig = Rig(mode=0)
    rig.dyn.set_load(torque_nm + 0.2)
    start = rig.reg('present_position')
    rig.write(torque_enable=1, goal_current=goal_current_raw)
    rig.run(1.0)
    assert rig.reg('present_position') == start
    assert rig.reg('present_velocity') == 0
    # Current mode holds the goal current against the load.
    assert abs(rig.reg('present_current') - goal_current_raw) <= 2
    rig.dyn.set_load(torque_nm - 0.3)
    rig.run(0.05)
    assert rig.reg('present_position') > start
    assert abs(rig.reg('present_current') - goal_current_raw) <= 3
    # Accelerating, it runs out of voltage: the PWM saturates and the current falls.
    rig.run(0.5)
    assert rig.reg('present_pwm') == 885
    assert rig.reg('present_current') < goal_current_raw


def test_current_mode_follows_negative_goal_without_load() -> None:
    rig = Rig(mode=0)
    rig.write(torque_enable=1, goal_current=-100)
    rig.run(0.02)
    assert rig.reg('present_velocity') < 0
    assert abs(rig.reg('present_current') + 100) <= 3
    # Unloaded, it speeds up until the supply runs out: PWM at the limit, current at friction.
    rig.run(0.5)
    assert rig.reg('present_pwm') == -885
    assert -100 < rig.reg('present_current') < 0


@pytest.mark.parametrize('goal_pwm', [442, -300, 0])
def test_pwm_mode_is_open_loop(goal_pwm: int) -> None:
    rig = Rig(mode=16)
    rig.write(torque_enable=1, goal_pwm=goal_pwm)
    rig.run(0.5)
    assert rig.reg('present_pwm') == goal_pwm
    # Steady state of the motor at that duty: the PWM scales the applied voltage.
    duty_v = abs(goal_pwm) / 885 * 12.0
    expected = math.copysign(motor.rad_s_to_rpm(MOTOR.no_load_speed_rad_s(duty_v)), goal_pwm)
    assert rpm(rig.reg('present_velocity')) == pytest.approx(expected, abs=0.3)


def test_current_based_position_limits_current_while_holding_against_load() -> None:
    rig = Rig(mode=5)
    rig.dyn.set_load(20.0)
    start = rig.reg('present_position')
    rig.write(torque_enable=1, goal_current=200)
    rig.write(goal_position=start + 2000)
    errors = rig.run(2.0)
    assert rig.reg('present_position') == start
    assert 195 <= rig.reg('present_current') <= 200
    assert errors & 0x20 == 0  # current limiting by Goal Current is not an overload
    # Free of the load it reaches the goal.
    rig.dyn.set_load(0.0)
    rig.run(3.0)
    assert abs(rig.reg('present_position') - (start + 2000)) <= 20
    assert rig.reg('moving_status') & 0x01


def test_overheat_trips_under_stall_after_long_advance() -> None:
    rig = Rig(mode=16)
    rig.dyn.set_load(100.0)
    # EEPROM, before torque on (which locks it). Shutdown on overheating only: with the
    # default (overload too) the servo would cut its torque after a second of stall.
    rig.write(temperature_limit=60, shutdown=0x04)
    rig.write(torque_enable=1, goal_pwm=885)
    assert rig.run(0.1) & 0x04 == 0
    errors = rig.dyn.advance(3600.0, rig.mem)  # cheap: the stalled state is jumped analytically
    assert errors & 0x04
    power_w = MOTOR.heat_power_w((12.0 / motor.RESISTANCE_OHM) ** 2, 12.0)
    expected_c = 25.0 + motor.THERMAL_RESISTANCE_C_W * power_w
    assert rig.dyn.temperature_c == pytest.approx(expected_c, abs=0.5)
    assert rig.reg('present_temperature') == round(rig.dyn.temperature_c)
    # Stall for one second does not heat it past the limit yet (minutes of thermal mass).
    cold = Rig(mode=16)
    cold.dyn.set_load(100.0)
    cold.write(temperature_limit=60, shutdown=0x04)
    cold.write(torque_enable=1, goal_pwm=885)
    assert cold.run(1.0) & 0x04 == 0
    assert cold.reg('present_temperature') < 27


def test_idle_temperature_settles_to_standby_heating() -> None:
    rig = Rig(mode=3)
    rig.dyn.advance(3600.0, rig.mem)
    assert rig.reg('present_temperature') == round(25.0 + 4.0 * 0.040 * 12.0)


def test_overload_after_one_second_of_saturated_stall() -> None:
    rig = Rig(mode=3)
    rig.dyn.set_load(10.0)
    start = rig.reg('present_position')
    rig.write(torque_enable=1)
    rig.write(goal_position=start + 1000)
    assert rig.run(0.9) & 0x20 == 0
    assert rig.run(0.3) & 0x20
    assert rig.reg('moving_status') & 0x08 == 0  # step profile: no following error
    # A long unloaded saturated move (step of 4000 pulses, ~1.3 s at full speed) is no overload.
    free = Rig(mode=4)
    free.write(torque_enable=1)
    free.write(goal_position=free.reg('present_position') + 4000)
    assert free.run(2.5) & 0x20 == 0
    assert free.reg('moving_status') & 0x01


def test_following_error_when_load_stops_a_profile() -> None:
    rig = Rig(mode=3)
    rig.dyn.set_load(10.0)
    start = rig.reg('present_position')
    rig.write(torque_enable=1, profile_velocity=100, profile_acceleration=50)
    rig.write(goal_position=start + 1500)
    rig.run(0.5)
    assert rig.reg('moving_status') & 0x08
    assert rig.reg('moving_status') & 0x01 == 0


@pytest.mark.parametrize('volts, expected', [(12.0, 0), (9.0, 0x01), (16.5, 0x01), (9.5, 0)])
def test_input_voltage_condition(volts: float, expected: int) -> None:
    rig = Rig(mode=3)
    rig.dyn.set_input_voltage(volts)
    assert rig.run(0.01) & 0x01 == expected
    assert rig.reg('present_input_voltage') == round(volts * 10)


def test_voltage_limits_come_from_registers() -> None:
    rig = Rig(mode=3)
    rig.write(min_voltage_limit=125)
    assert rig.run(0.01) & 0x01


def test_torque_off_coasts_to_a_stop() -> None:
    rig = Rig(mode=16)
    rig.write(torque_enable=1, goal_pwm=885)
    rig.run(0.5)
    rig.write(torque_enable=0)
    position = rig.reg('present_position')
    speeds = []
    for _ in range(30):
        rig.run(0.1)
        speeds.append(rig.reg('present_velocity'))
        assert rig.reg('present_pwm') == 0
        assert rig.reg('present_current') == 0
    assert speeds[0] > 0
    assert all(b <= a for a, b in zip(speeds, speeds[1:]))
    assert speeds[-1] == 0
    assert rig.reg('moving') == 0
    assert rig.reg('present_position') > position + 100  # it coasted on
    assert rig.dyn.current_a == 0.0


def test_reinit_within_one_turn_with_homing_offset() -> None:
    rig = Rig(mode=4, start_pulse=3 * 4096 + 100.3)
    assert rig.reg('present_position') == 100
    rig.write(homing_offset=500)
    rig.servo.clear_multi_turn()
    assert rig.reg('present_position') == 600
    rig.step()
    assert rig.reg('present_position') == 600
    rig = Rig(mode=4, start_pulse=-4096 - 50.0)
    assert rig.reg('present_position') == 4046
    # Extended position: the count continues across turns after the re-initialisation.
    rig.write(torque_enable=1)
    rig.write(goal_position=4046 + 5000)
    rig.run(2.5)
    assert abs(rig.reg('present_position') - 9046) <= 20
    assert rig.reg('position_trajectory') == 9046


def test_position_mode_keeps_goals_within_position_limits() -> None:
    rig = Rig(mode=3)
    rig.write(max_position_limit=3000, min_position_limit=1000)
    rig.write(torque_enable=1, profile_velocity=200, profile_acceleration=100)
    # A goal beyond the limits is refused (Data Limit Error): the servo keeps the goal it had.
    held = rig.reg('goal_position')
    assert rig.attempt('goal_position', 4000) == ErrorCode.DATA_LIMIT
    assert rig.reg('goal_position') == held
    rig.write(goal_position=3000)
    high = 0
    for _ in range(150):
        rig.run(0.01)
        high = max(high, rig.reg('position_trajectory'), rig.reg('present_position'))
    assert rig.reg('position_trajectory') == 3000
    assert abs(rig.reg('present_position') - 3000) <= 20
    assert high <= 3005
    assert rig.attempt('goal_position', -500) == ErrorCode.DATA_LIMIT
    assert rig.reg('goal_position') == 3000
    rig.write(goal_position=1000)
    rig.run(1.5)
    assert rig.reg('position_trajectory') == 1000
    assert abs(rig.reg('present_position') - 1000) <= 20


def test_moving_follows_moving_threshold() -> None:
    rig = Rig(mode=1)
    rig.write(moving_threshold=20)  # EEPROM: before torque on, which locks it
    rig.write(torque_enable=1, goal_velocity=15)
    rig.run(0.5)
    assert rig.reg('present_velocity') == 15
    assert rig.reg('moving') == 0
    rig.write(goal_velocity=-25)
    rig.run(0.5)
    assert rig.reg('present_velocity') == -25
    assert rig.reg('moving') == 1


def test_sub_period_calls_accumulate() -> None:
    fine = Rig(mode=16)
    coarse = Rig(mode=16)
    fine.write(torque_enable=1, goal_pwm=600)
    coarse.write(torque_enable=1, goal_pwm=600)
    fine.run(0.05, dt_s=0.00025)
    coarse.run(0.05, dt_s=0.01)
    assert fine.dyn.horn_position_pulse == pytest.approx(coarse.dyn.horn_position_pulse, abs=1e-6)


def test_bad_inputs_do_not_crash() -> None:
    rig = Rig(mode=16)
    rig.write(torque_enable=1, goal_pwm=885)
    rig.dyn.set_load(float('nan'))
    rig.dyn.set_input_voltage(float('inf'))
    for dt_s in (float('nan'), -1.0, float('inf'), 0.0):
        rig.dyn.advance(dt_s, rig.mem)
    rig.dyn.set_input_voltage(0.0)
    assert rig.dyn.advance(0.1, rig.mem) & 0x01
    assert rig.reg('present_input_voltage') == 0
    rig.dyn.set_load(-3.0)
    assert rig.dyn.load_nm == 3.0
