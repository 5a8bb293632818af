"""
The DYNAMIXEL-Y tables against the e-manual, as an oracle independent of models/y.py.

test_model_families.py checks every Y table against its dynamixel-sdk model file (addresses
and sizes) with the other families; here the figures are typed again from the ROBOTIS e-manual
YM070-210-*/YM080-230-* control tables and _data/dxl_y_info.yml, item by item.
"""

import importlib.util
import math
import pathlib

from dxl_servo_driver.models import ALL_MODELS, Model, model_for, model_named, modes
from dxl_servo_driver.models.units import units_for
import pytest

Y_NUMBERS = (4000, 4010, 4020, 4030, 4040, 4050, 4120, 4130, 4140, 4150, 4160, 4170)
Y_MODELS = tuple(model for model in ALL_MODELS if model.family == 'Y')

# The e-manual YM070-210-R051 control table: name -> (address, size, area, access, initial,
# minimum, maximum), Hybrid written as 'ram' (writable with torque on).
R051_ROWS: dict[str, tuple[int, int, str, str, int, int, int]] = {
    'model_number': (0, 2, 'eeprom', 'R', 4020, 0, 0xFFFF),
    'bus_watchdog': (8, 2, 'ram', 'RW', 0, 0, 127),
    'baud_rate_bus': (12, 1, 'eeprom', 'RW', 1, 0, 9),
    'return_delay_time': (13, 1, 'eeprom', 'RW', 250, 0, 254),
    'status_return_level': (15, 1, 'ram', 'RW', 2, 0, 2),
    'operating_mode': (33, 1, 'eeprom', 'RW', 3, 0, 3),
    'in_position_threshold': (40, 4, 'eeprom', 'RW', 19, 0, 2_147_483_647),
    'motor_temperature_limit': (57, 1, 'eeprom', 'RW', 60, 0, 100),
    'max_voltage_limit': (60, 2, 'eeprom', 'RW', 320, 240, 400),
    'pwm_limit': (64, 2, 'eeprom', 'RW', 1000, 0, 1000),
    'current_limit': (66, 2, 'eeprom', 'RW', 2080, 0, 2080),
    'acceleration_limit': (68, 4, 'eeprom', 'RW', 313, 0, 755_294),
    'velocity_limit': (72, 4, 'eeprom', 'RW', 3921, 0, 12_592),
    'max_position_limit': (76, 4, 'eeprom', 'RW', 262_144, -2_147_483_648, 2_147_483_647),
    'electronic_gearratio_numerator': (96, 4, 'eeprom', 'RW', 51, 1, 1_045_576),
    'hybrid_save': (170, 1, 'ram', 'RW', 0, 0, 2),
    'velocity_i_gain': (212, 4, 'ram', 'RW', 2_446_559, 0, 2_147_483_647),
    'position_p_gain': (232, 4, 'ram', 'RW', 6_283_185, 0, 2_147_483_647),
    'profile_velocity': (244, 4, 'ram', 'RW', 3921, 0, 12_592),
    'profile_time': (252, 4, 'ram', 'RW', 800, 0, 524_288),
    'indirect_address_1': (256, 2, 'eeprom', 'RW', 634, 0, 919),
    'indirect_address_128': (510, 2, 'eeprom', 'RW', 761, 0, 919),
    'torque_enable': (512, 1, 'ram', 'RW', 0, 0, 1),
    'goal_current': (526, 2, 'ram', 'RW', 0, -2080, 2080),
    'indirect_data_128': (761, 1, 'ram', 'RW', 0, 0, 255),
}
# Registers read only, with their unit: (address, size, unit).
R051_READ_ONLY: dict[str, tuple[int, int, str]] = {
    'controller_state': (152, 1, ''), 'error_code': (153, 1, ''),
    'error_code_history_16': (169, 1, ''), 'moving_status': (541, 1, ''),
    'realtime_tick': (542, 2, 'ms'), 'present_current': (546, 2, '0.01 A'),
    'present_velocity': (548, 4, '0.01 rpm'), 'present_position': (552, 4, 'pulse'),
    'present_input_voltage': (568, 2, '0.01 V'), 'present_motor_temperature': (571, 1, 'degC'),
    'backup_ready': (919, 1, ''),
}
# Per page: number -> (name, Electronic Gear Ratio Numerator, Acceleration Limit initial and
# maximum, Velocity Limit initial and maximum, In-Position Threshold, Motor Temperature Limit,
# Brake Delay).
PAGES: dict[int, tuple[str, int, int, int, int, int, int, int, int]] = {
    4000: ('YM070-210-M001', 1, 44_000, 38_520_000, 550_000, 642_200, 1000, 80, 0),
    4010: ('YM070-210-B001', 1, 44_000, 38_520_000, 550_000, 642_200, 1000, 80, 20),
    4020: ('YM070-210-R051', 51, 313, 755_294, 3921, 12_592, 19, 60, 0),
    4030: ('YM070-210-R099', 99, 161, 389_090, 2020, 6486, 10, 60, 0),
    4040: ('YM070-210-A051', 51, 313, 755_294, 3921, 12_592, 19, 60, 20),
    4050: ('YM070-210-A099', 99, 161, 389_090, 2020, 6486, 10, 60, 20),
    4120: ('YM080-230-M001', 1, 24_800, 21_336_000, 310_000, 355_600, 1000, 80, 0),
    4130: ('YM080-230-B001', 1, 24_800, 21_336_000, 310_000, 355_600, 1000, 80, 20),
    4140: ('YM080-230-R051', 51, 313, 418_352, 3921, 6972, 19, 60, 0),
    4150: ('YM080-230-R099', 99, 161, 215_515, 2020, 3591, 10, 60, 0),
    4160: ('YM080-230-A051', 51, 313, 418_352, 3921, 6972, 19, 60, 20),
    4170: ('YM080-230-A099', 99, 161, 215_515, 2020, 3591, 10, 60, 20),
}
# _data/dxl_y_info.yml: number -> (gear ratio, maximum torque N.m, maximum current A,
# no-load speed rpm), all at 24 V.
DATASHEET: dict[int, tuple[float, float, float, float]] = {
    4000: (1, 0.64, 20.8, 5675), 4010: (1, 0.64, 20.8, 5675),
    4020: (51, 16.3, 20.8, 111.3), 4030: (99, 31.7, 20.8, 57.3),
    4040: (51, 16.3, 20.8, 111.3), 4050: (99, 31.7, 20.8, 57.3),
    4120: (1, 1.24, 22.4, 3190), 4130: (1, 1.24, 22.4, 3190),
    4140: (51, 31.6, 22.4, 62.5), 4150: (99, 61.4, 22.4, 32.2),
    4160: (51, 31.6, 22.4, 62.5), 4170: (99, 61.4, 22.4, 32.2),
}
every_y = pytest.mark.parametrize('model', Y_MODELS, ids=lambda model: model.name)


