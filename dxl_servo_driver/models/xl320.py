"""
The XL-320 (model 350): a Protocol 2.0 servo with a control table of its own, as data.

Its table is the Protocol 1.0 one moved a little (one-byte EEPROM limits, Control Mode at 11,
Hardware Error Status at 50) and nothing of the X's: no indirect addresses, no Realtime Tick,
no profiles, no homing offset, no PWM nor current registers. Positions count 1,024 steps over
300 degrees (zero at 512, the middle of the range); speeds 0.111 rpm; Present Load 0.1 % of the
maximum torque. Present Speed, Present Load and Moving Speed carry their sign as bit 10, the
direction (set: CW, negative here); their minimum/maximum are the decoded values.

Items keep the e-manual's names in snake_case; Model.roles maps the XM430 manual's names the
driver asks for onto them:

- operating_mode -> control_mode (1 wheel, 2 joint: the modes velocity and position)
- goal_velocity -> moving_speed; present_velocity -> present_speed
- present_input_voltage -> present_voltage
- min_position_limit -> cw_angle_limit; max_position_limit -> ccw_angle_limit (both bound
  Goal Position in joint mode, as the X's limits do in position mode)

Left out: pwm_limit -> max_torque. The X's PWM Limit bounds a Goal PWM the XL-320 lacks; Max
Torque (0..1,023 of 0.1 % of the maximum torque) only sets Torque Limit at power-on, the
nearest notion but not the same register role. pwm_full_raw is 1,023 on that torque-limit scale
since the servo has no PWM register at all. acceleration_unit_rpm2 stays the default: there is no
profile acceleration. homing_offset, current_limit, velocity_limit: no such registers.

Caveats from the e-manual: in wheel mode Moving Speed and Present Speed count 0.1 % of the
output, not 0.111 rpm (1,023 is full output, about the 114 rpm no-load speed, so the two scales
agree only without load); Moving Speed 0 in joint mode means no speed control (full speed).

Sources: ROBOTIS e-manual XL-320 control table (docs/en/dxl/x/xl320.md): addresses, sizes,
initial values, ranges, Shutdown bits, baud table, datasheet; dynamixel-sdk's xl320.model and
dynamixel-workbench's dynamixel_item.cpp (XL320) for the cross-check of addresses and sizes.
Where they disagree: the workbench puts Torque Limit at 34, the e-manual and the SDK at 35 (35
kept). The SDK file's type info (zero at 2,048 of 4,095 over 2 pi) is not this servo's; the
e-manual's 1,024 steps over 300 degrees with zero at 512 are kept. Hardware Error Status holds
the Shutdown bits (e-manual: 'alarm shutdown error value'): bit 0 overload, 1 overheating, 2
input voltage; the page's voltage-limit text names 0x10 for the input voltage, a copy of another
family's text that its own Shutdown table contradicts.
"""

from dxl_servo_driver.models.base import datasheet, Item, Model
from dxl_servo_driver.models.layout import ItemMaker

__all__ = ['MODEL', 'MODELS']

FAMILY = 'XL-320'
NUMBER = 350
EEPROM_END = 24            # Torque Enable, the first RAM item
DIRECTION = 1024           # bit 10 of Moving Speed, Present Speed, Present Load
MAGNITUDE = DIRECTION - 1
# Baud Rate register value -> bit/s (e-manual XL-320).
BAUD_RATES: dict[int, int] = {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000}
# Hardware Error Status (50) and Shutdown (18) bits (e-manual XL-320, Shutdown).
HARDWARE_ERROR_BITS: dict[int, str] = {0x01: 'overload', 0x02: 'overheating',
                                       0x04: 'input_voltage'}
ROLES: dict[str, str] = {
    'operating_mode': 'control_mode', 'goal_velocity': 'moving_speed',
    'present_velocity': 'present_speed', 'present_input_voltage': 'present_voltage',
    'min_position_limit': 'cw_angle_limit', 'max_position_limit': 'ccw_angle_limit',
}


_item = ItemMaker(eeprom_end=EEPROM_END, direction_bit=DIRECTION)


