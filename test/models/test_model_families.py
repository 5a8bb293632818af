"""
The families beyond the X series: SDK model files item by item, consistency, units, physics.

Every model outside the X series is checked against the ROBOTIS model file dynamixel-sdk ships
for it (address and size of every row), and for what the data must hold whatever the family.
"""

import math
import pathlib
import re

from dxl_servo_driver.models import (
    ALL_MODELS, FAMILIES, Model, model_for, model_named, ModelError, modes, SUPPORTED,
    unsupported_reason, X_MODELS)
from dxl_servo_driver.models import pro_legacy
from dxl_servo_driver.models.names import OTHER_MODELS
import pytest
from sdk_model_files import listed_models, needs_sdk, SDK, SDK_ALIASES, SDK_NAMES, sdk_rows, snake

OTHERS = tuple(model for model in ALL_MODELS if model not in X_MODELS)
# Protocol 1.0 models: no SDK model file (dynamixel-sdk 4.1 ships 2.0 tables only); they are
# checked against dynamixel-workbench and the e-manual in test_protocol1_models.py.
PROTOCOL1_NUMBERS = frozenset(model.number for model in ALL_MODELS if model.protocol == 1.0)
# The PRO on its original firmware and the first RH-P12-RN: no SDK model file either; checked
# against dynamixel-workbench and the e-manual in test_pro_models.py.
NO_SDK_FILE = PROTOCOL1_NUMBERS | frozenset(model.number for model in pro_legacy.MODELS)


# Items a table has beyond its model file, by family, each from the e-manual.
EXTRAS: dict[str, set[str]] = {
    'MX(2.0)': set(),
    'P': set(),
    'PRO(A)': set(),
    # The e-manual's External Port Data 1..4 (600..606); the model file stops at the modes.
    'RH-P12-RN': {f'external_port_data_{n}' for n in (1, 2, 3, 4)},
    'Y': set(),
    'XL-320': set(),
}


def _label(model: Model) -> str:
    return f'{model.number}-{model.name}'


def _type_info(path: pathlib.Path) -> dict[str, float]:
    lines = path.read_text(encoding='utf-8').splitlines()
    info = {}
    for line in lines[lines.index('[type info]') + 2:]:
        if not line.strip():
            break
        name, value = line.split('\t')[:2]
        info[name] = float(value)
    return info


def _our_name(model: Model, sdk_name: str) -> str:
    if model.family != 'Y' and sdk_name in SDK_NAMES:
        return SDK_NAMES[sdk_name]
    return snake(sdk_name)


every_other = pytest.mark.parametrize('model', OTHERS, ids=_label)


@needs_sdk
@every_other
def test_every_model_file_row_is_in_the_table(model: Model) -> None:
    assert SDK is not None
    if model.number in NO_SDK_FILE:
        pytest.skip('no SDK model file (test_protocol1_models.py, test_pro_models.py)')
    path = SDK / listed_models()[model.number]
    seen = set()
    for address, size, sdk_name in sdk_rows(path):
        if sdk_name in SDK_ALIASES:
            ours = model.by_address(address)
            assert ours.name.startswith(SDK_ALIASES[sdk_name]), (sdk_name, ours)
        else:
            ours = model.item(_our_name(model, sdk_name))
            assert ours.address == address, (sdk_name, ours)
        assert ours.size == size, (sdk_name, ours)
        seen.add(ours.name)
    extras = {item.name for item in model.items} - seen
    unexplained = {name for name in extras
                   if name not in EXTRAS[model.family] and not name.startswith('indirect_')}
    assert not unexplained, f'{model.label}: items the model file lacks: {unexplained}'


@needs_sdk
@every_other
def test_position_and_velocity_units_agree_with_the_model_file(model: Model) -> None:
    assert SDK is not None
    if model.number in NO_SDK_FILE:
        pytest.skip('no SDK model file (test_protocol1_models.py, test_pro_models.py)')
    path = SDK / listed_models()[model.number]
    info = _type_info(path)
    if model.family in ('XL-320', 'RH-P12-RN'):
        pytest.skip('the model file type info is not per turn here (see the module)')
    per_rad = (info['value_of_max_radian_position'] - info['value_of_zero_radian_position']) \
        / info['max_radian']
    # Within a pulse: the X-style files give 4095 (not 4096) at +pi.
    assert model.pulses_per_rev == pytest.approx(per_rad * 2 * math.pi, rel=1e-3)
    assert model.position_zero_raw == info['value_of_zero_radian_position']
    for line in path.read_text(encoding='utf-8').splitlines():
        if line.startswith('Present Velocity\t'):
            rad_s = float(line.split('\t')[1])
            assert model.velocity_unit_rpm * 2 * math.pi / 60 == pytest.approx(rad_s, rel=1e-3)


