"""Unit conversions (raw <-> SI round trips) per model and the packed state block."""

import math

from dxl_servo_driver.driver import state_block
from dxl_servo_driver.models import ALL_MODELS, Model, model_for, modes, X_MODELS, xm430
from dxl_servo_driver.models.units import units_for
from hypothesis import given, strategies as st
import pytest

MANUAL = model_for(xm430.MODEL_NUMBER)   # the XM430 manual's table

XM430_UNITS = units_for(model_for(1030))


@given(st.integers(min_value=-xm430.EXTENDED_POSITION_LIMIT,
                   max_value=xm430.EXTENDED_POSITION_LIMIT))
def test_position_round_trip_from_raw(raw: int) -> None:
    assert XM430_UNITS.position_from_rad(XM430_UNITS.position_to_rad(raw)) == raw


@given(st.floats(min_value=-1600.0, max_value=1600.0, allow_nan=False))
def test_position_round_trip_from_rad(rad: float) -> None:
    back = XM430_UNITS.position_to_rad(XM430_UNITS.position_from_rad(rad))
    assert abs(back - rad) <= XM430_UNITS.rad_per_pulse / 2 + 1e-12


@given(st.integers(min_value=-2047, max_value=2047))
def test_velocity_round_trip(raw: int) -> None:
    assert XM430_UNITS.velocity_from_rad_s(XM430_UNITS.velocity_to_rad_s(raw)) == raw


@pytest.mark.parametrize('number', [1030, 1040, 1200])
@given(raw=st.integers(min_value=-2352, max_value=2352))
def test_current_round_trip(number: int, raw: int) -> None:
    units = units_for(model_for(number))
    assert units.current_from_a(units.current_to_a(raw)) == raw


@given(st.integers(min_value=-885, max_value=885))
def test_pwm_round_trip(raw: int) -> None:
    assert XM430_UNITS.pwm_from_ratio(XM430_UNITS.pwm_to_ratio(raw)) == raw


def test_units_match_the_xm430_manual() -> None:
    assert XM430_UNITS.position_to_rad(2048) == 0.0
    assert math.isclose(XM430_UNITS.position_to_rad(2048 + 4096), 2 * math.pi)
    assert math.isclose(XM430_UNITS.position_to_rad(0), -math.pi)
    # 0.229 rpm per unit
    assert math.isclose(XM430_UNITS.velocity_to_rad_s(1), 0.229 * 2 * math.pi / 60)
    assert math.isclose(XM430_UNITS.current_to_a(1000), 2.69)
    assert XM430_UNITS.pwm_to_ratio(885) == 1.0
    assert math.isclose(XM430_UNITS.voltage_to_v(120), 12.0)
    # The XM430 manual's datasheet: 4.1 N.m at 2.3 A, for 1030 and 1020 alike (it wins for 1030).
    assert math.isclose(XM430_UNITS.torque_constant_nm_per_a * 2.3, 4.1)
    assert math.isclose(XM430_UNITS.effort_to_nm(1000), 2.69 * 4.1 / 2.3)
    xm430_w210 = units_for(model_for(1020))
    assert xm430_w210.torque_constant_nm_per_a == XM430_UNITS.torque_constant_nm_per_a


def test_units_differ_where_the_models_do() -> None:
    # XH430-V: 1.34 mA per count; X330: 1 mA.
    assert math.isclose(units_for(model_for(1040)).current_to_a(1000), 1.34)
    assert math.isclose(units_for(model_for(1200)).current_to_a(1000), 1.0)
    # XL330-M288: 0.52 N.m at 1.47 A (5 V): effort of 1000 mA.
    assert math.isclose(units_for(model_for(1200)).effort_to_nm(1000), 0.52 / 1.47)
    # A torque constant from the file wins over the datasheet's.
    assert math.isclose(units_for(model_for(1200), 0.5).effort_to_nm(1000), 0.5)


def test_load_models_publish_effort_from_present_load() -> None:
    xl430 = units_for(model_for(1060))
    assert xl430.effort_register == 'present_load'
    # Present Load is 0.1 % of the stall torque (1.4 N.m at 11.1 V): 500 is half of it.
    assert math.isclose(xl430.effort_to_nm(500), 0.7)
    assert math.isnan(xl430.current_to_a(100))
    with pytest.raises(ValueError, match='senses no current'):
        xl430.current_from_a(0.1)
    assert 'current' not in xl430.kinds
    assert set(xl430.kinds) == {'position', 'velocity', 'pwm'}
    assert set(XM430_UNITS.kinds) == {'position', 'velocity', 'current', 'pwm'}


