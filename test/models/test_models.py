"""
The X-series catalogue: SDK model files, the XM430 manual, internal consistency, look-ups.

The other families are checked by test_model_families.py.
"""

from dataclasses import replace
import math
import pathlib
import re

from dxl_servo_driver.models import (
    ALL_MODELS, FAMILIES, MANUAL_DIFFERENCES, Model, model_for, model_named, ModelError, modes,
    SUPPORTED, unsupported_reason, X_MODELS, xm430)
from dxl_servo_driver.models.layout import EEPROM_END
from dxl_servo_driver.models.names import OTHER_MODELS
import pytest
from sdk_model_files import listed_models, needs_sdk, SDK, SDK_ALIASES, SDK_NAMES, sdk_rows, snake


# Items our tables have beyond the model files (all from the e-manual or the XM430 manual).
EXTRAS = {'startup_configuration', 'backup_ready'}
SEED_ONLY = {'acceleration_limit'}

# X models no SDK model file describes: checked against their e-manual page below instead.
NO_MODEL_FILE = {1710}
FILED = tuple(model for model in X_MODELS if model.number not in NO_MODEL_FILE)

SIGNED = {'homing_offset', 'goal_pwm', 'goal_current', 'goal_velocity', 'goal_position',
          'present_pwm', 'present_current', 'present_load', 'present_velocity',
          'present_position', 'velocity_trajectory', 'position_trajectory'}
LIMITS = {'goal_pwm': 'pwm_limit', 'goal_current': 'current_limit',
          'goal_velocity': 'velocity_limit', 'profile_velocity': 'velocity_limit',
          'goal_position': 'max_position_limit'}
MODE_NAMES = {'current', 'velocity', 'position', 'extended_position', 'current_based_position',
              'pwm'}
ERROR_NAMES = {'input_voltage', 'overheating', 'motor_encoder', 'electrical_shock', 'overload'}


def _label(model: Model) -> str:
    return f'{model.number}-fw{model.min_firmware}'


def _our_name(sdk_name: str) -> str:
    return SDK_NAMES.get(sdk_name) or snake(sdk_name)


def _stem(model: Model) -> str:
    return model.name.lower().replace('-', '_')


def _sdk_file(model: Model) -> pathlib.Path:
    """
    Return the model file describing this variant.

    The newest variant is the plain file; an older one is '<stem>_fwNN.model', NN being the
    last firmware it covers (the convention of ROBOTIS's dynamixel_hardware_interface).
    """
    assert SDK is not None
    variants = SUPPORTED[model.number]
    index = variants.index(model)
    if index == len(variants) - 1:
        return SDK / f'{_stem(model)}.model'
    return SDK / f'{_stem(model)}_fw{variants[index + 1].min_firmware - 1}.model'


def _squash(text: str) -> str:
    return re.sub(r'[^0-9a-z]', '', text.lower())


# --- the SDK's model files ---------------------------------------------------------------


@needs_sdk
@pytest.mark.parametrize('model', FILED, ids=_label)
def test_every_model_file_row_is_in_the_table(model: Model) -> None:
    path = _sdk_file(model)
    assert path.is_file(), f'{model.label}: no SDK model file {path.name}'
    seen = set()
    for address, size, sdk_name in sdk_rows(path):
        if sdk_name in SDK_ALIASES:
            ours = model.by_address(address)
            assert ours.name.startswith(SDK_ALIASES[sdk_name]), (sdk_name, ours)
        else:
            ours = model.item(_our_name(sdk_name))
            assert ours.address == address, (sdk_name, ours)
        assert ours.size == size, (sdk_name, ours)
        seen.add(ours.name)
    extras = {item.name for item in model.items} - seen
    allowed = EXTRAS | (SEED_ONLY if model.number in (1020, 1030) else set())
    unexplained = {name for name in extras
                   if name not in allowed and not name.startswith('indirect_')}
    assert not unexplained, f'{model.label}: items the model file lacks: {unexplained}'


@needs_sdk
def test_dynamixel_model_names_the_files_of_our_models() -> None:
    assert SDK is not None
    listed = listed_models()
    for number, variants in SUPPORTED.items():
        newest = variants[-1]
        if newest not in X_MODELS:
            continue   # test_model_families.py
        if number in listed:
            assert listed[number] == f'{_stem(newest)}.model', newest.label
        elif number in NO_MODEL_FILE:
            # XM335-T323: neither number nor file in the SDK; the number is the e-manual's.
            assert not (SDK / f'{_stem(newest)}.model').is_file()
        else:
            # XW430-T200: the file ships, the number is only in the e-manual.
            assert number == 1280 and (SDK / f'{_stem(newest)}.model').is_file()


