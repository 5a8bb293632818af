"""The XM430 manual's control table as data: addresses, sizes, areas, initial values, ranges."""

from typing import Union

from dxl_servo_driver.models import Item, model_for, modes, xm430
from dxl_servo_driver.models.xm430 import (
    BAUD_RATES, HARDWARE_ERROR_BITS, ITEMS, MODEL_NUMBER, TABLE_SIZE)
import pytest

MANUAL = model_for(xm430.MODEL_NUMBER)   # model 1030: the manual's items and the e-manual's
BY_NAME = {item.name: item for item in ITEMS}
BY_ADDRESS = {item.address: item for item in ITEMS}


def lookup(key: Union[str, int]) -> Item:
    """Return the manual's item with this name or address (KeyError as the model's)."""
    MANUAL.lookup(key)   # the model says why a key is wrong
    return BY_NAME[key] if isinstance(key, str) else BY_ADDRESS[key]


# (name, address, size, access, initial) transcribed from the manual's table
MANUAL_ROWS = [
    ('model_number', 0, 2, 'R', 1030), ('id', 7, 1, 'RW', 1), ('baud_rate', 8, 1, 'RW', 1),
    ('return_delay_time', 9, 1, 'RW', 250), ('operating_mode', 11, 1, 'RW', 3),
    ('protocol_version', 13, 1, 'RW', 2), ('homing_offset', 20, 4, 'RW', 0),
    ('moving_threshold', 24, 4, 'RW', 10), ('temperature_limit', 31, 1, 'RW', 80),
    ('max_voltage_limit', 32, 2, 'RW', 160), ('min_voltage_limit', 34, 2, 'RW', 95),
    ('pwm_limit', 36, 2, 'RW', 885), ('current_limit', 38, 2, 'RW', 1193),
    ('acceleration_limit', 40, 4, 'RW', 32767), ('velocity_limit', 44, 4, 'RW', 480),
    ('max_position_limit', 48, 4, 'RW', 4095), ('min_position_limit', 52, 4, 'RW', 0),
    ('shutdown', 63, 1, 'RW', 52), ('torque_enable', 64, 1, 'RW', 0), ('led', 65, 1, 'RW', 0),
    ('status_return_level', 68, 1, 'RW', 2), ('registered_instruction', 69, 1, 'R', 0),
    ('hardware_error_status', 70, 1, 'R', 0), ('velocity_i_gain', 76, 2, 'RW', 1920),
    ('velocity_p_gain', 78, 2, 'RW', 50), ('position_d_gain', 80, 2, 'RW', 0),
    ('position_i_gain', 82, 2, 'RW', 0), ('position_p_gain', 84, 2, 'RW', 800),
    ('feedforward_2nd_gain', 88, 2, 'RW', 0), ('feedforward_1st_gain', 90, 2, 'RW', 0),
    ('profile_acceleration', 108, 4, 'RW', 0), ('profile_velocity', 112, 4, 'RW', 0),
    ('moving', 122, 1, 'R', 0), ('moving_status', 123, 1, 'R', 0),
    ('indirect_address_1', 168, 2, 'RW', 224), ('indirect_address_28', 222, 2, 'RW', 251),
    ('indirect_data_1', 224, 1, 'RW', 0), ('indirect_data_28', 251, 1, 'RW', 0),
    ('indirect_address_29', 578, 2, 'RW', 634), ('indirect_address_56', 632, 2, 'RW', 661),
    ('indirect_data_29', 634, 1, 'RW', 0), ('indirect_data_56', 661, 1, 'RW', 0),
]
# (name, address, size) of items whose initial value the manual gives as '-'
MANUAL_DASH_ROWS = [
    ('model_information', 2, 4), ('firmware_version', 6, 1), ('goal_pwm', 100, 2),
    ('goal_current', 102, 2), ('goal_velocity', 104, 4), ('goal_position', 116, 4),
    ('realtime_tick', 120, 2), ('present_pwm', 124, 2), ('present_current', 126, 2),
    ('present_velocity', 128, 4), ('present_position', 132, 4), ('velocity_trajectory', 136, 4),
    ('position_trajectory', 140, 4), ('present_input_voltage', 144, 2),
    ('present_temperature', 146, 1),
]


