"""
The Protocol 1.0 models: AX, RX, EX-106+, DX-113/116/117, the MX on their 1.0 firmware: data.

One layout for all (one-byte addresses, EEPROM 0..23, RAM from Torque Enable at 24), each
family adding its own items: the MX its PID gains in place of the compliance margins and
slopes, Multi Turn Offset, Resolution Divider, Goal Acceleration and (firmware 40 on, 41 on the
MX-12W) Realtime Tick; the MX-64/106 Current, Torque Ctrl Mode Enable and Goal Torque; the
MX-106 and EX-106+ Drive Mode (dual joint); the EX-106+ Sensed Current. Items keep the e-manual's
names in snake_case; Model.roles maps the XM430 manual's names the driver asks for onto them:

- goal_velocity -> moving_speed, present_velocity -> present_speed (bit 10 the direction,
  set: CW, negative here; minimum/maximum are decoded values)
- present_input_voltage -> present_voltage; registered_instruction -> registered
- min_position_limit -> cw_angle_limit, max_position_limit -> ccw_angle_limit: Goal Position's
  bounds in joint mode, as the X's limits in position mode
- MX: homing_offset -> multi_turn_offset (added to Present Position like the X's Homing
  Offset, but only in multi-turn mode: homing_position_mode_limit 0 says position mode ignores
  any); profile_acceleration -> goal_acceleration (0: no limit, else 8.583 deg/s^2 per count,
  85.83 rev/min^2, the acceleration of the motion as the X's Profile Acceleration)
- MX-64/106: goal_current -> goal_torque (4.5 mA per count, bit 10 the direction) and
  present_current -> current (4.5 mA per count about 2,048, Item.raw_zero)

The names shutdown, temperature_limit and min/max_voltage_limit are the e-manual's already.
Left out: operating_mode (no register: the mode follows from the angle limits, both 0 wheel,
both 4,095 multi-turn on the MX, joint otherwise, and Torque Ctrl Mode Enable on the MX-64/106:
mode_register ''; the modes carry the X's numbers for their names, since no register holds
them); pwm_limit and goal_pwm (Max Torque and Torque Limit count 0.1 % of the maximum torque,
pwm_full_raw 1,023 is that scale, but there is no PWM register); profile_velocity (Moving Speed
is the joint-mode speed and the wheel-mode goal at once); velocity_limit, current_limit,
hardware_error_status (the errors come in the status packet's error byte:
hardware_error_bits are its bits, the ones Alarm LED and Shutdown select); the EX-106+'s Sensed
Current (10 mA per count about 512, but its page gives two contradictory signs).

Units: AX, RX, DX 1,024 steps over 300 degrees (zero 512); EX-106+ 4,096 over 250.92 degrees
(zero 2,048); MX 4,096 per turn (zero 2,048, Resolution Divider 1 assumed: another divides
every position). Speeds 0.111 rpm (AX, RX, EX, DX), 0.114 rpm (MX-28/64/106), 0.916 rpm
(MX-12W). In wheel mode the AX, RX, EX and DX count Moving Speed in 0.1 % of the output, not
rpm: the scales agree only without load. Load 0.1 %, voltage 0.1 V. Baud Rate: a value v is
2,000,000 / (v + 1) bit/s; bauds holds the e-manual's table with the rate each value really
gives (rounded down), plus 250..252 (2.25, 2.5, 3 Mbps) on the MX.

Instructions: no Protocol 1.0 model answers REBOOT (the e-manual's 1.0 instruction list and
dynamixel-sdk's 1.0 handler have none): reboot False. BULK_READ: the MX and the EX-106+ only.

Sources: ROBOTIS e-manual control tables and specifications of the AX-12A, AX-12W, AX-18A,
RX-10, RX-24F, RX-28, RX-64, EX-106+, DX-113, DX-116, DX-117, MX-12W, MX-28, MX-64 and MX-106
(docs/en/dxl/.., the Korean pages where the English ones lack an item), its Protocol 1.0 page
and its shared control-table texts (_includes/en/dxl/control_table_*.md); dynamixel-workbench's
dynamixel_item.cpp for the cross-check of addresses and sizes; ROBOTIS's DX-series user's
manual (2004) for the DX-116's motor. Where they disagree, the choice is commented at the figure.
"""