@needs_sdk
def test_every_other_sdk_model_is_refused_by_name() -> None:
    for number, file_name in listed_models().items():
        if number in SUPPORTED:
            continue
        reason = unsupported_reason(number)
        assert _squash(file_name.removesuffix('.model')) in _squash(reason), (number, reason)


# --- the XM430 manual -----------------------------------------------------------------------


@pytest.mark.parametrize('number', [1020, 1030])
def test_xm430_tables_carry_the_manuals_items_unchanged(number: int) -> None:
    model = model_for(number)
    for manual_item in xm430.ITEMS:
        ours = model.item(manual_item.name)
        if manual_item.name == 'model_number':
            # The manual's is model 1030; only the number it reports differs for 1020.
            assert ours.initial == number
            assert replace(ours, initial=xm430.MODEL_NUMBER) == manual_item
        else:
            assert ours == manual_item
    added = {item.name for item in model.items} - {manual_item.name for manual_item in xm430.ITEMS}
    assert added == {'drive_mode', 'secondary_id', 'bus_watchdog', 'startup_configuration',
                     'backup_ready'}
    assert model.modes == modes.numbers(*modes.NAMES)
    assert model.bauds == xm430.BAUD_RATES
    assert model.hardware_error_bits == xm430.HARDWARE_ERROR_BITS


def test_the_manuals_datasheet_is_the_xm430_w350_one() -> None:
    # The XM430 manual: 353.5:1; 3.8/4.1/4.8 N.m at 11.1/12/14.8 V, 2.1/2.3/2.7 A, 43/46/57 rpm.
    physics = model_for(1020).physics
    assert physics.gear_ratio == 353.5 and physics.nominal_voltage_v == 12.0
    rows = [(p.voltage_v, p.stall_torque_nm, p.stall_current_a, p.no_load_speed_rpm)
            for p in physics.points]
    assert rows == [(11.1, 3.8, 2.1, 43), (12.0, 4.1, 2.3, 46), (14.8, 4.8, 2.7, 57)]
    assert model_for(1020).torque_constant_nm_per_a == pytest.approx(4.1 / 2.3)
    # The manual (model 1030) wins over the e-manual's XM430-W210 figures for 1030.
    assert (model_for(1030).physics.gear_ratio, model_for(1030).physics.points) == (
        physics.gear_ratio, physics.points)


def test_the_manuals_differences_are_listed() -> None:
    text = ' '.join(MANUAL_DIFFERENCES)
    for name in ('Drive Mode', 'Secondary(Shadow) ID', 'Bus Watchdog', 'Acceleration Limit',
                 'Startup Configuration', 'Backup Ready'):
        assert name in text
    assert all(sentence.endswith('.') for sentence in MANUAL_DIFFERENCES)


# --- internal consistency -------------------------------------------------------------------


@pytest.mark.parametrize('model', X_MODELS, ids=_label)
def test_items_are_sorted_disjoint_and_well_formed(model: Model) -> None:
    names = [item.name for item in model.items]
    assert len(names) == len(set(names))
    assert [item.address for item in model.items] == sorted(item.address for item in model.items)
    for item, following in zip(model.items, model.items[1:]):
        assert item.address + item.size <= following.address, (item.name, following.name)
    for item in model.items:
        assert re.fullmatch(r'[a-z][a-z0-9_]*', item.name), item.name
        assert item.size in (1, 2, 4) and item.access in ('R', 'RW')
        assert item.area == ('eeprom' if item.address < EEPROM_END else 'ram'), item.name
        assert item.minimum <= item.initial <= item.maximum, item.name
        bits = 8 * item.size - (1 if item.signed else 0)
        low, high = (-(1 << bits), (1 << bits) - 1) if item.signed else (0, (1 << bits) - 1)
        assert low <= item.minimum and item.maximum <= high, item.name
        assert item.signed == (item.name in SIGNED), item.name
        assert model.by_address(item.address) is item
        assert model.lookup(item.name) is item