@needs_sdk
def test_the_sdk_lists_every_supported_number_but_one() -> None:
    listed = listed_models()
    # XW430-T200 and XM335-T323: only the e-manual numbers them; Protocol 1.0 and the original
    # PRO firmware: no SDK file at all.
    assert set(SUPPORTED) - set(listed) == {1280, 1710} | NO_SDK_FILE
    assert all(number in SUPPORTED or number in OTHER_MODELS for number in listed)


@every_other
def test_items_are_sorted_disjoint_and_well_formed(model: Model) -> None:
    names = [item.name for item in model.items]
    assert len(names) == len(set(names))
    assert [item.address for item in model.items] == sorted(item.address for item in model.items)
    for item, following in zip(model.items, model.items[1:]):
        assert item.address + item.size <= following.address, (item.name, following.name)
    for item in model.items:
        assert re.fullmatch(r'[a-z][a-z0-9_]*', item.name), item.name
        assert item.size in (1, 2, 4) and item.access in ('R', 'RW')
        if model.family == 'Y':
            # Areas per item (test_y_models.py checks them): only RAM from eeprom_end on.
            assert item.area in ('eeprom', 'ram') and (
                item.address < model.eeprom_end or item.area == 'ram'), item.name
        else:
            assert item.area == ('eeprom' if item.address < model.eeprom_end else 'ram'), \
                item.name
        assert item.minimum <= item.initial <= item.maximum, item.name
        bits = 8 * item.size - (1 if item.signed else 0)
        low, high = (-(1 << bits), (1 << bits) - 1) if item.signed else (0, (1 << bits) - 1)
        if item.direction_bit:   # decoded: the magnitude below the bit, signed by it
            assert not item.signed and item.direction_bit < (1 << bits), item.name
            low, high = 1 - item.direction_bit, item.direction_bit - 1
        elif item.raw_zero:      # decoded: raw - raw_zero
            low, high = -item.raw_zero, (1 << bits) - 1 - item.raw_zero
        assert low <= item.minimum and item.maximum <= high, item.name
        for value in {item.minimum, item.initial, item.maximum}:
            assert item.decode(item.encode(value)) == value, item.name
        if item.limit is not None:
            assert model.has(item.limit), item.name
        assert model.lookup(item.address) is item and model.lookup(item.name) is item


@every_other
def test_modes_units_and_bauds(model: Model) -> None:
    assert model.modes and set(model.modes) <= set(modes.NAMES)
    # Every family holds a position; the gripper has no velocity mode.
    assert set(model.modes) & modes.POSITION_MODES
    assert len(set(model.modes.values())) == len(model.modes)
    if model.mode_register:
        register = model.item(model.mode_register)
        assert all(register.minimum <= value <= register.maximum
                   for value in model.modes.values())
        assert register.initial in model.modes.values()
    assert model.protocol in (1.0, 2.0)
    assert model.velocity_unit_rpm > 0 and model.pulses_per_rev > 0
    assert model.pwm_full_raw > 0 and model.voltage_unit_v > 0
    assert (model.current_unit_a is not None) == model.has('present_current')
    assert model.current_unit_a is None or model.current_unit_a > 0
    assert (model.load_unit_ratio is not None) == model.has('present_load')
    assert ('current' in model.modes) <= model.has('goal_current')
    for name in modes.NAMES:
        if name in model.modes:
            for register in modes.BY_NAME[name].slot:
                assert model.has(register), (name, register)
    baud = model.item('baud_rate_bus' if model.family == 'Y' else 'baud_rate')
    speeds = [model.bauds[value] for value in sorted(model.bauds)]
    if model.protocol == 1.0:
        # Any value v is 2,000,000 / (v + 1) bit/s (test_protocol1_models.py); the table
        # holds the e-manual's list, slower as the value grows.
        assert all(baud.minimum <= value <= baud.maximum for value in model.bauds)
        assert len(set(speeds)) == len(speeds)
    else:
        assert sorted(model.bauds) == list(range(baud.minimum, baud.maximum + 1))
        assert speeds == sorted(set(speeds))
    assert baud.initial in model.bauds
    assert all(bit & (bit - 1) == 0 and bit < 0x100 for bit in model.hardware_error_bits)
    # Protocol 1.0: the bits of the status packet's error byte (no register holds them).
    assert bool(model.hardware_error_bits) == (model.has('hardware_error_status')
                                               or model.protocol == 1.0)
    assert model.item('model_number').initial == model.number