from dataclasses import replace

from dxl_servo_driver.models import modes
from dxl_servo_driver.models.base import datasheet, Item, Model, Physics
from dxl_servo_driver.models.layout import ItemMaker

__all__ = ['MODELS']

EEPROM_END = 24
DIRECTION = 1024           # bit 10 of Moving Speed, Present Speed, Present Load, Goal Torque
MAGNITUDE = DIRECTION - 1
MX_TURNS_LIMIT = 28_672    # e-manual: multi-turn Goal Position -28,672..28,672 (7 turns)
MX_OFFSET_LIMIT = 24_576   # e-manual: Multi Turn Offset -24,576..24,576
MX_CURRENT_ZERO = 2048     # e-manual: Current reads 2,048 with no current flowing
GOAL_ACCELERATION_RPM2 = 8.583 / 360.0 * 3600.0   # 8.583 deg/s^2 in rev/min^2
# The e-manual's Baud Rate table: each value v runs the servo at 2,000,000 / (v + 1) bit/s,
# and the table names the host speed each one serves, within the 3 % a UART tolerates (34 is
# 57,142.9 bit/s, 0.79 % from 57,600; 16 is 2.1 % from 115,200). A host opens its port at that
# speed, so that is the rate the catalogue gives; servo_rate() says what the servo runs at.
BAUD_RATES: dict[int, int] = {1: 1_000_000, 3: 500_000, 4: 400_000, 7: 250_000, 9: 200_000,
                              16: 115_200, 34: 57_600, 103: 19_200, 207: 9_600}


def servo_rate(value: int) -> float:
    """Return the bit rate a Protocol 1.0 servo runs at for a Baud Rate value below 250."""
    return 2_000_000 / (value + 1)


MX_BAUD_RATES: dict[int, int] = {**BAUD_RATES, 250: 2_250_000, 251: 2_500_000, 252: 3_000_000}
# The status packet's error byte (e-manual Protocol 1.0): what Alarm LED and Shutdown select.
ERROR_BITS: dict[int, str] = {
    0x01: 'input_voltage', 0x02: 'angle_limit', 0x04: 'overheating', 0x08: 'range',
    0x10: 'checksum', 0x20: 'overload', 0x40: 'instruction',
}
ROLES: dict[str, str] = {
    'goal_velocity': 'moving_speed', 'present_velocity': 'present_speed',
    'present_input_voltage': 'present_voltage', 'registered_instruction': 'registered',
    'min_position_limit': 'cw_angle_limit', 'max_position_limit': 'ccw_angle_limit',
}
MX_ROLES: dict[str, str] = {**ROLES, 'homing_offset': 'multi_turn_offset',
                            'profile_acceleration': 'goal_acceleration'}
MX_CURRENT_ROLES: dict[str, str] = {**MX_ROLES, 'goal_current': 'goal_torque',
                                    'present_current': 'current'}
JOINT_WHEEL = modes.numbers('velocity', 'position')
JOINT_WHEEL_TURNS = modes.numbers('velocity', 'position', 'extended_position')
WITH_TORQUE = modes.numbers('current', 'velocity', 'position', 'extended_position')


_item = ItemMaker(eeprom_end=EEPROM_END, direction_bit=DIRECTION)