@pytest.mark.parametrize('model', X_MODELS, ids=_label)
def test_limits_point_at_existing_registers(model: Model) -> None:
    for item in model.items:
        if item.limit is not None:
            bound = model.item(item.limit)
            # The static range is the widest the limit register allows.
            assert bound.maximum <= item.maximum, item.name
    for name, limit in LIMITS.items():
        if model.has(name):
            assert model.item(name).limit == limit
    expected = 'acceleration_limit' if model.has('acceleration_limit') else None
    assert model.item('profile_acceleration').limit == expected
    velocity = model.item('goal_velocity')
    assert velocity.minimum == -model.item('velocity_limit').maximum


@pytest.mark.parametrize('model', X_MODELS, ids=_label)
def test_modes_units_and_bauds_agree_with_the_table(model: Model) -> None:
    assert set(model.modes) <= MODE_NAMES and {'velocity', 'position', 'pwm'} <= set(model.modes)
    assert len(set(model.modes.values())) == len(model.modes)
    mode = model.item('operating_mode')
    assert all(mode.minimum <= value <= mode.maximum for value in model.modes.values())
    assert mode.initial in model.modes.values()
    assert (model.current_unit_a is not None) == model.has('present_current')
    assert (model.load_unit_ratio is not None) == model.has('present_load')
    assert model.has('present_current') != model.has('present_load')
    assert ('current' in model.modes) == model.has('goal_current') == model.has('current_limit')
    baud = model.item('baud_rate')
    assert sorted(model.bauds) == list(range(baud.minimum, baud.maximum + 1))
    speeds = [model.bauds[value] for value in sorted(model.bauds)]
    assert speeds == sorted(set(speeds)) and baud.initial in model.bauds
    assert all(bit & (bit - 1) == 0 and bit < 0x80 for bit in model.hardware_error_bits)
    assert set(model.hardware_error_bits.values()) == ERROR_NAMES
    assert model.item('model_number').initial == model.number
    assert model.item('firmware_version').initial >= model.min_firmware
    volts = model.item('present_input_voltage').initial
    assert model.item('min_voltage_limit').initial <= volts
    assert volts <= model.item('max_voltage_limit').initial


@pytest.mark.parametrize('model', X_MODELS, ids=_label)
def test_indirect_entries_match_the_items(model: Model) -> None:
    addresses = [item for item in model.items if item.name.startswith('indirect_address_')]
    data = [item for item in model.items if item.name.startswith('indirect_data_')]
    assert len(model.indirect) == len(addresses) == len(data) > 0
    for number, (address, datum) in enumerate(model.indirect, start=1):
        entry = model.item(f'indirect_address_{number}')
        target = model.item(f'indirect_data_{number}')
        assert (entry.address, entry.size, entry.initial) == (address, 2, datum)
        assert (target.address, target.size) == (datum, 1)
        assert entry.minimum == EEPROM_END and entry.maximum == model.table_end - 1


@pytest.mark.parametrize('model', X_MODELS, ids=_label)
def test_physics_is_usable(model: Model) -> None:
    physics = model.physics
    voltages = [point.voltage_v for point in physics.points]
    assert voltages == sorted(set(voltages))
    assert any(math.isclose(v, physics.nominal_voltage_v) for v in voltages)
    assert physics.gear_ratio > 1 and physics.source
    assert model.torque_constant_nm_per_a > 0 and model.stall_torque_nm > 0
    for point in physics.points:
        assert point.stall_current_a > 0 and point.no_load_speed_rpm > 0
    # The velocity registers can express the no-load speed.
    fastest = max(point.no_load_speed_rpm for point in physics.points)
    assert model.item('velocity_limit').maximum * model.velocity_unit_rpm >= fastest
    # The nominal supply sits inside the power-on voltage limits.
    nominal = physics.nominal_voltage_v / model.voltage_unit_v
    assert model.item('min_voltage_limit').initial <= nominal
    assert nominal <= model.item('max_voltage_limit').initial


def test_family_features() -> None:
    assert not model_for(1060).has('goal_current') and model_for(1060).has('present_load')
    assert set(model_for(1060).modes) == {'velocity', 'position', 'extended_position', 'pwm'}
    assert model_for(1060).load_unit_ratio == 0.001
    assert model_for(1120).item('external_port_data_3').address == 156
    assert not model_for(1170).has('led') and model_for(1020).has('led')
    assert model_for(1200).current_unit_a == 0.001 and max(model_for(1200).bauds) == 6
    assert model_for(1200).bauds[6] == 4_000_000 and model_for(1060).bauds[7] == 4_500_000
    assert model_for(1040).current_unit_a == pytest.approx(1.34e-3)
    assert model_for(1090).fast_sync_read_firmware is None
    assert model_for(1060).fast_sync_read_firmware == 45
    assert model_for(1200).fast_sync_read_firmware == 46


