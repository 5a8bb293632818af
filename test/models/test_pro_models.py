"""
The DYNAMIXEL PRO on its original firmware and the first RH-P12-RN: oracles and meanings.

The generic checks (items disjoint and in range, modes, units, physics) run over these models in
test_model_families.py. Here: addresses and sizes item by item against dynamixel-workbench's
dynamixel_item.cpp (items_EXTPRO and its per-model position and velocity info), initial values
against the ROBOTIS e-manual pages, hard-coded as oracles independent of the module, and what
roles, units and modes must mean. The L42-10-S300-R, whose sources disagree, is checked against
each of them where they agree: workbench's items_PRO and info_PRO, the ROBOTIS-Framework device
file, its page (current and older revision) and the PRO data file.
"""

import math

from dxl_servo_driver.models import ALL_MODELS, Model, model_for, model_named, modes, SUPPORTED
from dxl_servo_driver.models.names import OTHER_MODELS
from dxl_servo_driver.models.units import units_for
import pytest

L42 = model_for(35072)
# The ten on the shared layout (the L42 has its own checks below).
PRO = tuple(model for model in ALL_MODELS if model.family == 'PRO' and model is not L42)
GRIPPER = model_for(35073)

# dynamixel-workbench items_EXTPRO: our name -> (address, size). Its rows 626..632 are named
# External_Port_Mode_1..4 (2 bytes): the e-manual's External Port Data 1..4.
WB_EXTPRO = {
    'model_number': (0, 2), 'firmware_version': (6, 1), 'id': (7, 1), 'baud_rate': (8, 1),
    'return_delay_time': (9, 1), 'operating_mode': (11, 1), 'homing_offset': (13, 4),
    'moving_threshold': (17, 4), 'temperature_limit': (21, 1), 'max_voltage_limit': (22, 2),
    'min_voltage_limit': (24, 2), 'acceleration_limit': (26, 4), 'torque_limit': (30, 2),
    'velocity_limit': (32, 4), 'max_position_limit': (36, 4), 'min_position_limit': (40, 4),
    'external_port_mode_1': (44, 1), 'external_port_mode_2': (45, 1),
    'external_port_mode_3': (46, 1), 'external_port_mode_4': (47, 1), 'shutdown': (48, 1),
    'torque_enable': (562, 1), 'led_red': (563, 1), 'led_green': (564, 1),
    'led_blue': (565, 1), 'velocity_i_gain': (586, 2), 'velocity_p_gain': (588, 2),
    'position_p_gain': (594, 2), 'goal_position': (596, 4), 'goal_velocity': (600, 4),
    'goal_torque': (604, 2), 'goal_acceleration': (606, 4), 'moving': (610, 1),
    'present_position': (611, 4), 'present_velocity': (615, 4), 'present_current': (621, 2),
    'present_input_voltage': (623, 2), 'present_temperature': (625, 1),
    'external_port_data_1': (626, 2), 'external_port_data_2': (628, 2),
    'external_port_data_3': (630, 2), 'external_port_data_4': (632, 2),
    'registered_instruction': (890, 1), 'status_return_level': (891, 1),
    'hardware_error_status': (892, 1),
}
# Items the e-manual has and the workbench leaves out.
BEYOND_WORKBENCH = {'model_information'}
# workbench info_EXTPRO: number -> (velocity rpm per count, position at +pi).
WB_INFO = {
    37928: (0.00249657, 144_197), 37896: (0.00199234, 180_692), 38152: (0.00199234, 180_692),
    38176: (0.00346667, 103_846), 43288: (0.00389076, 131_593), 46096: (0.00397746, 125_708),
    46352: (0.00397746, 125_708), 51200: (0.00329218, 151_875), 53768: (0.00199234, 250_961),
    54024: (0.00199234, 250_961),
}
# e-manual pages: number -> (name, Torque Limit initial and maximum, Velocity Limit, Velocity I
# and P Gain, Position P Gain, resolution, mA per current count). The L54-30-S500-R's page
# was not found with these values (the module assumes them from its siblings): left out.
EMANUAL = {
    54024: ('H54-200-S500-R', 620, 1860, 17_000, 14, 399, 32, 501_923, 16.11328),
    53768: ('H54-100-S500-R', 310, 930, 17_000, 16, 256, 32, 501_923, 16.11328),
    51200: ('H42-20-S300-R', 465, 1395, 10_300, 40, 440, 32, 303_750, 4.02832),
    46352: ('M54-60-S250-R', 180, 540, 8000, 16, 256, 32, 251_417, 16.11328),
    46096: ('M54-40-S250-R', 120, 360, 8000, 16, 256, 32, 251_417, 16.11328),
    43288: ('M42-10-S260-R', 300, 900, 8000, 72, 520, 32, 263_187, 4.02832),
    38152: ('L54-50-S500-R', 120, 360, 8000, 16, 256, 32, 361_384, 16.11328),
    38176: ('L54-50-S290-R', 120, 360, 8000, 16, 412, 250, 207_692, 16.11328),
    37928: ('L54-30-S400-R', 100, 300, 9000, 16, 412, 200, 288_395, 16.11328),
}
# _data/dxl_pro_info.yml: number -> (gear ratio, continuous N.m, continuous A, no-load rpm).
DATASHEET = {
    54024: (501.923, 44.7, 9.3, 33.1), 53768: (501.923, 25.3, 5.5, 33.3),
    51200: (303.75, 5.1, 1.5, 32.7), 46352: (251.4, 10.1, 3.0, 33.1),
    46096: (251.4, 3.9, 1.9, 28.4), 43288: (257.0, 1.7, 0.6, 28.0),
    38152: (501.923, 14.0, 1.9, 16.0), 38176: (288.5, 4.8, 1.9, 26.0),
    37896: (501.923, 5.4, 1.6, 23.0), 37928: (400.5, 2.5, 1.6, 28.7),
}
# e-manual RH-P12-RN page: name -> (address, size, initial).
GRIPPER_EMANUAL = {
    'model_number': (0, 2, 35073), 'id': (7, 1, 1), 'baud_rate': (8, 1, 1),
    'return_delay_time': (9, 1, 250), 'operating_mode': (11, 1, 5),
    'moving_threshold': (17, 4, 10), 'temperature_limit': (21, 1, 80),
    'max_voltage_limit': (22, 2, 400), 'min_voltage_limit': (24, 2, 150),
    'acceleration_limit': (26, 4, 255), 'current_limit': (30, 2, 820),
    'velocity_limit': (32, 4, 100), 'max_position_limit': (36, 4, 1150),
    'min_position_limit': (40, 4, 0), 'shutdown': (48, 1, 48), 'indirect_address_1': (49, 2, 634),
    'indirect_address_256': (559, 2, 889), 'torque_enable': (562, 1, 0),
    'position_d_gain': (590, 2, 0), 'position_i_gain': (592, 2, 0),
    'goal_velocity': (600, 4, 0), 'goal_current': (604, 2, 0), 'goal_acceleration': (606, 4, 0),
    'present_current': (621, 2, 0), 'external_port_data_4': (632, 2, 0),
    'indirect_data_256': (889, 1, 0), 'hardware_error_status': (892, 1, 0),
}