def _common(number: int, *, bauds: tuple[int, int, int], steps: int, temperature: tuple[int, int],
            voltage: tuple[int, int, int, int], max_torque: int, speed: str, punch: int,
            volts: float, turns: bool = False) -> list[Item]:
    """
    Return the items every Protocol 1.0 table shares.

    bauds (initial, minimum, maximum); steps: positions per joint range (1,024 or 4,096);
    temperature (initial, maximum); voltage (min initial, max initial, lowest, highest) in
    0.1 V; speed the Moving/Present Speed unit; turns: the MX's signed multi-turn positions.
    """
    top = steps - 1
    low_v, high_v, lowest, highest = voltage
    goal = (-MX_TURNS_LIMIT, MX_TURNS_LIMIT) if turns else (0, top)
    present = (-32768, 32767) if turns else (0, 0xFFFF if steps == 4096 else top)
    # '-' initial values of the e-manual: the simulator's power-on state (at rest, nominal
    # voltage, 25 degC); Torque Limit powers on at Max Torque.
    return [
        _item('model_number', 0, 2, 'R', number, 0, 0xFFFF, description='Model Number'),
        _item('firmware_version', 2, 1, 'R', 0, 0, 0xFF, description='Firmware Version'),
        _item('id', 3, 1, 'RW', 1, 0, 253, description='DYNAMIXEL ID (254 is broadcast)'),
        _item('baud_rate', 4, 1, 'RW', *bauds,
              description='Communication Speed (2,000,000 / (value + 1) bit/s)'),
        _item('return_delay_time', 5, 1, 'RW', 250, 0, 254, unit='2 us',
              description='Response Delay Time'),
        _item('cw_angle_limit', 6, 2, 'RW', 0, 0, top, unit='pulse',
              description='Clockwise Angle Limit (Goal Position minimum; both 0: wheel mode)'),
        _item('ccw_angle_limit', 8, 2, 'RW', top, 0, top, unit='pulse',
              description='Counter-Clockwise Angle Limit (Goal Position maximum)'),
        _item('temperature_limit', 11, 1, 'RW', temperature[0], 0, temperature[1], unit='degC',
              description='Maximum Internal Temperature Limit'),
        _item('min_voltage_limit', 12, 1, 'RW', low_v, lowest, highest, unit='0.1 V',
              description='Minimum Input Voltage Limit'),
        _item('max_voltage_limit', 13, 1, 'RW', high_v, lowest, highest, unit='0.1 V',
              description='Maximum Input Voltage Limit'),
        _item('max_torque', 14, 2, 'RW', max_torque, 0, 1023, unit='0.1 %',
              description='Maximum Torque (Torque Limit at power-on)'),
        _item('status_return_level', 16, 1, 'RW', 2, 0, 2,
              description='Select Types of Status Return'),
        _item('alarm_led', 17, 1, 'RW', 36, 0, 0x7F,
              description='LED for Alarm (error byte bits that blink the LED)'),
        _item('shutdown', 18, 1, 'RW', 36, 0, 0x7F,
              description='Shutdown (error byte bits that zero Torque Limit)'),
        _item('torque_enable', 24, 1, 'RW', 0, 0, 1, description='Motor Torque On/Off'),
        _item('led', 25, 1, 'RW', 0, 0, 1, description='Status LED On/Off'),
        _item('goal_position', 30, 2, 'RW', 0, *goal, unit='pulse', signed=turns,
              limit='ccw_angle_limit', description='Target Position (joint mode)'),
        # Joint mode: 0..1,023 (0: no speed control); wheel mode: +-1,023, bit 10 the direction.
        _item('moving_speed', 32, 2, 'RW', 0, -MAGNITUDE, MAGNITUDE, unit=speed, direction=True,
              description='Moving Speed (bit 10: CW)'),
        _item('torque_limit', 34, 2, 'RW', max_torque, 0, 1023, unit='0.1 %',
              description='Torque Limit (0 after an alarm shutdown)'),
        _item('present_position', 36, 2, 'R', 0, *present, unit='pulse', signed=turns,
              description='Present Position'),
        _item('present_speed', 38, 2, 'R', 0, -MAGNITUDE, MAGNITUDE, unit=speed, direction=True,
              description='Present Speed (bit 10: CW)'),
        _item('present_load', 40, 2, 'R', 0, -MAGNITUDE, MAGNITUDE, unit='0.1 %', direction=True,
              description='Present Load (bit 10: CW)'),
        _item('present_voltage', 42, 1, 'R', round(volts * 10), 0, 0xFF, unit='0.1 V',
              description='Present Voltage'),
        _item('present_temperature', 43, 1, 'R', 25, 0, 0xFF, unit='degC',
              description='Present Temperature'),
        _item('registered', 44, 1, 'R', 0, 0, 1, description='If Instruction is registered'),
        _item('moving', 46, 1, 'R', 0, 0, 1, description='Movement Status'),
        _item('lock', 47, 1, 'RW', 0, 0, 1,
              description='Locking EEPROM (1 holds until power is cycled)'),
        # The e-manual's 0x20..0x3FF, widened to 0 where the power-on value is 0 (MX, EX).
        _item('punch', 48, 2, 'RW', punch, 0, 1023, description='Minimum Current Threshold'),
    ]


