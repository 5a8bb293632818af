"""
The XL-320 and the Protocol 1.0 models: e-manual spot checks, workbench cross-checks, roles.

The generic checks (items disjoint and in range, modes, units, physics) run over these models
in test_model_families.py. Here: item by item against values read from the ROBOTIS e-manual
and dynamixel-workbench's dynamixel_item.cpp, hard-coded as an oracle independent of the
modules, and what roles, direction bits and the sign conventions must hold.
"""

import math

from dxl_servo_driver.models import ALL_MODELS, Model, model_for, model_named, modes, SUPPORTED
from dxl_servo_driver.models.names import OTHER_MODELS
import pytest

XL320 = model_for(350)
OLDER = tuple(model for model in ALL_MODELS if model.protocol == 1.0 or model.number == 350)

# What each role means, by the size and kind of the X register it stands for: (size, sign)
# where sign is 'direction' (a direction bit), 'plain' or 'any'.
ROLE_SHAPES: dict[str, tuple[int, str]] = {
    'operating_mode': (1, 'plain'),
    'goal_velocity': (2, 'direction'),
    'present_velocity': (2, 'direction'),
    'present_input_voltage': (1, 'plain'),
    'min_position_limit': (2, 'plain'),
    'max_position_limit': (2, 'plain'),
    'registered_instruction': (1, 'plain'),
    'homing_offset': (2, 'any'),
    'profile_acceleration': (1, 'plain'),
    'present_current': (2, 'any'),
    'goal_current': (2, 'direction'),
}


def _label(model: Model) -> str:
    return f'{model.number}-{model.name}-fw{model.min_firmware}'


every_older = pytest.mark.parametrize('model', OLDER, ids=_label)


@every_older
def test_roles_point_at_items_whose_shape_fits_the_role(model: Model) -> None:
    assert set(model.roles) <= set(ROLE_SHAPES), set(model.roles) - set(ROLE_SHAPES)
    for role, own in model.roles.items():
        assert not any(item.name == role for item in model.items), role
        item = model.item(own)
        assert model.item(role) is item
        size, sign = ROLE_SHAPES[role]
        assert item.size == size, (role, own)
        if sign == 'direction':
            assert item.direction_bit == 1024 and not item.signed, (role, own)
        elif sign == 'plain':
            assert not item.direction_bit and not item.raw_zero, (role, own)
    # The angle limits bound Goal Position: same unit, same range.
    low, high = model.item('min_position_limit'), model.item('max_position_limit')
    goal = model.item('goal_position')
    assert low.unit == high.unit == goal.unit == 'pulse'
    assert goal.limit == high.name


@every_older
def test_direction_bit_items_round_trip(model: Model) -> None:
    directed = [item for item in model.items if item.direction_bit]
    assert {'present_speed', 'present_load'} <= {item.name for item in directed}
    for item in directed:
        assert item.direction_bit == 1024 and item.size == 2
        assert (item.minimum, item.maximum) == (-1023, 1023)
        for value in (-1023, -1, 0, 1, 512, 1023):
            assert item.decode(item.encode(value)) == value
        # CW (negative here) sets bit 10 over the magnitude; 1,024 reads as 0 (e-manual).
        assert item.encode(-5) == (1024 + 5).to_bytes(2, 'little')
        assert item.decode((1024).to_bytes(2, 'little')) == 0
        with pytest.raises(OverflowError):
            item.encode(1024)


@every_older
def test_modes_follow_the_mode_register_or_the_angle_limits(model: Model) -> None:
    assert set(model.modes) <= set(modes.NAMES)
    if model.protocol == 1.0:
        assert model.mode_register == '' and not model.has('operating_mode')
        # The numbers are the X's codes for these names: no register holds them.
        assert all(model.modes[name] == modes.BY_NAME[name].number for name in model.modes)
        assert model.eeprom_end == 24 and model.item('torque_enable').address == 24
        assert not model.reboot
        assert max(item.address + item.size for item in model.items) <= 256
    else:
        assert model.mode_register == 'control_mode' and model.reboot and model.bulk_read
    assert model.velocity_unit_rpm > 0 and model.pulses_per_rev > 0 and model.voltage_unit_v > 0
    assert model.load_unit_ratio == 0.001 and model.pwm_full_raw == 1023
    assert not model.indirect and model.fast_sync_read_firmware is None
    assert model.item('goal_position').maximum <= model.extended_position_limit