# --- look-ups ------------------------------------------------------------------------------


def test_x330_indirect_block_depends_on_the_firmware() -> None:
    old, new = SUPPORTED[1230]
    assert (old.min_firmware, new.min_firmware) == (0, 53)
    assert model_for(1230, 52) is old and model_for(1230, 0) is old
    assert model_for(1230, 53) is new and model_for(1230) is new
    assert old.indirect[0] == (168, 208) and len(old.indirect) == 20
    assert new.indirect[0] == (168, 224) and len(new.indirect) == 28
    assert old.table_end == 228 and new.table_end == 252


def test_model_for_picks_the_only_table_whatever_the_firmware() -> None:
    assert model_for(1020, 1) is model_for(1020, 99) is model_for(1020) is SUPPORTED[1020][0]
    with pytest.raises(ModelError):
        model_for(1020, -1)


# Every model still refused is refused by its name (whatever is left in names.py), and a
# number nobody knows by its number.
@pytest.mark.parametrize('number,names', [
    *((number, (name,)) for number, (name, _) in OTHER_MODELS.items()), (9999, ('9999',)),
])
def test_refused_models_are_named(number: int, names: tuple[str, ...]) -> None:
    reason = unsupported_reason(number)
    with pytest.raises(ModelError) as raised:
        model_for(number)
    assert isinstance(raised.value, ValueError)
    for text in (reason, str(raised.value)):
        assert all(name in text for name in names), text
        assert all(family in text for family in FAMILIES), text


def test_supported_models_have_no_reason_to_refuse() -> None:
    assert all(unsupported_reason(number) == '' for number in SUPPORTED)
    assert len(X_MODELS) == 39 and len({model.number for model in X_MODELS}) == 33
    assert set(X_MODELS) <= set(ALL_MODELS)


def test_model_named() -> None:
    assert model_named('xl430-w250') is model_for(1060)
    assert model_named(' XM430-W350-T ') is model_for(1020)
    assert model_named('xh540-w270-t/r') is model_for(1100)
    assert model_named('XW430-T200') is model_for(1280)
    assert model_named('XC330-M288') is model_for(1240)
    assert model_named('XM335-T323-T') is model_for(1710)
    # The ball-bearing XC430 report the plain ones' numbers (their e-manual pages).
    assert model_named('XC430-T150BB-T') is model_for(1070) is model_named('xc430-w150bb')
    assert model_named('XC430-W240BB') is model_for(1080) is model_named('XC430-T240BB')
    assert model_named('L42-10-S300-R') is model_for(35072)
    with pytest.raises(ModelError, match='XC335-T332'):
        model_named('XC335-T332')


def test_item_lookups_fail_clearly() -> None:
    model = model_for(1060)
    with pytest.raises(KeyError, match='XL430-W250.*goal_current'):
        model.item('goal_current')
    with pytest.raises(KeyError, match='address 1'):
        model.by_address(1)
    assert model.lookup(126).name == 'present_load' and model.has('present_load')
    assert model.decode_hardware_errors(0x24) == ['overheating', 'overload']


def test_physics_between_and_beyond_the_published_points() -> None:
    physics = model_for(1020).physics
    assert physics.at(12.0) == physics.nominal
    middle = physics.at((12.0 + 14.8) / 2)
    assert middle.stall_torque_nm == pytest.approx((4.1 + 4.8) / 2)
    assert middle.no_load_speed_rpm == pytest.approx((46 + 57) / 2)
    assert physics.at(5.0) == physics.points[0] and physics.at(30.0) == physics.points[-1]


# --- XM335-T323: its e-manual page as the oracle (no SDK model file) -------------------------