def _compliance(margin: int, slope: int) -> list[Item]:
    # AX, RX, EX, DX: margins 0..255 in position units, slopes in seven steps up to 254.
    return [
        _item('cw_compliance_margin', 26, 1, 'RW', margin, 0, 255, unit='pulse',
              description='CW Compliance Margin'),
        _item('ccw_compliance_margin', 27, 1, 'RW', margin, 0, 255, unit='pulse',
              description='CCW Compliance Margin'),
        _item('cw_compliance_slope', 28, 1, 'RW', slope, 0, 254,
              description='CW Compliance Slope'),
        _item('ccw_compliance_slope', 29, 1, 'RW', slope, 0, 254,
              description='CCW Compliance Slope'),
    ]


def _drive_mode() -> Item:
    # MX-106 and EX-106+: bit 0 reverse, bit 1 dual-joint slave (e-manual Drive Mode).
    return _item('drive_mode', 10, 1, 'RW', 0, 0, 3,
                 description='Drive Mode (bit 0 reverse, 1 dual-joint slave)')


def _sorted(items: list[Item]) -> tuple[Item, ...]:
    return tuple(sorted(items, key=lambda each: each.address))


def _model(number: int, name: str, family: str, items: list[Item], model_modes: dict[str, int],
           physics: Physics, *, pulses_per_rev: float, zero: int, speed_rpm: float,
           extended: int, bauds: dict[int, int], bulk_read: bool,
           roles: dict[str, str] = ROLES) -> Model:
    mx = family == 'MX(1.0)'
    current = 'current' in model_modes
    return Model(
        number=number, name=name, family=family, items=_sorted(items), modes=dict(model_modes),
        bauds=dict(bauds), current_unit_a=0.0045 if current else None, load_unit_ratio=0.001,
        velocity_unit_rpm=speed_rpm, pulses_per_rev=pulses_per_rev, position_zero_raw=zero,
        pwm_full_raw=1023, voltage_unit_v=0.1, indirect=(),
        hardware_error_bits=dict(ERROR_BITS), physics=physics, fast_sync_read_firmware=None,
        roles=dict(roles), acceleration_unit_rpm2=GOAL_ACCELERATION_RPM2 if mx else 214.577,
        extended_position_limit=extended, homing_position_mode_limit=0 if mx else None,
        protocol=1.0, mode_register='', eeprom_end=EEPROM_END, bulk_read=bulk_read,
        reboot=False)


_SPEC = 'ROBOTIS e-manual {} specifications'
_ONE = _SPEC + ' (one voltage published; the recommended {:g} V is not)'
POT_PULSES = 1024 * 360 / 300     # 1,024 steps over 300 degrees


# --- AX, RX, DX: potentiometer positions, compliance --------------------------------------

def _pot(number: int, name: str, family: str, *, baud: int, temperature: tuple[int, int],
         voltage: tuple[int, int, int, int], compliance: tuple[int, int], physics: Physics,
         max_torque: int = 1023, wheel: bool = True) -> Model:
    volts = physics.nominal_voltage_v
    items = _common(number, bauds=(baud, 1, 254), steps=1024, temperature=temperature,
                    voltage=voltage, max_torque=max_torque, speed='0.111 rpm', punch=32,
                    volts=volts)
    # DX-113/116/117 pages: 'does not support Wheel Mode'.
    model_modes = JOINT_WHEEL if wheel else modes.numbers('position')
    return _model(number, name, family, items + _compliance(*compliance), model_modes,
                  physics, pulses_per_rev=POT_PULSES, zero=512, speed_rpm=0.111, extended=1023,
                  bauds=BAUD_RATES, bulk_read=False)


_AX_V = (60, 140, 50, 160)    # volt_limit text: 50..160 (5..16 V)
_RX_V = (60, 190, 50, 250)    # volt_limit_rx text: 50..250 (5..25 V)