def _direct_drive(number: int) -> int:
    """Return the number of the -M001 of a model's frame (YM070 4000, YM080 4120)."""
    return 4000 if number < 4120 else 4120


def test_the_twelve_are_supported() -> None:
    assert tuple(model.number for model in Y_MODELS) == Y_NUMBERS
    for number, page in PAGES.items():
        assert model_for(number).name == page[0]
        assert model_named(page[0].lower() + '-rh') is model_for(number)


def test_the_r051_table_reads_as_the_e_manual() -> None:
    model = model_for(4020)
    for name, row in R051_ROWS.items():
        item = model.item(name)
        assert (item.address, item.size, item.area, item.access, item.initial, item.minimum,
                item.maximum) == row, name
    for name, (address, size, unit) in R051_READ_ONLY.items():
        item = model.item(name)
        assert (item.address, item.size, item.area, item.access, item.unit) == \
            (address, size, 'ram', 'R', unit), name


@every_y
def test_each_page_has_its_figures(model: Model) -> None:
    (name, gear, acceleration, acceleration_max, velocity, velocity_max, threshold,
     motor_limit, brake_delay) = PAGES[model.number]
    assert model.name == name and model.item('model_number').initial == model.number
    assert model.item('electronic_gearratio_numerator').initial == gear
    assert model.item('electronic_gearratio_denominator').initial == 1
    for register in ('acceleration_limit', 'profile_acceleration'):
        item = model.item(register)
        assert (item.initial, item.maximum) == (acceleration, acceleration_max), register
    for register in ('velocity_limit', 'profile_velocity'):
        item = model.item(register)
        assert (item.initial, item.maximum) == (velocity, velocity_max), register
    assert model.item('goal_velocity').maximum == velocity_max
    assert model.item('in_position_threshold').initial == threshold
    assert model.item('moving_threshold').initial == threshold
    assert model.item('motor_temperature_limit').initial == motor_limit
    assert model.item('inverter_temperature_limit').initial == 80
    assert model.item('brake_delay').initial == brake_delay
    assert model.item('goal_update_delay').initial == (200 if brake_delay else 0)
    # A geared page's maxima are the direct-drive page's divided by its gear.
    direct = PAGES[_direct_drive(model.number)]
    assert acceleration_max == direct[3] // gear and velocity_max == direct[5] // gear


@every_y
def test_areas_per_item(model: Model) -> None:
    area = {item.name: item.area for item in model.items}
    # Below 512 the e-manual mixes areas; Hybrid (gains, profiles) is written with torque on.
    for name in ('bus_watchdog', 'status_return_level', 'registered_instruction',
                 'controller_state', 'error_code', 'hybrid_save', 'velocity_p_gain',
                 'position_d_gain', 'profile_acceleration', 'profile_time'):
        assert area[name] == 'ram', name
    for name in ('id', 'baud_rate_bus', 'drive_mode', 'operating_mode', 'homing_offset',
                 'current_limit', 'max_position_limit', 'brake_delay',
                 'velocity_ff_lpf_time', 'indirect_address_64'):
        assert area[name] == 'eeprom', name
    assert all(item.area == 'ram' for item in model.items if item.address >= 512)
    assert model.eeprom_end == 512