# (address, size) of every item the page lists, indirect entries aside.
XM335_PAGE = {
    'model_number': (0, 2), 'model_information': (2, 4), 'firmware_version': (6, 1),
    'id': (7, 1), 'baud_rate': (8, 1), 'return_delay_time': (9, 1), 'drive_mode': (10, 1),
    'operating_mode': (11, 1), 'secondary_id': (12, 1), 'protocol_version': (13, 1),
    'homing_offset': (20, 4), 'moving_threshold': (24, 4), 'temperature_limit': (31, 1),
    'max_voltage_limit': (32, 2), 'min_voltage_limit': (34, 2), 'pwm_limit': (36, 2),
    'current_limit': (38, 2), 'velocity_limit': (44, 4), 'max_position_limit': (48, 4),
    'min_position_limit': (52, 4), 'startup_configuration': (60, 1), 'pwm_slope': (62, 1),
    'shutdown': (63, 1), 'torque_enable': (64, 1), 'led': (65, 1),
    'status_return_level': (68, 1), 'registered_instruction': (69, 1),
    'hardware_error_status': (70, 1), 'velocity_i_gain': (76, 2), 'velocity_p_gain': (78, 2),
    'position_d_gain': (80, 2), 'position_i_gain': (82, 2), 'position_p_gain': (84, 2),
    'feedforward_2nd_gain': (88, 2), 'feedforward_1st_gain': (90, 2), 'bus_watchdog': (98, 1),
    'goal_pwm': (100, 2), 'goal_current': (102, 2), 'goal_velocity': (104, 4),
    'profile_acceleration': (108, 4), 'profile_velocity': (112, 4), 'goal_position': (116, 4),
    'realtime_tick': (120, 2), 'moving': (122, 1), 'moving_status': (123, 1),
    'present_pwm': (124, 2), 'present_current': (126, 2), 'present_velocity': (128, 4),
    'present_position': (132, 4), 'velocity_trajectory': (136, 4),
    'position_trajectory': (140, 4), 'present_input_voltage': (144, 2),
    'present_temperature': (146, 1), 'backup_ready': (147, 1),
}
# name -> initial, as the page gives them.
XM335_INITIALS = {
    'model_number': 1710, 'baud_rate': 3, 'drive_mode': 0, 'operating_mode': 3,
    'protocol_version': 2, 'moving_threshold': 10, 'temperature_limit': 70,
    'max_voltage_limit': 140, 'min_voltage_limit': 55, 'pwm_limit': 885, 'current_limit': 910,
    'velocity_limit': 280, 'max_position_limit': 3072, 'min_position_limit': 1024,
    'pwm_slope': 255, 'shutdown': 52, 'velocity_i_gain': 1800, 'velocity_p_gain': 50,
    'position_p_gain': 2000, 'indirect_address_1': 224, 'indirect_address_28': 251,
}


def test_xm335_against_its_page() -> None:
    model = model_for(1710)
    ours = {item.name: (item.address, item.size) for item in model.items
            if not item.name.startswith('indirect_')}
    assert ours == XM335_PAGE
    for name, initial in XM335_INITIALS.items():
        assert model.item(name).initial == initial, name
    # 28 entries: addresses 168..222, data 224..251, any RAM address 64..251.
    assert model.indirect[0] == (168, 224) and model.indirect[-1] == (222, 251)
    assert len(model.indirect) == 28 and model.table_end == 252
    assert model.item('indirect_address_1').maximum == 251
    assert (model.item('protocol_version').maximum, model.item('baud_rate').maximum) == (22, 6)
    assert model.item('current_limit').unit == '1 mA' and model.current_unit_a == 0.001
    assert model.item('velocity_limit').maximum == 2047
    assert model.item('pwm_slope').unit == '3.955 mV/ms'
    assert max(model.bauds.values()) == 4_000_000 and set(model.modes) == MODE_NAMES
    assert len(SUPPORTED[1710]) == 1 and model.fast_sync_read_firmware == 46


def test_xm335_physics_is_the_copied_datasheet() -> None:
    physics = model_for(1710).physics
    assert physics.gear_ratio == 323.04 and physics.nominal_voltage_v == 11.1
    assert [(p.voltage_v, p.stall_torque_nm, p.stall_current_a, p.no_load_speed_rpm)
            for p in physics.points] == [(11.1, 1.03, 0.80, 53)]
    # The stated cross-check: the XC330-T288 at 11.1 V scaled by the gear ratios.
    sibling = model_for(1220).physics
    assert physics.nominal.stall_torque_nm == pytest.approx(
        sibling.at(11.1).stall_torque_nm * 323.04 / sibling.gear_ratio, abs=0.005)
    assert 'third-party' in physics.source