AX_RX_DX: tuple[Model, ...] = (
    _pot(12, 'AX-12A', 'AX', baud=1, temperature=(70, 100), voltage=_AX_V, compliance=(1, 32),
         physics=datasheet(254.0, 12.0, ((12.0, 1.5, 1.5, 59),),
                           _ONE.format('AX-12A', 11.1))),
    # The AX-12W's 470 rpm is its wheel-mode no-load speed (54 rpm in joint mode, e-manual).
    _pot(300, 'AX-12W', 'AX', baud=1, temperature=(70, 99), voltage=_AX_V, compliance=(4, 64),
         physics=datasheet(32.0, 12.0, ((12.0, 0.2, 1.4, 470),),
                           _ONE.format('AX-12W', 11.1))),
    _pot(18, 'AX-18A', 'AX', baud=1, temperature=(75, 99), voltage=_AX_V, compliance=(1, 32),
         max_torque=983, physics=datasheet(254.0, 12.0, ((12.0, 1.8, 2.2, 97),),
                                           _ONE.format('AX-18A', 11.1))),
    _pot(10, 'RX-10', 'RX', baud=34, temperature=(80, 100), voltage=_RX_V, compliance=(1, 32),
         physics=datasheet(193.0, 12.0, ((12.0, 1.3, 0.8, 54),), _ONE.format('RX-10', 11.1))),
    _pot(24, 'RX-24F', 'RX', baud=34, temperature=(80, 100), voltage=_RX_V, compliance=(1, 32),
         physics=datasheet(193.0, 12.0, ((12.0, 2.6, 2.4, 126),),
                           _ONE.format('RX-24F', 11.1))),
    _pot(28, 'RX-28', 'RX', baud=34, temperature=(80, 100), voltage=_RX_V, compliance=(1, 32),
         physics=datasheet(193.0, 18.5, ((18.5, 3.7, 1.9, 85),), _ONE.format('RX-28', 14.8))),
    # The RX-64 page cites the 50..160 voltage text beside its own initial 190: the RX range
    # 50..250 is kept.
    _pot(64, 'RX-64', 'RX', baud=34, temperature=(80, 100), voltage=_RX_V, compliance=(1, 32),
         physics=datasheet(200.0, 18.5, ((18.5, 5.3, 2.6, 64),), _ONE.format('RX-64', 14.8))),
    # DX-113: its page gives 1.0 N.m and 54 rpm at 12 V, no stall current. The RX-10, the
    # RX model that followed it at the same 54 rpm at 12 V and near the same gear (193:1), has
    # 1.3 N.m at 0.8 A: its 1.625 N.m/A is assumed, 1.0 N.m at 0.62 A. Its voltage limits cite
    # an older text: the DX-117's 50..250 range is kept beside its published 60/190.
    _pot(113, 'DX-113', 'DX', baud=34, temperature=(85, 100), voltage=_RX_V,
         compliance=(0, 32), wheel=False, physics=datasheet(
             192.6, 12.0, ((12.0, 1.0, 0.62, 54),),
             _ONE.format('DX-113', 11.1) + '; no stall current published: the RX-10 torque '
             'constant 1.3 N.m / 0.8 A (same 54 rpm at 12 V, 193:1) assumed')),
    # DX-116: its page gives 2.1 N.m at 12 V and 2.9 N.m at 16 V (142.5:1), no stall current
    # nor speed. The DX-series manual (2004) says the DX-116 and DX-117 use the same RE-max
    # coreless motor: the DX-117's (3.7 N.m at 1.9 A, 85 rpm at 18.5 V, 192.6:1) is assumed,
    # its torque per amp and speed per volt carried through the 142.5:1 gear (1.441 N.m/A:
    # 1.46 and 2.01 A; 884.9 motor rpm/V: 74.5 and 99.4 rpm). The DX-116 manual's 70 rpm at
    # the top of Moving Speed is near the 12 V figure. 16 V is the point nearest the
    # recommended 14.8 V.
    _pot(116, 'DX-116', 'DX', baud=34, temperature=(85, 100), voltage=_RX_V,
         compliance=(0, 32), wheel=False, physics=datasheet(
             142.5, 16.0, ((12.0, 2.1, 1.46, 74.5), (16.0, 2.9, 2.01, 99.4)),
             _SPEC.format('DX-116') + ' (stall torque only; the recommended 14.8 V is not '
             'published); stall current and no-load speed assumed from the DX-117, whose '
             'RE-max motor the DX-series manual says the DX-116 shares, scaled by gear ratio '
             '(192.6 -> 142.5) and voltage')),
    _pot(117, 'DX-117', 'DX', baud=34, temperature=(80, 100), voltage=_RX_V, compliance=(1, 32),
         wheel=False, physics=datasheet(192.6, 18.5, ((18.5, 3.7, 1.9, 85),),
                                        _ONE.format('DX-117', 14.8))),
)