@every_older
def test_physics_is_sane(model: Model) -> None:
    nominal = model.physics.nominal
    assert 0.1 < nominal.stall_torque_nm < 20 and 0.1 < nominal.stall_current_a < 10
    assert 10 < nominal.no_load_speed_rpm < 600 and 10 < model.physics.gear_ratio < 300
    low, high = model.item('min_voltage_limit'), model.item('max_voltage_limit')
    assert low.minimum <= nominal.voltage_v / model.voltage_unit_v <= high.maximum


# --- XL-320 ----------------------------------------------------------------------------------

# e-manual XL-320 control table: name -> (address, size, initial).
XL320_EMANUAL = {
    'model_number': (0, 2, 350), 'id': (3, 1, 1), 'baud_rate': (4, 1, 3),
    'return_delay_time': (5, 1, 250), 'ccw_angle_limit': (8, 2, 1023),
    'control_mode': (11, 1, 2), 'temperature_limit': (12, 1, 65),
    'min_voltage_limit': (13, 1, 60), 'max_voltage_limit': (14, 1, 90),
    'max_torque': (15, 2, 1023), 'shutdown': (18, 1, 3), 'torque_enable': (24, 1, 0),
    'p_gain': (29, 1, 32), 'torque_limit': (35, 2, 1023), 'hardware_error_status': (50, 1, 0),
    'punch': (51, 2, 32),
}
# dynamixel-workbench dynamixel_item.cpp, items_XL320: name -> (address, size).
XL320_WORKBENCH = {
    'model_number': (0, 2), 'firmware_version': (2, 1), 'id': (3, 1), 'baud_rate': (4, 1),
    'return_delay_time': (5, 1), 'cw_angle_limit': (6, 2), 'ccw_angle_limit': (8, 2),
    'control_mode': (11, 1), 'temperature_limit': (12, 1), 'min_voltage_limit': (13, 1),
    'max_voltage_limit': (14, 1), 'max_torque': (15, 2), 'status_return_level': (17, 1),
    'shutdown': (18, 1), 'torque_enable': (24, 1), 'led': (25, 1), 'd_gain': (27, 1),
    'i_gain': (28, 1), 'p_gain': (29, 1), 'goal_position': (30, 2), 'moving_speed': (32, 2),
    'torque_limit': (34, 2), 'present_position': (37, 2), 'present_speed': (39, 2),
    'present_load': (41, 2), 'present_voltage': (45, 1), 'present_temperature': (46, 1),
    'registered_instruction': (47, 1), 'moving': (49, 1), 'hardware_error_status': (50, 1),
    'punch': (51, 2),
}


def test_xl320_against_the_emanual() -> None:
    for name, (address, size, initial) in XL320_EMANUAL.items():
        item = XL320.item(name)
        assert (item.address, item.size, item.initial) == (address, size, initial), name
    assert XL320.bauds == {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000}
    assert XL320.hardware_error_bits == {1: 'overload', 2: 'overheating', 4: 'input_voltage'}
    assert XL320.item('led').maximum == 7 and XL320.item('control_mode').minimum == 1


def test_xl320_against_the_workbench() -> None:
    assert {item.name for item in XL320.items} == set(XL320_WORKBENCH)
    for name, (address, size) in XL320_WORKBENCH.items():
        item = XL320.item(name)
        if name == 'torque_limit':
            # The workbench's 34 would end where Moving Speed's bytes do not; the e-manual
            # and the SDK model file agree on 35.
            assert (item.address, item.size) == (35, 2)
            continue
        assert (item.address, item.size) == (address, size), name


def test_xl320_units_modes_and_roles() -> None:
    assert XL320.protocol == 2.0 and XL320.eeprom_end == 24
    assert XL320.modes == {'velocity': 1, 'position': 2}
    assert XL320.item('operating_mode') is XL320.item('control_mode')
    assert XL320.pulses_per_rev == pytest.approx(1228.8) and XL320.position_zero_raw == 512
    # 1,023 steps span 300 degrees, centred on 512.
    span = 1023 / XL320.pulses_per_rev * 360
    assert span == pytest.approx(300 * 1023 / 1024)
    assert XL320.current_unit_a is None and not XL320.has('present_current')
    assert not XL320.has('pwm_limit') and not XL320.has('homing_offset')
    assert not XL320.has('realtime_tick') and XL320.extended_position_limit == 1023
    assert XL320.homing_position_mode_limit is None
    assert XL320.stall_torque_nm == 0.39 and XL320.physics.nominal.voltage_v == 7.4
    assert XL320.physics.nominal.no_load_speed_rpm == 114 and XL320.physics.gear_ratio == 238
    assert math.isclose(XL320.torque_constant_nm_per_a, 0.39 / 1.1)
    assert model_named('xl-320') is XL320 and 350 in SUPPORTED and 350 not in OTHER_MODELS