def _label(model: Model) -> str:
    return f'{model.number}-{model.name}'


every_pro = pytest.mark.parametrize('model', PRO, ids=_label)


def test_the_eleven_and_the_gripper_are_supported() -> None:
    assert {model.number for model in PRO} == set(WB_INFO)
    assert all(len(SUPPORTED[number]) == 1 for number in (*WB_INFO, 35072, 35073))
    assert not {35072, 35073, *WB_INFO} & set(OTHER_MODELS)
    assert model_named('l42-10-s300-r') is L42 and L42.family == 'PRO'
    assert model_named('h54-200-s500-r') is model_for(54024)
    assert model_named('H54-200-S500-R(A)') is model_for(54025)
    assert model_named('RH-P12-RN') is GRIPPER and model_named('RH-P12-RN(A)').number == 35074


@every_pro
def test_addresses_and_sizes_against_the_workbench(model: Model) -> None:
    ours = {item.name: (item.address, item.size) for item in model.items
            if not item.name.startswith('indirect_')}
    assert set(ours) == set(WB_EXTPRO) | BEYOND_WORKBENCH
    for name, place in WB_EXTPRO.items():
        assert ours[name] == place, name


@every_pro
def test_units_against_the_workbench_info_and_the_emanual(model: Model) -> None:
    rpm, at_pi = WB_INFO[model.number]
    assert model.velocity_unit_rpm == rpm and model.position_zero_raw == 0
    # The workbench maps +-pi to +-(resolution / 2): within a pulse of the resolution.
    assert abs(model.pulses_per_rev - 2 * at_pi) <= 1
    assert model.item('max_position_limit').initial == at_pi
    assert model.item('min_position_limit').initial == -at_pi
    gear = DATASHEET[model.number][0]
    # One velocity count is 1 rpm of the motor: the output unit is one over the gear ratio.
    assert rpm * gear == pytest.approx(1.0, rel=2e-3)
    assert model.acceleration_unit_rpm2 == pytest.approx(58_000 * rpm)
    # e-manual formula: 33,000 / 2,048 mA on the 54 frames, 8,250 / 2,048 on the 42 ones.
    frame = 42 if model.name[1:3] == '42' else 54
    per_count = (33_000 if frame == 54 else 8_250) / 2048 / 1000
    assert model.current_unit_a == pytest.approx(per_count)