# --- EX-106+: 4,096 steps over 250.92 degrees --------------------------------------------

def _ex106() -> Model:
    items = _common(107, bauds=(34, 1, 254), steps=4096, temperature=(80, 100),
                    voltage=(60, 240, 50, 250), max_torque=1023, speed='0.111 rpm', punch=0,
                    volts=18.5)
    items += _compliance(1, 32)
    items.append(_drive_mode())
    # Raw: 10 mA per count about 512 (no current); the page's two examples disagree on the
    # sign, so no role reads it as a current.
    items.append(_item('sensed_current', 56, 2, 'R', 512, 0, 1023,
                       description='Sensed Current (10 mA per count, 512 is none)'))
    # Wheel mode reads the raw encoder count, 0..65,535, in Present Position (e-manual).
    physics = datasheet(184.0, 18.5, ((18.5, 10.9, 7.0, 91),), _ONE.format('EX-106+', 14.8))
    # dynamixel-workbench's EX table puts Moving Speed at 34 and Torque Limit at 35 (they
    # would overlap); the e-manual's 32 and 34 are kept. Its 250.92 degrees per 4,096 steps
    # (+-2.18969 rad about 2,048) match the e-manual's 0..251 degree range.
    return _model(107, 'EX-106+', 'EX', items, JOINT_WHEEL, physics,
                  pulses_per_rev=4096 * 360 / 250.92, zero=2048, speed_rpm=0.111,
                  extended=4095, bauds=BAUD_RATES, bulk_read=True)


# --- MX on Protocol 1.0 ---------------------------------------------------------------------

def _mx(number: int, name: str, *, baud: int, temperature: int, gains: tuple[int, int, int],
        punch: int, speed_rpm: float, tick_firmware: int, physics: Physics,
        torque: bool = False, drive_mode: bool = False) -> tuple[Model, Model]:
    """Return the two tables of one MX(1.0): before and from the firmware with Realtime Tick."""
    d_gain, i_gain, p_gain = gains
    items = _common(number, bauds=(baud, 1, 252), steps=4096, temperature=(temperature, 100),
                    voltage=(60, 160, 50, 160), max_torque=1023, speed=f'{speed_rpm:g} rpm',
                    punch=punch, volts=physics.nominal_voltage_v, turns=True)
    items += [
        _item('multi_turn_offset', 20, 2, 'RW', 0, -MX_OFFSET_LIMIT, MX_OFFSET_LIMIT,
              unit='pulse', signed=True,
              description='Multi Turn Offset (added to Present Position in multi-turn mode)'),
        _item('resolution_divider', 22, 1, 'RW', 1, 1, 4,
              description='Resolution Divider (Present Position = real / divider + offset)'),
        # The D, I, P order holds from firmware 0x1E on (e-manual, Korean MX-28 page).
        _item('d_gain', 26, 1, 'RW', d_gain, 0, 254, description='Derivative Gain'),
        _item('i_gain', 27, 1, 'RW', i_gain, 0, 254, description='Integral Gain'),
        _item('p_gain', 28, 1, 'RW', p_gain, 0, 254, description='Proportional Gain'),
        _item('goal_acceleration', 73, 1, 'RW', 0, 0, 254, unit='8.583 deg/s^2',
              description='Goal Acceleration (0: no acceleration control)'),
    ]
    if drive_mode:
        items.append(_drive_mode())
    if torque:
        unit = '4.5 mA'
        items += [
            # RW in the e-manual; raw 2,048 is no current, above it positive.
            # The e-manual's initial 0 is read as no current (raw 2,048, its idle value).
            _item('current', 68, 2, 'RW', 0, -MX_CURRENT_ZERO, MX_CURRENT_ZERO - 1,
                  unit=unit, raw_zero=MX_CURRENT_ZERO,
                  description='Consuming Current (4.5 mA per count about 2,048)'),
            _item('torque_ctrl_mode_enable', 70, 1, 'RW', 0, 0, 1,
                  description='Torque Control Mode On/Off (1: Goal Torque only)'),
            _item('goal_torque', 71, 2, 'RW', 0, -MAGNITUDE, MAGNITUDE, unit=unit,
                  direction=True, description='Goal Torque (bit 10: CW; within Torque Limit)'),
        ]
    model = _model(number, name, 'MX(1.0)', items, WITH_TORQUE if torque else JOINT_WHEEL_TURNS,
                   physics, pulses_per_rev=4096, zero=2048, speed_rpm=speed_rpm,
                   extended=MX_TURNS_LIMIT, bauds=MX_BAUD_RATES, bulk_read=True,
                   roles=MX_CURRENT_ROLES if torque else MX_ROLES)
    tick = _item('realtime_tick', 50, 2, 'R', 0, 0, 32767, unit='ms',
                 description='Count Time in millisecond (wraps after 32,767)')
    ticking = replace(model, items=_sorted([*model.items, tick]), min_firmware=tick_firmware)
    return model, ticking