@every_y
def test_roles_point_at_items_of_the_same_meaning(model: Model) -> None:
    assert model.roles == {
        'baud_rate': 'baud_rate_bus', 'protocol_version': 'protocol_type',
        'secondary_id': 'secondary_shadow_id',
        'present_temperature': 'present_motor_temperature',
        'temperature_limit': 'motor_temperature_limit'}
    for role, name in model.roles.items():
        assert model.item(role) is model.item(name) and not any(
            item.name == role for item in model.items)
    # The X's names found directly on the Y.
    for name in ('drive_mode', 'homing_offset', 'velocity_limit', 'acceleration_limit',
                 'pwm_limit', 'current_limit', 'profile_velocity', 'profile_acceleration',
                 'goal_pwm', 'goal_current', 'goal_velocity', 'goal_position', 'present_pwm',
                 'present_current', 'present_velocity', 'present_position',
                 'velocity_trajectory', 'position_trajectory', 'bus_watchdog',
                 'status_return_level', 'return_delay_time', 'velocity_p_gain',
                 'velocity_i_gain', 'position_p_gain', 'position_i_gain', 'position_d_gain',
                 'startup_configuration', 'led', 'realtime_tick', 'moving_threshold'):
        assert model.has(name), name
    # What the Y does not have, under any name: an error code instead of error bits, Moving
    # Status instead of Moving, its own FF gains instead of the X's feedforward pair.
    for name in ('hardware_error_status', 'shutdown', 'moving', 'feedforward_1st_gain',
                 'feedforward_2nd_gain', 'present_load'):
        assert not model.has(name), name
    assert model.hardware_error_bits == {}
    assert model.has('error_code') and model.has('controller_state')


@every_y
def test_modes_and_units(model: Model) -> None:
    assert model.modes == {'current': 0, 'velocity': 1, 'position': 3}
    assert set(model.modes) <= set(modes.NAMES) and model.mode_register == 'operating_mode'
    assert model.protocol == 2.0 and model.fast_sync_read_firmware is None
    assert model.pulses_per_rev == 524_288 and model.position_zero_raw == 0
    assert model.velocity_unit_rpm == 0.01 and model.current_unit_a == 0.01
    assert model.load_unit_ratio is None and model.pwm_full_raw == 1000
    assert model.item('pwm_limit').maximum == model.pwm_full_raw
    assert model.voltage_unit_v == 0.01 and model.voltage_limit_unit_v == 0.1
    assert model.acceleration_unit_rpm2 == 10.0
    assert model.extended_position_limit == 2**31 - 1
    assert model.homing_position_mode_limit is None
    assert model.bauds[1] == 57_600 and model.bauds[9] == 10_500_000 and len(model.bauds) == 10
    assert model.indirect[0] == (256, 634) and model.indirect[-1] == (510, 761)
    assert len(model.indirect) == 128
    units = units_for(model)
    assert units.position_to_rad(262_144) == pytest.approx(math.pi)
    assert units.velocity_to_rad_s(100) == pytest.approx(2 * math.pi / 60)
    assert units.current_to_a(2080) == pytest.approx(20.8)
    assert units.voltage_to_v(2400) == pytest.approx(24.0)


@every_y
def test_physics_is_the_datasheet(model: Model) -> None:
    gear, torque, current, speed = DATASHEET[model.number]
    physics = model.physics
    assert physics.gear_ratio == gear and physics.nominal_voltage_v == 24.0
    assert len(physics.points) == 1
    point = physics.nominal
    assert (point.stall_torque_nm, point.stall_current_a, point.no_load_speed_rpm) == \
        (torque, current, speed)
    assert model.torque_constant_nm_per_a == pytest.approx(torque / current)
    # A geared model turns its motor's no-load speed over its gear, within the datasheet's
    # rounding.
    motor = DATASHEET[_direct_drive(model.number)]
    assert speed == pytest.approx(motor[3] / gear, rel=0.01)


def test_the_sdk_files_of_the_twelve_are_one_table() -> None:
    spec = importlib.util.find_spec('dynamixel_easy_sdk')
    if spec is None or not spec.submodule_search_locations:
        pytest.skip('dynamixel_easy_sdk (dynamixel-sdk 4.1) is not installed')
    folder = pathlib.Path(list(spec.submodule_search_locations)[0]) / 'control_table'
    texts = {(folder / (name.lower().replace('-', '_') + '.model')).read_text(encoding='utf-8')
             for name, *_ in PAGES.values()}
    assert len(texts) == 1


@pytest.mark.parametrize('plain, braked', ((4000, 4010), (4020, 4040), (4030, 4050),
                                           (4120, 4130), (4140, 4160), (4150, 4170)))
def test_a_brake_changes_only_the_brake_timing(plain: int, braked: int) -> None:
    without, with_brake = model_for(plain), model_for(braked)
    differ = {a.name for a, b in zip(without.items, with_brake.items) if a != b}
    assert differ == {'model_number', 'brake_delay', 'goal_update_delay',
                      'normal_excitation_voltage', 'overexcitation_time'}