@every_other
def test_indirect_entries_match_the_items(model: Model) -> None:
    addresses = [item for item in model.items if item.name.startswith('indirect_address_')]
    data = [item for item in model.items if item.name.startswith('indirect_data_')]
    assert len(model.indirect) == len(addresses) == len(data)
    for number, (address, datum) in enumerate(model.indirect, start=1):
        entry = model.item(f'indirect_address_{number}')
        target = model.item(f'indirect_data_{number}')
        assert (entry.address, entry.size, entry.initial) == (address, 2, datum)
        assert (target.address, target.size) == (datum, 1)
        # RAM only, except on the Y whose entries may point anywhere in the table (0..919).
        assert entry.minimum == (0 if model.family == 'Y' else model.eeprom_end)
        assert entry.maximum >= model.table_end - 1


@every_other
def test_physics_is_usable(model: Model) -> None:
    physics = model.physics
    voltages = [point.voltage_v for point in physics.points]
    assert voltages == sorted(set(voltages))
    assert any(math.isclose(v, physics.nominal_voltage_v) for v in voltages)
    # The direct-drive Y (-M001, -B001) have no gear: 1.
    assert physics.gear_ratio >= 1 and physics.source
    assert model.torque_constant_nm_per_a > 0 and model.stall_torque_nm > 0
    for point in physics.points:
        assert point.stall_current_a > 0 and point.no_load_speed_rpm > 0
    low = model.item('min_voltage_limit')
    high = model.item('max_voltage_limit')
    nominal = physics.nominal_voltage_v / model.voltage_limit_unit_v
    assert low.minimum <= nominal <= high.maximum


def test_families_are_named_in_refusals() -> None:
    for number in OTHER_MODELS:
        reason = unsupported_reason(number)
        assert OTHER_MODELS[number][0] in reason
        assert all(family in reason for family in FAMILIES)
        with pytest.raises(ModelError):
            model_for(number)
    assert not set(OTHER_MODELS) & set(SUPPORTED)


# --- per family --------------------------------------------------------------------------


def test_mx_2_0() -> None:
    mx28, mx64, mx106 = model_for(30), model_for(311), model_for(321)
    assert set(mx28.modes) == {'velocity', 'position', 'extended_position', 'pwm'}
    assert mx28.has('present_load') and not mx28.has('goal_current')
    assert mx64.current_unit_a == pytest.approx(3.36e-3) == mx106.current_unit_a
    assert mx64.modes == modes.numbers(*modes.NAMES) == mx106.modes
    assert mx64.item('current_limit').maximum == 1941
    assert mx106.item('current_limit').maximum == 2047
    assert mx106.item('drive_mode').maximum == 7 and mx64.item('drive_mode').maximum == 5
    for model in (mx28, mx64, mx106):
        assert model.has('acceleration_limit')
        assert not model.has('startup_configuration') and not model.has('backup_ready')
        assert model.fast_sync_read_firmware is None and model.indirect[28] == (578, 634)
    assert model_named('mx-28(2.0)') is mx28


def test_p_pro_a_and_the_gripper() -> None:
    ph54 = model_for(2020)
    assert ph54.eeprom_end == 512 and ph54.item('torque_enable').address == 512
    assert ph54.item('indirect_address_1').area == 'eeprom'
    assert ph54.item('indirect_address_128').address == 422 and len(ph54.indirect) == 128
    assert ph54.item('indirect_address_1').minimum == 512
    assert ph54.pulses_per_rev == 1_003_846 and ph54.position_zero_raw == 0
    assert ph54.velocity_unit_rpm == 0.01 and ph54.current_unit_a == 0.001
    assert ph54.pwm_full_raw == 2009 and max(ph54.bauds.values()) == 10_500_000
    assert set(ph54.modes) == {'current', 'velocity', 'position', 'extended_position', 'pwm'}
    assert model_for(2000).pulses_per_rev == 607_500
    assert model_for(2100).pulses_per_rev == 526_374
    for p_number, a_number in ((2000, 51201), (2010, 53769), (2020, 54025), (2100, 43289),
                               (2110, 46097), (2120, 46353)):
        p_model, a_model = model_for(p_number), model_for(a_number)
        lacking = {item.name for item in p_model.items} - {item.name for item in a_model.items}
        assert lacking == {'protocol_version', 'startup_configuration', 'backup_ready'}
        assert p_model.physics.points == a_model.physics.points
    gripper = model_for(35074)
    assert gripper.modes == {'current': 0, 'current_based_position': 5}
    assert not gripper.has('drive_mode') and gripper.item('operating_mode').initial == 5
    assert model_named('RH-P12-RN(A)') is gripper and model_named('ph54-200-s500-r') is ph54
