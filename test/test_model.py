"""Unit conversions (raw <-> SI round trips) and the packed state block."""

import math

from dxl_servo_driver import control_table as ct
from dxl_servo_driver import model
from hypothesis import given, strategies as st


@given(st.integers(min_value=-ct.EXTENDED_POSITION_LIMIT, max_value=ct.EXTENDED_POSITION_LIMIT))
def test_position_round_trip_from_raw(raw: int) -> None:
    assert model.position_from_rad(model.position_to_rad(raw)) == raw


@given(st.floats(min_value=-1600.0, max_value=1600.0, allow_nan=False))
def test_position_round_trip_from_rad(rad: float) -> None:
    back = model.position_to_rad(model.position_from_rad(rad))
    assert abs(back - rad) <= model.RAD_PER_PULSE / 2 + 1e-12


@given(st.integers(min_value=-1023, max_value=1023))
def test_velocity_round_trip(raw: int) -> None:
    assert model.velocity_from_rad_s(model.velocity_to_rad_s(raw)) == raw


@given(st.integers(min_value=-1193, max_value=1193))
def test_current_round_trip(raw: int) -> None:
    assert model.current_from_a(model.current_to_a(raw)) == raw


@given(st.integers(min_value=-885, max_value=885))
def test_pwm_round_trip(raw: int) -> None:
    assert model.pwm_from_ratio(model.pwm_to_ratio(raw)) == raw


@given(st.integers(min_value=0, max_value=300))
def test_voltage_round_trip(raw: int) -> None:
    assert model.voltage_from_v(model.voltage_to_v(raw)) == raw


def test_units_match_the_seed() -> None:
    assert model.position_to_rad(2048) == 0.0
    assert math.isclose(model.position_to_rad(2048 + 4096), 2 * math.pi)
    assert math.isclose(model.position_to_rad(0), -math.pi)
    # 0.229 rpm per unit
    assert math.isclose(model.velocity_to_rad_s(1), 0.229 * 2 * math.pi / 60)
    assert math.isclose(model.current_to_a(1000), 2.69)
    assert model.pwm_to_ratio(885) == 1.0
    assert math.isclose(model.voltage_to_v(120), 12.0)
    assert math.isclose(model.DEFAULT_TORQUE_CONSTANT_NM_PER_A * 2.3, 4.1)


def test_state_block_maps_every_byte_of_its_registers() -> None:
    block = model.STATE_BLOCK
    targets = block.indirect_map()
    assert len(targets) == block.size
    expected = []
    for name in block.names:
        item = ct.BY_NAME[name]
        expected.extend(range(item.address, item.address + item.size))
    assert targets == expected
    # Indirect addresses may only point at RAM (the seed: 64..661).
    assert all(64 <= address <= 661 for address in targets)
    assert block.read_address == 224
    assert block.indirect_map_address() == 168
    assert block.size <= 28    # stays within indirect data 1..28


def test_state_block_decodes_signed_values() -> None:
    block = model.STATE_BLOCK
    raw = bytearray(block.size)
    values = {'present_position': -5000, 'present_velocity': -7, 'present_current': -300,
              'present_pwm': -885, 'present_input_voltage': 121, 'present_temperature': 41,
              'moving': 1, 'moving_status': 0x33, 'hardware_error_status': 0x24,
              'torque_enable': 1, 'status_return_level': 2, 'realtime_tick': 32767}
    for field in block.fields:
        item = ct.BY_NAME[field.name]
        raw[field.offset:field.offset + field.size] = values[field.name].to_bytes(
            field.size, 'little', signed=item.signed)
    decoded = dict(zip(block.names, block.decode(bytes(raw))))
    assert decoded == values
    assert not block.restarted(block.decode(bytes(raw)))
    assert block.restarted(block.decode(bytes(block.size)))


def test_bus_budget_matches_the_spec_formula() -> None:
    # SPEC section 5: sync read of 10 bytes = (14 + N) + 21 N, sync write of 4 bytes = 14 + 5 N.
    for n in (1, 6, 12, 24):
        budget = model.bus_budget(n, 4_000_000, read_length=10, write_length=4)
        assert budget.bytes_per_cycle == (14 + n) + 21 * n + 14 + 5 * n
        assert math.isclose(budget.wire_time_s, budget.bytes_per_cycle * 10 / 4_000_000)
    slow = model.bus_budget(3, 57600, return_delay_time_raw=250, latency_timer_s=0.016)
    assert math.isclose(slow.return_delay_s, 3 * 500e-6)
    assert slow.rate_limit_hz < 50.0


def test_mode_commands_cover_every_mode() -> None:
    assert set(model.MODE_COMMANDS) == set(ct.OPERATING_MODES)
    for kinds in model.MODE_COMMANDS.values():
        assert kinds <= set(model.COMMAND_KINDS)