@every_pro
def test_initial_values_against_the_emanual(model: Model) -> None:
    common = {'id': 1, 'baud_rate': 1, 'return_delay_time': 250, 'operating_mode': 3,
              'homing_offset': 0, 'moving_threshold': 50, 'temperature_limit': 80,
              'max_voltage_limit': 400, 'min_voltage_limit': 150, 'shutdown': 58,
              'indirect_address_1': 634, 'indirect_address_256': 889, 'torque_enable': 0,
              'goal_velocity': 0, 'goal_torque': 0, 'goal_acceleration': 0,
              'status_return_level': 2, 'model_number': model.number}
    for name, initial in common.items():
        assert model.item(name).initial == initial, name
    assert model.item('indirect_address_256').address == 559
    assert model.item('indirect_data_256').address == 889
    if model.number not in EMANUAL:
        return
    name, torque, torque_max, velocity, v_i, v_p, p_p, resolution, milliamps = \
        EMANUAL[model.number]
    assert model.name == name and model.pulses_per_rev == resolution
    limit = model.item('torque_limit')
    assert (limit.initial, limit.maximum) == (torque, torque_max)
    assert model.item('goal_torque').maximum == torque_max
    assert model.item('velocity_limit').initial == velocity
    gains = (model.item(each).initial for each in
             ('velocity_i_gain', 'velocity_p_gain', 'position_p_gain'))
    assert tuple(gains) == (v_i, v_p, p_p)
    assert model.current_unit_a == pytest.approx(milliamps / 1000, rel=1e-6)


@every_pro
def test_roles_modes_and_features(model: Model) -> None:
    assert model.roles == {'goal_current': 'goal_torque', 'current_limit': 'torque_limit'}
    for role, own in model.roles.items():
        assert not any(item.name == role for item in model.items)
        assert model.item(role).name == own
    # Goal Torque is the motor current, bounded by Torque Limit in the same unit.
    goal, limit = model.item('goal_current'), model.item('current_limit')
    assert goal.limit == limit.name and goal.unit == limit.unit
    assert goal.unit == model.item('present_current').unit and goal.signed
    assert model.modes == {'current': 0, 'velocity': 1, 'position': 3, 'extended_position': 4}
    assert set(model.modes) <= set(modes.NAMES)
    assert model.mode_register == 'operating_mode' and model.item('operating_mode').maximum == 4
    for absent in ('realtime_tick', 'present_pwm', 'goal_pwm', 'profile_velocity',
                   'profile_acceleration', 'moving_status', 'drive_mode', 'bus_watchdog'):
        assert not model.has(absent), absent
    assert model.eeprom_end == 562 and model.item('torque_enable').address == 562
    assert model.item('shutdown').area == 'eeprom' and model.item('led_red').area == 'ram'
    assert len(model.indirect) == 256 and model.indirect[0] == (49, 634)
    assert model.indirect[-1] == (559, 889)
    assert model.item('indirect_address_1').minimum == 562
    assert model.item('indirect_address_1').maximum == 892
    assert model.fast_sync_read_firmware is None and model.reboot and model.bulk_read
    assert model.bauds[8] == 10_500_000 and max(model.bauds) == 8
    assert model.hardware_error_bits == {
        0x01: 'input_voltage', 0x02: 'motor_hall_sensor', 0x04: 'overheating',
        0x08: 'motor_encoder', 0x10: 'electrical_shock', 0x20: 'overload'}
    # Shutdown's default 58 is bits 1, 3, 4, 5: every one a named error.
    assert all(model.hardware_error_bits.get(bit) for bit in (0x02, 0x08, 0x10, 0x20))


