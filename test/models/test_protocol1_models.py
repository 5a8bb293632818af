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
from dxl_servo_driver.models.protocol1 import servo_rate
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


# --- Protocol 1.0 ----------------------------------------------------------------------------

# dynamixel-workbench dynamixel_item.cpp, items_AX and items_RX (identical): (address, size).
WB_AX = {
    'model_number': (0, 2), 'firmware_version': (2, 1), 'id': (3, 1), 'baud_rate': (4, 1),
    'return_delay_time': (5, 1), 'cw_angle_limit': (6, 2), 'ccw_angle_limit': (8, 2),
    'temperature_limit': (11, 1), 'min_voltage_limit': (12, 1), 'max_voltage_limit': (13, 1),
    'max_torque': (14, 2), 'status_return_level': (16, 1), 'alarm_led': (17, 1),
    'shutdown': (18, 1), 'torque_enable': (24, 1), 'led': (25, 1),
    'cw_compliance_margin': (26, 1), 'ccw_compliance_margin': (27, 1),
    'cw_compliance_slope': (28, 1), 'ccw_compliance_slope': (29, 1), 'goal_position': (30, 2),
    'moving_speed': (32, 2), 'torque_limit': (34, 2), 'present_position': (36, 2),
    'present_speed': (38, 2), 'present_load': (40, 2), 'present_voltage': (42, 1),
    'present_temperature': (43, 1), 'registered': (44, 1), 'moving': (46, 1), 'lock': (47, 1),
    'punch': (48, 2),
}
# items_EX: the AX rows plus Drive Mode and Sensed Current ('Sensored_Current'); its Moving
# Speed at 34 and Torque Limit at 35 would overlap: the e-manual's 32 and 34 are the oracle.
WB_EX = {**WB_AX, 'drive_mode': (10, 1), 'sensed_current': (56, 2)}
# items_MX (MX-12W, MX-28): gains instead of compliance, the multi-turn items, acceleration.
WB_MX = {name: place for name, place in WB_AX.items() if 'compliance' not in name}
WB_MX.update({'multi_turn_offset': (20, 2), 'resolution_divider': (22, 1), 'd_gain': (26, 1),
              'i_gain': (27, 1), 'p_gain': (28, 1), 'goal_acceleration': (73, 1)})
# items_EXTMX (MX-64, MX-106): plus current and torque control.
WB_EXTMX = {**WB_MX, 'current': (68, 2), 'torque_ctrl_mode_enable': (70, 1),
            'goal_torque': (71, 2)}
# The DX-116's e-manual table is the DX-113's row for row: held to the same AX rows.
WORKBENCH = {12: WB_AX, 300: WB_AX, 18: WB_AX, 10: WB_AX, 24: WB_AX, 28: WB_AX, 64: WB_AX,
             113: WB_AX, 116: WB_AX, 117: WB_AX, 107: WB_EX, 360: WB_MX, 29: WB_MX,
             310: WB_EXTMX, 320: WB_EXTMX}
# Items the e-manual has and the workbench lacks: Realtime Tick (MX firmware 40/41 on),
# the MX-106's Drive Mode.
BEYOND_WORKBENCH = {'realtime_tick', 'drive_mode'}

