"""
The XM430 manual's control table as data (XM430-W210, model 1030; 1020 has the same table).

The base every X-series table is stated against (models.catalog states each family by its
differences from this one), and the authority for 1020 and 1030. Where the manual is garbled
the table follows its obvious intent; each such choice is commented at the item. Pure data.
"""

from dxl_servo_driver.models.base import Item
from dxl_servo_driver.models.layout import indirect_items, indirect_pairs, item

MODEL_NUMBER = 1030
# The models whose table is the manual's (the XM430-W350 and -W210), plus what the e-manual adds.
MODEL_NUMBERS = (1020, MODEL_NUMBER)
# The manual gives '-' for the firmware version; the simulator reports this value.
FIRMWARE_VERSION = 45
TABLE_SIZE = 662

INT32_MIN = -(1 << 31)
INT32_MAX = (1 << 31) - 1
EXTENDED_POSITION_LIMIT = 1_048_575  # +-256 rev, goal_position in modes 4 and 5
HOMING_OFFSET_LIMIT = 1_044_479
HOMING_OFFSET_POSITION_MODE_LIMIT = 1024  # mode 3 ignores offsets beyond this (manual note)

# Baud Rate register value -> bit/s.
BAUD_RATES: dict[int, int] = {
    0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000, 6: 4_000_000,
    7: 4_500_000,
}

# Hardware Error Status bit -> name (bits 1, 6 and 7 are unused).
HARDWARE_ERROR_BITS: dict[int, str] = {
    0x01: 'input_voltage', 0x04: 'overheating', 0x08: 'motor_encoder',
    0x10: 'electrical_shock', 0x20: 'overload',
}

# Indirect Address/Data 1..28 and 29..56: two banks.
# The Realtime Tick counts milliseconds 0..32767, then wraps.
TICK_PERIOD_MS = 32768

INDIRECT_PAIRS: tuple[tuple[int, int], ...] = indirect_pairs((168, 224, 28), (578, 634, 28))