@every_pro
def test_physics_is_the_datasheet(model: Model) -> None:
    gear, torque, current, speed = DATASHEET[model.number]
    nominal = model.physics.nominal
    assert nominal.voltage_v == 24.0 and nominal.stall_torque_nm == torque
    assert nominal.stall_current_a == current and nominal.no_load_speed_rpm == speed
    assert model.physics.gear_ratio == pytest.approx(gear, rel=1e-3)
    assert 'continuous' in model.physics.source
    # The Velocity Limit at power-on is within the no-load speed's reach.
    limit_rpm = model.item('velocity_limit').initial * model.velocity_unit_rpm
    assert 0.5 * speed < limit_rpm < 1.2 * speed
    units = units_for(model)
    assert units.effort_register == 'present_current'
    assert math.isclose(units.current_to_a(100), 100 * model.current_unit_a)


def test_the_gripper_against_its_page() -> None:
    for name, (address, size, initial) in GRIPPER_EMANUAL.items():
        item = GRIPPER.item(name)
        assert (item.address, item.size, item.initial) == (address, size, initial), name
    assert GRIPPER.modes == {'current': 0, 'current_based_position': 5}
    assert GRIPPER.roles == {} and not GRIPPER.has('homing_offset')
    assert not GRIPPER.has('velocity_p_gain') and GRIPPER.has('position_p_gain')
    assert GRIPPER.item('goal_current').limit == 'current_limit'
    assert GRIPPER.current_unit_a == pytest.approx(4.02e-3)
    assert GRIPPER.velocity_unit_rpm == 0.114 and GRIPPER.acceleration_unit_rpm2 == 214.577
    assert GRIPPER.item('goal_position').maximum == 1150 == GRIPPER.extended_position_limit
    assert 0x02 not in GRIPPER.hardware_error_bits
    # Current Limit's 820 counts are the 3.33 A peak current.
    assert 820 * GRIPPER.current_unit_a == pytest.approx(3.33, rel=0.02)
    assert GRIPPER.physics.gear_ratio == 1181.0
    assert GRIPPER.physics.nominal == model_for(35074).physics.nominal


# --- L42-10-S300-R (35072) ---------------------------------------------------------------------

# dynamixel-workbench items_PRO (the L42's own list): items_EXTPRO without Homing Offset, row by
# row the same addresses and sizes otherwise.
WB_PRO = {name: place for name, place in WB_EXTPRO.items() if name != 'homing_offset'}
# Rows the sources disagree on, left out of the model: the current page's Velocity I/P Gain
# (workbench lists them; the older page and the description have Position D/I Gain instead).
L42_CONTESTED = {'velocity_i_gain', 'velocity_p_gain'}
# workbench info_PRO: rpm per count, raw at -pi, at 0 rad, at +pi.
WB_INFO_PRO = (0.114, -2048, 0, 2048)
# ROBOTIS-Framework L42-10-S300-R.device [type info]: addresses and the radian mapping.
FRAMEWORK_L42 = {
    'torque_enable': 562, 'position_p_gain': 594, 'goal_position': 596, 'goal_velocity': 600,
    'goal_torque': 604, 'moving': 610, 'present_position': 611, 'present_velocity': 615,
    'present_current': 621,
}
FRAMEWORK_RADIAN = (-2047, 0, 2048)
# Its e-manual page (current revision): initial values.
L42_EMANUAL = {
    'model_number': 35072, 'id': 1, 'baud_rate': 1, 'return_delay_time': 250,
    'operating_mode': 3, 'moving_threshold': 10, 'temperature_limit': 80,
    'max_voltage_limit': 400, 'min_voltage_limit': 150, 'torque_limit': 987,
    'max_position_limit': 2048, 'min_position_limit': -2047, 'indirect_address_1': 634,
    'indirect_address_256': 889, 'torque_enable': 0, 'position_p_gain': 64,
    'goal_velocity': 0, 'goal_torque': 0, 'goal_acceleration': 0, 'registered_instruction': 0,
    'status_return_level': 2, 'hardware_error_status': 0,
}
# The older revision's Shutdown (0x30), the bits the description marks as defaults.
L42_SHUTDOWN = 48
# _data/dxl_pro_info.yml: gear ratio, resolution, continuous N.m and A, no-load rpm.
L42_DATASHEET = (303.75, 4096, 1.2, 0.8, 29.7)