def _items() -> tuple[Item, ...]:
    # '-' initial values of the e-manual: the simulator's power-on state (goal at rest,
    # 7.4 V, 25 degC); Torque Limit powers on at Max Torque.
    return (
        _item('model_number', 0, 2, 'R', NUMBER, 0, 0xFFFF, description='Model Number'),
        _item('firmware_version', 2, 1, 'R', 0, 0, 0xFF, description='Firmware Version'),
        _item('id', 3, 1, 'RW', 1, 0, 252, description='DYNAMIXEL ID (254 is broadcast)'),
        _item('baud_rate', 4, 1, 'RW', 3, 0, 3, description='Communication Speed'),
        _item('return_delay_time', 5, 1, 'RW', 250, 0, 254, unit='2 us',
              description='Response Delay Time'),
        _item('cw_angle_limit', 6, 2, 'RW', 0, 0, 1023, unit='pulse',
              description='Clockwise Angle Limit (Goal Position minimum)'),
        _item('ccw_angle_limit', 8, 2, 'RW', 1023, 0, 1023, unit='pulse',
              description='Counter-Clockwise Angle Limit (Goal Position maximum)'),
        _item('control_mode', 11, 1, 'RW', 2, 1, 2,
              description='Control Mode (1 wheel, 2 joint)'),
        _item('temperature_limit', 12, 1, 'RW', 65, 0, 150, unit='degC',
              description='Maximum Internal Temperature Limit'),
        _item('min_voltage_limit', 13, 1, 'RW', 60, 50, 250, unit='0.1 V',
              description='Minimum Input Voltage Limit'),
        _item('max_voltage_limit', 14, 1, 'RW', 90, 50, 250, unit='0.1 V',
              description='Maximum Input Voltage Limit'),
        _item('max_torque', 15, 2, 'RW', 1023, 0, 1023, unit='0.1 %',
              description='Maximum Torque (Torque Limit at power-on)'),
        _item('status_return_level', 17, 1, 'RW', 2, 0, 2,
              description='Select Types of Status Return'),
        _item('shutdown', 18, 1, 'RW', 3, 0, 7,
              description='Shutdown conditions (bit 0 overload, 1 overheating, 2 input voltage)'),
        _item('torque_enable', 24, 1, 'RW', 0, 0, 1, description='Motor Torque On/Off'),
        _item('led', 25, 1, 'RW', 0, 0, 7,
              description='LED colour (bit 0 red, 1 green, 2 blue)'),
        _item('d_gain', 27, 1, 'RW', 0, 0, 254, description='Derivative Gain'),
        _item('i_gain', 28, 1, 'RW', 0, 0, 254, description='Integral Gain'),
        _item('p_gain', 29, 1, 'RW', 32, 0, 254, description='Proportional Gain'),
        _item('goal_position', 30, 2, 'RW', 0, 0, 1023, unit='pulse',
              limit='ccw_angle_limit', description='Desired Position (joint mode)'),
        # Joint mode: 0..1,023 of 0.111 rpm (0: no speed control); wheel mode: +-1,023 of
        # 0.1 % of the output, bit 10 the direction.
        _item('moving_speed', 32, 2, 'RW', 0, -MAGNITUDE, MAGNITUDE, unit='0.111 rpm',
              direction=True, description='Moving Speed (bit 10: CW)'),
        _item('torque_limit', 35, 2, 'RW', 1023, 0, 1023, unit='0.1 %',
              description='Torque Limit (0 after an alarm shutdown)'),
        _item('present_position', 37, 2, 'R', 0, 0, 1023, unit='pulse',
              description='Present Position'),
        _item('present_speed', 39, 2, 'R', 0, -MAGNITUDE, MAGNITUDE, unit='0.111 rpm',
              direction=True, description='Present Speed (bit 10: CW)'),
        _item('present_load', 41, 2, 'R', 0, -MAGNITUDE, MAGNITUDE, unit='0.1 %',
              direction=True, description='Present Load (bit 10: CW)'),
        _item('present_voltage', 45, 1, 'R', 74, 0, 0xFF, unit='0.1 V',
              description='Present Voltage'),
        _item('present_temperature', 46, 1, 'R', 25, 0, 0xFF, unit='degC',
              description='Present Temperature'),
        _item('registered_instruction', 47, 1, 'R', 0, 0, 1,
              description='If Instruction is registered'),
        _item('moving', 49, 1, 'R', 0, 0, 1, description='Movement Status'),
        _item('hardware_error_status', 50, 1, 'R', 0, 0, 7,
              description='Hardware Error Status (the Shutdown bits)'),
        _item('punch', 51, 2, 'RW', 32, 0, 1023, description='Minimum Current Threshold'),
    )


MODEL = Model(
    number=NUMBER, name='XL-320', family=FAMILY, items=_items(),
    modes={'velocity': 1, 'position': 2}, bauds=dict(BAUD_RATES), current_unit_a=None,
    load_unit_ratio=0.001, velocity_unit_rpm=0.111, pulses_per_rev=1024 * 360 / 300,
    position_zero_raw=512, pwm_full_raw=1023, voltage_unit_v=0.1, indirect=(),
    hardware_error_bits=dict(HARDWARE_ERROR_BITS),
    physics=datasheet(238.0, 7.4, ((7.4, 0.39, 1.1, 114),),
                      'ROBOTIS e-manual XL-320 specifications (one voltage published)'),
    fast_sync_read_firmware=None, roles=dict(ROLES), extended_position_limit=1023,
    homing_position_mode_limit=None, protocol=2.0, mode_register='control_mode',
    eeprom_end=EEPROM_END)
MODELS: tuple[Model, ...] = (MODEL,)