# e-manual control tables: number -> {name: (address, size, initial)}, at least six per family.
EMANUAL = {
    12: {'model_number': (0, 2, 12), 'baud_rate': (4, 1, 1), 'ccw_angle_limit': (8, 2, 1023),
         'temperature_limit': (11, 1, 70), 'max_voltage_limit': (13, 1, 140),
         'alarm_led': (17, 1, 36), 'shutdown': (18, 1, 36), 'cw_compliance_slope': (28, 1, 32),
         'torque_limit': (34, 2, 1023), 'punch': (48, 2, 32)},
    300: {'model_number': (0, 2, 300), 'cw_compliance_margin': (26, 1, 4),
          'ccw_compliance_slope': (29, 1, 64), 'min_voltage_limit': (12, 1, 60)},
    18: {'model_number': (0, 2, 18), 'temperature_limit': (11, 1, 75),
         'max_torque': (14, 2, 983), 'torque_limit': (34, 2, 983)},
    28: {'model_number': (0, 2, 28), 'baud_rate': (4, 1, 34), 'max_voltage_limit': (13, 1, 190),
         'temperature_limit': (11, 1, 80), 'lock': (47, 1, 0), 'registered': (44, 1, 0),
         'punch': (48, 2, 32)},
    64: {'model_number': (0, 2, 64), 'max_voltage_limit': (13, 1, 190)},
    113: {'model_number': (0, 2, 113), 'baud_rate': (4, 1, 34),
          'temperature_limit': (11, 1, 85),
          'min_voltage_limit': (12, 1, 60), 'max_voltage_limit': (13, 1, 190),
          'cw_compliance_margin': (26, 1, 0), 'ccw_compliance_slope': (29, 1, 32),
          'punch': (48, 2, 32)},
    116: {'model_number': (0, 2, 116), 'baud_rate': (4, 1, 34),
          'return_delay_time': (5, 1, 250), 'ccw_angle_limit': (8, 2, 1023),
          'temperature_limit': (11, 1, 85), 'min_voltage_limit': (12, 1, 60),
          'max_voltage_limit': (13, 1, 190), 'max_torque': (14, 2, 1023),
          'alarm_led': (17, 1, 36), 'cw_compliance_margin': (26, 1, 0),
          'ccw_compliance_slope': (29, 1, 32), 'punch': (48, 2, 32)},
    117: {'model_number': (0, 2, 117), 'baud_rate': (4, 1, 34),
          'max_voltage_limit': (13, 1, 190), 'cw_compliance_margin': (26, 1, 1)},
    107: {'model_number': (0, 2, 107), 'ccw_angle_limit': (8, 2, 4095),
          'drive_mode': (10, 1, 0), 'max_voltage_limit': (13, 1, 240), 'punch': (48, 2, 0),
          'moving_speed': (32, 2, 0), 'torque_limit': (34, 2, 1023)},
    29: {'model_number': (0, 2, 29), 'baud_rate': (4, 1, 34), 'ccw_angle_limit': (8, 2, 4095),
         'multi_turn_offset': (20, 2, 0), 'resolution_divider': (22, 1, 1),
         'p_gain': (28, 1, 32), 'punch': (48, 2, 0), 'goal_acceleration': (73, 1, 0),
         'realtime_tick': (50, 2, 0)},
    310: {'model_number': (0, 2, 310), 'torque_ctrl_mode_enable': (70, 1, 0),
          'goal_torque': (71, 2, 0), 'max_voltage_limit': (13, 1, 160)},
    320: {'model_number': (0, 2, 320), 'drive_mode': (10, 1, 0),
          'max_voltage_limit': (13, 1, 160), 'goal_acceleration': (73, 1, 0)},
    360: {'model_number': (0, 2, 360), 'baud_rate': (4, 1, 1), 'd_gain': (26, 1, 8),
          'p_gain': (28, 1, 8), 'punch': (48, 2, 32), 'temperature_limit': (11, 1, 70)},
}
PROTOCOL1 = tuple(model for model in ALL_MODELS if model.protocol == 1.0)
every_protocol1 = pytest.mark.parametrize('model', PROTOCOL1, ids=_label)


def test_every_protocol1_model_is_here_once_or_twice() -> None:
    assert {model.number for model in PROTOCOL1} == set(WORKBENCH)
    for model in PROTOCOL1:
        assert len(SUPPORTED[model.number]) == (2 if model.family == 'MX(1.0)' else 1)


@every_protocol1
def test_protocol1_against_the_workbench(model: Model) -> None:
    oracle = WORKBENCH[model.number]
    ours = {item.name: (item.address, item.size) for item in model.items}
    assert set(oracle) <= set(ours), set(oracle) - set(ours)
    assert set(ours) - set(oracle) <= BEYOND_WORKBENCH
    for name, place in oracle.items():
        assert ours[name] == place, name


@every_protocol1
def test_protocol1_against_the_emanual(model: Model) -> None:
    for name, (address, size, initial) in EMANUAL.get(model.number, {}).items():
        if name == 'realtime_tick' and not model.min_firmware:
            assert not model.has(name)
            continue
        item = model.item(name)
        assert (item.address, item.size, item.initial) == (address, size, initial), name


@every_protocol1
def test_protocol1_bauds_are_the_formula(model: Model) -> None:
    mx = model.family == 'MX(1.0)'
    # The e-manual's table: the host speed each value serves, within the 3 % a UART takes of
    # what the servo runs at (2,000,000 / (v + 1); 16 is the worst, 2.1 %).
    expected = {1: 1_000_000, 3: 500_000, 4: 400_000, 7: 250_000, 9: 200_000, 16: 115_200,
                34: 57_600, 103: 19_200, 207: 9_600}
    if mx:
        expected.update({250: 2_250_000, 251: 2_500_000, 252: 3_000_000})
    assert model.bauds == expected
    for value, bps in model.bauds.items():
        if value < 250:
            assert abs(servo_rate(value) - bps) / bps < 0.03
    assert model.item('baud_rate').initial in (1, 34)