MX_MODELS: tuple[Model, ...] = (
    # The English MX-12W page is the AX-12W's text (0.29 degree steps, 0.111 rpm, 80 degC,
    # model number 104, which is 360's low byte): the Korean page's MX items, 0.916 rpm and
    # 70 degC (the datasheet's operating range) are kept. Its datasheet gives no stall torque:
    # the AX-12W's (same 32:1 gearing and 470 rpm) stands in.
    *_mx(360, 'MX-12W', baud=1, temperature=70, gains=(8, 0, 8), punch=32, speed_rpm=0.916,
         tick_firmware=41, physics=datasheet(
             32.0, 12.0, ((12.0, 0.2, 1.4, 470),),
             'ROBOTIS e-manual MX-12W specifications give 32:1 and 470 rpm at 12 V, no stall '
             'torque: the AX-12W 0.2 N.m at 1.4 A (same gearing and speed) assumed')),
    *_mx(29, 'MX-28', baud=34, temperature=80, gains=(0, 0, 32), punch=0, speed_rpm=0.114,
         tick_firmware=40, physics=datasheet(
             193.0, 12.0, ((11.1, 2.3, 1.3, 50), (12.0, 2.5, 1.4, 55), (14.8, 3.1, 1.7, 67)),
             _SPEC.format('MX-28') + ' (_data/dxl_mx_info.yml)')),
    # The MX-64 page gives Max Voltage Limit 240 beside the 50..160 range its text states
    # (the MX-28, MX-106 and MX-64(2.0) pages: 160): 160 kept.
    *_mx(310, 'MX-64', baud=34, temperature=80, gains=(0, 0, 32), punch=0, speed_rpm=0.114,
         tick_firmware=40, torque=True, physics=datasheet(
             200.0, 12.0, ((11.1, 5.5, 3.9, 58), (12.0, 6.0, 4.1, 63), (14.8, 7.3, 5.2, 78)),
             _SPEC.format('MX-64') + ' (_data/dxl_mx_info.yml)')),
    *_mx(320, 'MX-106', baud=34, temperature=80, gains=(0, 0, 32), punch=0, speed_rpm=0.114,
         tick_firmware=40, torque=True, drive_mode=True, physics=datasheet(
             225.0, 12.0, ((11.1, 8.0, 4.8, 41), (12.0, 8.4, 5.2, 45), (14.8, 10.0, 6.3, 55)),
             _SPEC.format('MX-106') + ' (_data/dxl_mx_info.yml)')),
)

MODELS: tuple[Model, ...] = (*AX_RX_DX, _ex106(), *MX_MODELS)