def _build() -> tuple[Item, ...]:
    u8, u16, u32 = 0xFF, 0xFFFF, 0xFFFFFFFF
    items = [
        item('model_number', 0, 2, 'R', MODEL_NUMBER, 0, u16, description='Model Number'),
        # '-' in the manual: the simulator reports 0.
        item('model_information', 2, 4, 'R', 0, 0, u32, description='Model Information'),
        item('firmware_version', 6, 1, 'R', FIRMWARE_VERSION, 0, u8,
             description='Firmware Version'),
        item('id', 7, 1, 'RW', 1, 0, 252, description='Dynamixel ID (254 is broadcast)'),
        item('baud_rate', 8, 1, 'RW', 1, 0, 7, description='Communication Baud Rate'),
        item('return_delay_time', 9, 1, 'RW', 250, 0, 254, unit='2 us',
             description='Response Delay Time'),
        # Only the values of models.modes are valid; others are a data range error.
        item('operating_mode', 11, 1, 'RW', 3, 0, 16, description='Operating Mode'),
        item('protocol_version', 13, 1, 'RW', 2, 1, 2, description='Protocol Version'),
        item('homing_offset', 20, 4, 'RW', 0, -HOMING_OFFSET_LIMIT, HOMING_OFFSET_LIMIT,
             signed=True, unit='pulse', description='Home Position Offset'),
        # The manual copies the homing offset's range here; a velocity threshold is 0..1023 in
        # 0.229 rpm, as the velocity limit.
        item('moving_threshold', 24, 4, 'RW', 10, 0, 1023, unit='0.229 rpm',
             description='Velocity Threshold for Movement Detection'),
        item('temperature_limit', 31, 1, 'RW', 80, 0, 100, unit='degC',
             description='Maximum Internal Temperature Limit'),
        item('max_voltage_limit', 32, 2, 'RW', 160, 95, 160, unit='0.1 V',
             description='Maximum Voltage Limit'),
        item('min_voltage_limit', 34, 2, 'RW', 95, 95, 160, unit='0.1 V',
             description='Minimum Voltage Limit'),
        item('pwm_limit', 36, 2, 'RW', 885, 0, 885, unit='0.113 %',
             description='Maximum PWM Limit'),
        item('current_limit', 38, 2, 'RW', 1193, 0, 1193, unit='2.69 mA',
             description='Maximum Current Limit'),
        # The manual's '0.0036 rev/min2' is 0.229 rpm / 64 per ms, i.e. 214.577 rev/min^2.
        item('acceleration_limit', 40, 4, 'RW', 32767, 0, 32767, unit='214.577 rev/min^2',
             description='Maximum Acceleration Limit'),
        item('velocity_limit', 44, 4, 'RW', 480, 0, 1023, unit='0.229 rpm',
             description='Maximum Velocity Limit'),
        item('max_position_limit', 48, 4, 'RW', 4095, 0, 4095, unit='pulse',
             description='Maximum Position Limit'),
        item('min_position_limit', 52, 4, 'RW', 0, 0, 4095, unit='pulse',
             description='Minimum Position Limit'),
        # Bits 7, 6 and 1 are unused: stored but without effect.
        item('shutdown', 63, 1, 'RW', 0x34, 0, u8, description='Shutdown conditions'),
        item('torque_enable', 64, 1, 'RW', 0, 0, 1, description='Motor Torque On/Off'),
        item('led', 65, 1, 'RW', 0, 0, 1, description='Status LED On/Off'),
        item('status_return_level', 68, 1, 'RW', 2, 0, 2,
             description='Select Types of Status Return'),
        item('registered_instruction', 69, 1, 'R', 0, 0, 1,
             description='Check Reception of Instruction'),
        item('hardware_error_status', 70, 1, 'R', 0, 0, u8,
             description='Hardware Error Status'),
        # The manual's velocity I divisor '65563' is read as 65536.
        item('velocity_i_gain', 76, 2, 'RW', 1920, 0, 32767, unit='1/65536',
             description='I Gain of Velocity'),
        item('velocity_p_gain', 78, 2, 'RW', 50, 0, 32767, unit='1/128',
             description='P Gain of Velocity'),
        item('position_d_gain', 80, 2, 'RW', 0, 0, 32767, unit='1/16',
             description='D Gain of Position'),
        item('position_i_gain', 82, 2, 'RW', 0, 0, 32767, unit='1/65536',
             description='I Gain of Position'),
        item('position_p_gain', 84, 2, 'RW', 800, 0, 32767, unit='1/128',
             description='P Gain of Position'),
        item('feedforward_2nd_gain', 88, 2, 'RW', 0, 0, 32767, unit='1/4',
             description='2nd Gain of Feed-Forward'),
        item('feedforward_1st_gain', 90, 2, 'RW', 0, 0, 32767, unit='1/4',
             description='1st Gain of Feed-Forward'),
        # Dynamically limited items: the static range is the widest the limit register allows
        # (data range error beyond it), the limit register's value gives a data limit error.
        # Goal PWM / Goal Current power on at PWM Limit / Current Limit (the manual's '-').
        item('goal_pwm', 100, 2, 'RW', 885, -885, 885, signed=True, limit='pwm_limit',
             unit='0.113 %', description='Target PWM Value'),
        item('goal_current', 102, 2, 'RW', 1193, -1193, 1193, signed=True,
             limit='current_limit', unit='2.69 mA', description='Target Current Value'),
        item('goal_velocity', 104, 4, 'RW', 0, -1023, 1023, signed=True,
             limit='velocity_limit', unit='0.229 rpm', description='Target Velocity Value'),
        item('profile_acceleration', 108, 4, 'RW', 0, 0, 32767, limit='acceleration_limit',
             unit='214.577 rev/min^2', description='Acceleration Value of Profile'),
        item('profile_velocity', 112, 4, 'RW', 0, 0, 1023, limit='velocity_limit',
             unit='0.229 rpm', description='Velocity Value of Profile'),
        # Limited by min/max_position_limit in position mode (3) and by +-1,048,575 in modes 4
        # and 5; the '-' initial value is documented by the simulator (present position at boot).
        item('goal_position', 116, 4, 'RW', 0, INT32_MIN, INT32_MAX, signed=True,
             limit='max_position_limit', unit='pulse',
             description='Target Position Value (min/max_position_limit in mode 3)'),
        item('realtime_tick', 120, 2, 'R', 0, 0, 32767, unit='ms',
             description='Count Time in millisecond'),
        item('moving', 122, 1, 'R', 0, 0, 1, description='Movement Status'),
        item('moving_status', 123, 1, 'R', 0, 0, u8,
             description='Detailed Information of Movement Status'),
        item('present_pwm', 124, 2, 'R', 0, -885, 885, signed=True, unit='0.113 %',
             description='Current PWM Value'),
        item('present_current', 126, 2, 'R', 0, -32768, 32767, signed=True, unit='2.69 mA',
             description='Current Current Value'),
        item('present_velocity', 128, 4, 'R', 0, INT32_MIN, INT32_MAX, signed=True,
             unit='0.229 rpm', description='Current Velocity Value'),
        item('present_position', 132, 4, 'R', 0, INT32_MIN, INT32_MAX, signed=True,
             unit='pulse', description='Current Position Value'),
        item('velocity_trajectory', 136, 4, 'R', 0, INT32_MIN, INT32_MAX, signed=True,
             unit='0.229 rpm', description='Target Velocity Trajectory Generated by Profile'),
        item('position_trajectory', 140, 4, 'R', 0, INT32_MIN, INT32_MAX, signed=True,
             unit='pulse', description='Target Position Trajectory Generated by Profile'),
        item('present_input_voltage', 144, 2, 'R', 120, 0, u16, unit='0.1 V',
             description='Current Input Voltage'),
        # The manual's 'Present Temperature (144)' is address 146, as its table says.
        item('present_temperature', 146, 1, 'R', 25, 0, u8, unit='degC',
             description='Current Internal Temperature'),
    ]
    items += indirect_items(INDIRECT_PAIRS, TABLE_SIZE - 1)
    items.sort(key=lambda each: each.address)
    return tuple(items)


ITEMS: tuple[Item, ...] = _build()