@pytest.mark.parametrize('table', ALL_MODELS, ids=lambda m: f'{m.name}-fw{m.min_firmware}')
def test_state_block_maps_every_byte_of_its_registers(table: Model) -> None:
    effort = 'present_current' if table.has('present_current') else 'present_load'
    block = state_block.state_block(table, effort)
    if block.direct:
        _check_direct_block(table, block)
        return
    targets = block.indirect_map()
    assert len(targets) == block.size
    expected = []
    for name in block.names:
        if not block.has(name):
            continue   # compact (the X330's PWM) or a register the table lacks (the Y's Moving)
        item = table.item(block.register(name))
        expected.extend(range(item.address, item.address + item.size))
    assert targets == expected
    # Only a table with fewer than 22 indirect entries (X330 before firmware 53) drops PWM.
    assert block.compact == (len(table.indirect) < 22)
    assert block.has_pwm == (not block.compact and table.has('present_pwm'))
    # Indirect addresses point at RAM items (the Y has some below 512), never the EEPROM.
    owners = {item.address + k: item for item in table.items for k in range(item.size)}
    assert all(owners[address].area == 'ram' for address in targets)
    assert (block.read_address, block.indirect_map_address()) == table.indirect[0][::-1]
    # The block's indirect data bytes are consecutive: one read fetches them.
    data = [pair[1] for pair in table.indirect[:block.size]]
    assert data == list(range(block.read_address, block.read_address + block.size))
    if table in X_MODELS:
        # The manual's table and every X since the X330 moved its block: 224; before: 208.
        old_x330 = table.family in ('XL330', 'XC330') and table.min_firmware == 0
        assert block.read_address == (208 if old_x330 else 224)
        assert block.indirect_map_address() == 168


def _check_direct_block(table: Model, block: state_block.StateBlock) -> None:
    """Check a table without indirect entries enough: one read of its registers, in place."""
    assert not table.indirect or len(table.indirect) < block.size
    assert state_block.goal_slot(table, block, next(iter(table.modes))) is None
    assert not block.has_canary and block.has_tick == table.has('realtime_tick')
    # One span from the first state register to the last, each field at its own offset.
    for field in block.fields:
        item = table.item(field.name)
        assert block.read_address + field.offset == item.address, field
        assert field.size == item.size
    last = max(table.item(field.name).address + field.size for field in block.fields)
    assert block.read_address + block.size == last
    # Decoding the span as the servo holds it gives each field's value (signs by direction bit).
    values = {field.name: -5 if table.item(field.name).direction_bit else 7
              for field in block.fields}
    data = bytearray(block.size)
    for field in block.fields:
        item = table.item(field.name)
        data[field.offset:field.offset + field.size] = item.encode(values[field.name])
    decoded = block.decode(bytes(data))
    for name in block.names:
        expected = values[block.register(name)] if block.has(name) else 0
        assert decoded[block.index[name]] == expected, name


def test_state_block_decodes_signed_values() -> None:
    block = state_block.state_block(model_for(1030), 'present_current')
    raw = bytearray(block.size)
    values = {'present_position': -5000, 'present_velocity': -7, 'present_current': -300,
              'present_pwm': -885, 'present_input_voltage': 121, 'present_temperature': 41,
              'moving': 1, 'moving_status': 0x33, 'hardware_error_status': 0x24,
              'torque_enable': 1, 'status_return_level': 2, 'realtime_tick': 32767}
    for field in block.fields:
        item = MANUAL.item(field.name)
        raw[field.offset:field.offset + field.size] = values[field.name].to_bytes(
            field.size, 'little', signed=item.signed)
    decoded = dict(zip((field.name for field in block.fields), block.decode(bytes(raw))))
    assert decoded == values
    assert not block.restarted(block.decode(bytes(raw)))
    assert block.restarted(block.decode(bytes(block.size)))
    # The shape the cycle decodes with is every block's.
    assert state_block.BLOCK_SHAPE.decode(bytes(raw)) == block.decode(bytes(raw))


def test_bus_budget_matches_the_spec_formula() -> None:
    # The benchmark's count (docs/performance.md, Benchmark): sync read of 10 bytes
    # = (14 + N) + 21 N, sync write of 4 bytes = 14 + 5 N.
    for n in (1, 6, 12, 24):
        budget = state_block.bus_budget(n, 4_000_000, read_length=10, write_length=4)
        assert budget.bytes_per_cycle == (14 + n) + 21 * n + 14 + 5 * n
        assert math.isclose(budget.wire_time_s, budget.bytes_per_cycle * 10 / 4_000_000)
    slow = state_block.bus_budget(3, 57600, return_delay_time_raw=250, latency_timer_s=0.016)
    assert math.isclose(slow.return_delay_s, 3 * 500e-6)
    assert slow.rate_limit_hz < 50.0


def test_the_mode_table_is_whole() -> None:
    # The XM430 manual's modes and register values.
    assert modes.numbers(*modes.NAMES) == {'current': 0, 'velocity': 1, 'position': 3,
                                           'extended_position': 4, 'current_based_position': 5,
                                           'pwm': 16}
    for mode in modes.MODES:
        assert mode.holding in mode.commands and set(mode.commands) <= set(modes.COMMAND_KINDS)
        assert mode.slot[0] == mode.holding_register   # what changes most often first
        assert {kind for _, kind in mode.joint_state} <= set(mode.commands)
        assert mode.position == (mode.holding == 'position')
    assert modes.POSITION_NUMBERS == {3, 4, 5}
    for table in ALL_MODELS:
        units = units_for(table)
        for mode in table.modes:
            # Every mode a model has is driven by commands it has.
            assert set(modes.BY_NAME[mode].commands) <= set(units.kinds), (table.name, mode)