@pytest.mark.parametrize('name,address,size,access,initial', MANUAL_ROWS)
def test_manual_rows(name: str, address: int, size: int, access: str, initial: int) -> None:
    item = lookup(name)
    expected = (address, size, access, initial)
    assert (item.address, item.size, item.access, item.initial) == expected
    assert item.area == ('eeprom' if address < 64 else 'ram')
    assert lookup(address) is item


@pytest.mark.parametrize('name,address,size', MANUAL_DASH_ROWS)
def test_manual_rows_without_initial(name: str, address: int, size: int) -> None:
    item = MANUAL.item(name)
    assert (item.address, item.size) == (address, size)
    assert item.minimum <= item.initial <= item.maximum


def test_items_cover_the_manual_and_do_not_overlap() -> None:
    assert len(ITEMS) == len(MANUAL_ROWS) - 8 + 56 * 2 + len(MANUAL_DASH_ROWS)
    assert [item.address for item in ITEMS] == sorted(item.address for item in ITEMS)
    for previous, item in zip(ITEMS, ITEMS[1:]):
        assert previous.address + previous.size <= item.address, (previous, item)
    assert ITEMS[-1].address + ITEMS[-1].size == TABLE_SIZE == 662
    assert len(BY_NAME) == len(BY_ADDRESS) == len(ITEMS)


def test_indirect_items() -> None:
    for number in range(1, 57):
        address = lookup(f'indirect_address_{number}')
        data = lookup(f'indirect_data_{number}')
        assert address.initial == data.address
        assert (address.minimum, address.maximum) == (64, 661)
        assert address.size == 2 and data.size == 1
    assert lookup('indirect_address_27').address == 220
    assert lookup('indirect_data_30').address == 635


def test_signedness_and_limits() -> None:
    signed = {item.name for item in ITEMS if item.signed}
    assert signed == {'homing_offset', 'goal_pwm', 'goal_current', 'goal_velocity',
                      'goal_position', 'present_pwm', 'present_current', 'present_velocity',
                      'present_position', 'velocity_trajectory', 'position_trajectory'}
    limits = {item.name: item.limit for item in ITEMS if item.limit}
    assert limits == {'goal_pwm': 'pwm_limit', 'goal_current': 'current_limit',
                      'goal_velocity': 'velocity_limit',
                      'profile_acceleration': 'acceleration_limit',
                      'profile_velocity': 'velocity_limit', 'goal_position': 'max_position_limit'}
    assert (MANUAL.item('homing_offset').minimum, MANUAL.item('homing_offset').maximum) == (
        -1_044_479, 1_044_479)
    assert MANUAL.item('return_delay_time').maximum == 254
    voltage = MANUAL.item('max_voltage_limit')
    assert (voltage.minimum, voltage.maximum) == (95, 160)


def test_lookup_errors_are_clear() -> None:
    with pytest.raises(KeyError, match='no control-table item named'):
        lookup('goal_positon')
    with pytest.raises(KeyError, match='address 1$|address 1\\b'):
        lookup(1)   # inside model_number


def test_constants() -> None:
    assert MODEL_NUMBER == 1030
    assert BAUD_RATES == {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000,
                          5: 3_000_000, 6: 4_000_000, 7: 4_500_000}
    assert modes.numbers(*modes.NAMES) == {
        'current': 0, 'velocity': 1, 'position': 3, 'extended_position': 4,
        'current_based_position': 5, 'pwm': 16}
    assert sorted(HARDWARE_ERROR_BITS) == [0x01, 0x04, 0x08, 0x10, 0x20]


def test_decode_hardware_errors() -> None:
    assert MANUAL.decode_hardware_errors(0) == []
    assert MANUAL.decode_hardware_errors(0x25) == ['input_voltage', 'overheating', 'overload']
    assert MANUAL.decode_hardware_errors(0x80 | 0x08) == ['motor_encoder']