def test_the_l42_addresses_against_workbench_and_the_framework() -> None:
    ours = {item.name: (item.address, item.size) for item in L42.items
            if not item.name.startswith('indirect_')}
    assert set(ours) == (set(WB_PRO) - L42_CONTESTED) | BEYOND_WORKBENCH
    for name, place in WB_PRO.items():
        if name not in L42_CONTESTED:
            assert ours[name] == place, name
    for name, address in FRAMEWORK_L42.items():
        assert L42.item(name).address == address, name
    for absent in ('homing_offset', 'position_d_gain', 'position_i_gain', *L42_CONTESTED):
        assert not L42.has(absent), absent
    assert len(L42.indirect) == 256 and L42.indirect[-1] == (559, 889)


def test_the_l42_initial_values_against_its_page() -> None:
    for name, initial in L42_EMANUAL.items():
        assert L42.item(name).initial == initial, name
    assert L42.item('shutdown').initial == L42_SHUTDOWN
    # Shutdown's defaults are named errors (overload, electrical shock).
    assert [L42.hardware_error_bits[bit] for bit in (0x10, 0x20)] == [
        'electrical_shock', 'overload']
    # Torque Limit's range is 0..987 and Goal Torque is within +-Torque Limit (its table).
    assert L42.item('torque_limit').maximum == 987
    goal = L42.item('goal_torque')
    expected = (-987, 987, 'torque_limit', True)
    assert (goal.minimum, goal.maximum, goal.limit, goal.signed) == expected


def test_the_l42_units_modes_and_roles() -> None:
    rpm, at_minus_pi, at_zero, at_pi = WB_INFO_PRO
    assert L42.velocity_unit_rpm == rpm and L42.position_zero_raw == at_zero
    assert L42.pulses_per_rev == at_pi - at_minus_pi == L42_DATASHEET[1]
    low, zero, high = FRAMEWORK_RADIAN
    assert zero == L42.position_zero_raw and abs(L42.pulses_per_rev - (high - low)) <= 1
    # Its page's formula for Present Current and Goal Torque.
    assert L42.current_unit_a == pytest.approx(8.25 / 2048)
    assert 987 * L42.current_unit_a == pytest.approx(3.976, abs=1e-3)
    assert L42.acceleration_unit_rpm2 == pytest.approx(214 / 303.75)
    assert L42.modes == {'velocity': 1, 'position': 3}
    mode = L42.item('operating_mode')
    assert (mode.minimum, mode.maximum) == (1, 3)
    assert L42.roles == {'goal_current': 'goal_torque', 'current_limit': 'torque_limit'}
    assert L42.item('goal_current').name == 'goal_torque'
    assert L42.eeprom_end == 562 and L42.homing_position_mode_limit is None
    assert units_for(L42).effort_register == 'present_current'


def test_the_l42_physics_is_its_datasheet() -> None:
    gear, _, torque, current, speed = L42_DATASHEET
    nominal = L42.physics.nominal
    assert (nominal.voltage_v, nominal.stall_torque_nm, nominal.stall_current_a,
            nominal.no_load_speed_rpm) == (24.0, torque, current, speed)
    assert L42.physics.gear_ratio == gear and 'continuous' in L42.physics.source
    assert 'assumed' in L42.physics.source
    # The no-load speed fits the page's +-1,023 velocity range (260 counts); the assumed
    # Velocity Limit is that range's top.
    assert speed / L42.velocity_unit_rpm < 1023 == L42.item('velocity_limit').initial