@every_protocol1
def test_protocol1_modes_roles_and_instructions(model: Model) -> None:
    assert model.hardware_error_bits == {
        0x01: 'input_voltage', 0x02: 'angle_limit', 0x04: 'overheating', 0x08: 'range',
        0x10: 'checksum', 0x20: 'overload', 0x40: 'instruction'}
    assert not model.has('hardware_error_status') and not model.has('operating_mode')
    assert model.item('shutdown').initial == model.item('alarm_led').initial == 0x24
    family = model.family
    assert model.bulk_read == (family in ('MX(1.0)', 'EX'))
    expected = {'AX': {'velocity', 'position'}, 'RX': {'velocity', 'position'},
                'EX': {'velocity', 'position'}, 'DX': {'position'},
                'MX(1.0)': {'velocity', 'position', 'extended_position'}}[family]
    if model.number in (310, 320):
        expected = expected | {'current'}
    assert set(model.modes) == expected
    if family == 'MX(1.0)':
        assert model.item('homing_offset').name == 'multi_turn_offset'
        assert model.homing_position_mode_limit == 0
        assert model.extended_position_limit == 28_672 and model.pulses_per_rev == 4096
        assert model.item('goal_position').signed and model.position_zero_raw == 2048
        assert model.item('profile_acceleration').name == 'goal_acceleration'
        assert model.acceleration_unit_rpm2 == pytest.approx(85.83)
    else:
        assert not model.has('homing_offset') and not model.has('profile_acceleration')
        assert model.homing_position_mode_limit is None
    if family in ('AX', 'RX', 'DX'):
        assert model.pulses_per_rev == pytest.approx(1228.8) and model.position_zero_raw == 512
        assert model.extended_position_limit == 1023 and model.velocity_unit_rpm == 0.111


def test_mx_realtime_tick_comes_with_firmware_40() -> None:
    for number, first in ((29, 40), (310, 40), (320, 40), (360, 41)):
        assert not model_for(number, first - 1).has('realtime_tick')
        tick = model_for(number, first).item('realtime_tick')
        assert (tick.address, tick.size, tick.maximum) == (50, 2, 32767)
        assert model_for(number) is model_for(number, first)


def test_mx64_current_is_offset_and_goal_torque_signed_by_a_bit() -> None:
    mx64 = model_for(310)
    current = mx64.item('present_current')
    assert current.name == 'current' and current.raw_zero == 2048
    # e-manual: 2,148 is 450 mA (4.5 mA per count above 2,048); 2,048 is none.
    assert current.decode((2148).to_bytes(2, 'little')) == 100
    assert current.decode((2048).to_bytes(2, 'little')) == 0
    assert current.encode(-48) == (2000).to_bytes(2, 'little')
    assert mx64.current_unit_a == pytest.approx(0.0045)
    goal = mx64.item('goal_current')
    assert goal.name == 'goal_torque' and goal.direction_bit == 1024
    assert goal.encode(-100) == (1024 + 100).to_bytes(2, 'little')
    assert not model_for(29).has('present_current') and model_for(29).current_unit_a is None


def test_units_differ_where_the_manual_says() -> None:
    ex = model_for(107)
    assert ex.pulses_per_rev == pytest.approx(4096 * 360 / 250.92) and ex.position_zero_raw == 2048
    assert ex.item('present_position').maximum == 0xFFFF   # the raw encoder in wheel mode
    assert model_for(29).velocity_unit_rpm == 0.114 == model_for(320).velocity_unit_rpm
    assert model_for(360).velocity_unit_rpm == 0.916
    assert model_for(18).stall_torque_nm == 1.8 and model_for(28).physics.nominal_voltage_v == 18.5
    assert model_for(310).physics.at(14.8).stall_torque_nm == 7.3
    assert model_named('mx-28') is model_for(29) and model_named('MX-28(2.0)') is model_for(30)


def test_the_dx_models_borrow_what_their_pages_lack() -> None:
    dx113, rx10 = model_for(113), model_for(10)
    assert 113 not in OTHER_MODELS and dx113.modes == {'position': 3}
    assert dx113.torque_constant_nm_per_a == pytest.approx(rx10.torque_constant_nm_per_a,
                                                           rel=0.01)
    assert dx113.stall_torque_nm == 1.0 and dx113.physics.nominal.no_load_speed_rpm == 54
    assert dx113.physics.gear_ratio == 192.6 and 'assumed' in dx113.physics.source
    # DX-116: the page's torques (2.1 N.m at 12 V, 2.9 at 16 V, 142.5:1); the DX-117's motor
    # through the 142.5:1 gear for the current and the speed.
    dx116, dx117 = model_for(116), model_for(117)
    assert 116 not in OTHER_MODELS and dx116.modes == {'position': 3}
    assert dx116.physics.gear_ratio == 142.5 and 'assumed' in dx116.physics.source
    assert [(p.voltage_v, p.stall_torque_nm) for p in dx116.physics.points] == [
        (12.0, 2.1), (16.0, 2.9)]
    ratio = 142.5 / 192.6
    for point in dx116.physics.points:
        assert point.torque_constant_nm_per_a == pytest.approx(
            dx117.torque_constant_nm_per_a * ratio, rel=0.01)
        expected = 85 / 18.5 * point.voltage_v / ratio
        assert point.no_load_speed_rpm == pytest.approx(expected, rel=0.005)
    assert dx116.physics.nominal_voltage_v == 16.0 and dx116.protocol == 1.0
    assert model_named('DX-116') is dx116
    for model in PROTOCOL1:
        assert model.number not in OTHER_MODELS
