"""
DYNAMIXEL PRO on its original firmware (H42/H54/M42/M54/L54/L42 -R) and the first RH-P12-RN.

Not the P/PRO(A) layout of models.pro: EEPROM 0..561 (the 256 Indirect Address entries at 49..559
included), RAM from Torque Enable at 562; Goal Position 596, Goal Velocity 600, Goal Torque 604,
Goal Acceleration 606, Present Position 611, Present Velocity 615, Present Current 621, Indirect
Data 634..889, Hardware Error Status 892. No Realtime Tick, no PWM register, no Moving Status, no
profile registers, no Drive Mode, no Bus Watchdog, no Secondary ID.

Units (e-manual, per model): positions count pulses of the output shaft about 0 (H54 +-250,961
for +-180 degrees, the resolution over two); Goal/Present Velocity count 1 rpm of the motor
before the gear, so the output unit is one over the gear ratio (H54 0.00199234 rpm); Goal
Torque and Present Current count 33,000/2,048 mA on the 54 frames and 8,250/2,048 mA on the 42
ones (the e-manual's formula); Goal Acceleration counts 58,000 rev/min^2 of the motor, over
the gear ratio at the output; voltage 0.1 V.

Operating Mode 0 is Torque Control Mode, a control of the motor current through Goal Torque:
'current' here, with Model.roles goal_current -> goal_torque and current_limit -> torque_limit
(Torque Limit bounds Goal Torque in the same unit). Goal Velocity also caps the speed in the
position modes and Goal Acceleration shapes a profile only with a non-zero Goal Velocity: no
role maps the X's Profile Velocity/Acceleration onto them, whose meaning differs. No PWM mode
(the datasheet lists one, the control table has no register for it).

The gripper RH-P12-RN (35073) has this layout with Current Limit and Goal Current under those
names, position PID gains (590..594) instead of the velocity PI gains, no Homing Offset, and
the current (0) and current-based position (5) modes.

The L42-10-S300-R (35072) has this layout with other units and fewer registers. Its e-manual
page contradicts itself and has changed over time; each contested item is settled by the
sources that agree, the rest assumed (see L42_SOURCE):
- positions: 4,096 pulses per output turn (the PRO data file, the Korean PRO overview) about 0,
  +-2,048 for +-180 degrees (dynamixel-workbench info_PRO, the ROBOTIS-Framework device file,
  the page's initial limits 2,048/-2,047); the page's '0 ~ 4,095, 0 ~ 360 degrees' text is the
  MX's and is not followed (the limits it sits beside are negative);
- velocity: 0.114 rpm of the output (the page's Goal/Present Velocity text and workbench
  info_PRO; the table gives no unit), the page's range +-1,023;
- Goal Torque: the motor current, 8,250/2,048 mA as on the other 42 frames (the page's
  formula names Goal Torque and Present Current, its table bounds it by +-Torque Limit, its older
  revision calls it 'Desired Current Value'; the '0 ~ 1,023, 0.1 %' text is the MX's Torque
  Limit text); a cap in both of its modes, 0 at power-on (table; the PRO rule: 0 lets Torque
  Limit apply, which is what the text's 'Torque Limit at power-on' amounts to);
- Goal Acceleration: '214 RPM^2 @ Core Motor' read as the other PRO pages' phrase is (a motor
  figure), over the 303.75:1 gear at the output (0.70453 rev/min^2); the other reading (214
  rev/min^2 at the output, as on the X) is not excluded by any source, and nothing here uses
  the figure but the simulator;
- modes: velocity (1) and position (3) only (its Operating Mode table; the spec sheet's list is
  the shared PRO one);
- no Homing Offset (dynamixel-workbench items_PRO, the ROBOTIS-Framework device file and the
  page's older revision have none; the current table lists one with no description);
- gains: only Position P Gain (594), in every source; the current table's Velocity I/P (586,
  588; initial values the H42-20-S300-R's) and the older table's and the description's Position
  D/I (590, 592) contradict each other and are left out;
- Shutdown 48 (0x30, bits 4 and 5: the description's defaults and the older revision's value;
  the current table's '30' is read as that hexadecimal); Moving Threshold 10 (the current
  table; the older revision gives 50);
- Velocity Limit and Acceleration Limit are '-' on the page: 1,023 (the text's Goal Velocity
  range) and 255 (as for the other PRO here) are assumed; the page's Indirect Address range
  '562 ~ 949' passes the table's end, 892 is kept.

Sources: the ROBOTIS e-manual pages of the H54-200-S500-R, H54-100-S500-R, H42-20-S300-R,
M54-60-S250-R, M54-40-S250-R, M42-10-S260-R, L54-50-S500-R, L54-50-S290-R, L54-30-S400-R (their
control tables with units and initial values), its shared PRO texts (Operating Mode, Baud Rate,
Goal Velocity scale factors, Goal Torque formula, Goal Acceleration, Min/Max Position Limit,
Shutdown, Indirect Address) and _data/dxl_pro_info.yml (resolution, gear ratio, datasheet
figures); the RH-P12-RN page; the L42-10-S300-R page (current and older revision);
dynamixel-workbench's dynamixel_item.cpp (items_EXTPRO, items_PRO and the per-model position and
velocity info) for the cross-check of addresses and sizes; ROBOTIS-Framework's
L42-10-S300-R.device (as kept in a public fork) for the L42's. Assumptions are commented at the
figure.
"""

from dataclasses import dataclass

from dxl_servo_driver.models import modes
from dxl_servo_driver.models.base import datasheet, Item, Model
from dxl_servo_driver.models.layout import indirect_items, indirect_pairs, ItemMaker

__all__ = ['GRIPPER', 'L42', 'MODELS', 'PRO_MODELS']

EEPROM_END = 562           # Torque Enable: the first RAM address
LAST_RAM = 892             # e-manual: Indirect Address takes RAM 562..892 (Hardware Error Status)
INT32_MIN = -(1 << 31)
INT32_MAX = (1 << 31) - 1
# Baud Rate register value -> bit/s (e-manual PRO baud table: 0..8; the control tables' 0..13
# range lists no rate above 8).
BAUD_RATES: dict[int, int] = {
    0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000, 6: 4_000_000,
    7: 4_500_000, 8: 10_500_000,
}
# Indirect Address 1..256 at 49..559 (EEPROM), Indirect Data 1..256 at 634..889.
INDIRECT_PAIRS = indirect_pairs((49, 634, 256))
PRO_MODES = modes.numbers('current', 'velocity', 'position', 'extended_position')
GRIPPER_MODES = modes.numbers('current', 'current_based_position')
# Shutdown bits (e-manual PRO Shutdown): bit 1 is the motor hall sensor error here.
HARDWARE_ERROR_BITS: dict[int, str] = {
    0x01: 'input_voltage', 0x02: 'motor_hall_sensor', 0x04: 'overheating',
    0x08: 'motor_encoder', 0x10: 'electrical_shock', 0x20: 'overload',
}
# The gripper's bit 1 is unused (its page).
GRIPPER_ERROR_BITS = {bit: name for bit, name in HARDWARE_ERROR_BITS.items() if bit != 0x02}
CURRENT_54_MA = 33_000 / 2048    # 16.11328 mA per count
CURRENT_42_MA = 8_250 / 2048     # 4.02832 mA per count
MOTOR_ACCELERATION_RPM2 = 58_000  # one Goal Acceleration count at the motor
# No PWM register: the XM430 manual's 885 stands as the simulator's duty scale.
NO_PWM_SCALE = 885
ROLES: dict[str, str] = {'goal_current': 'goal_torque', 'current_limit': 'torque_limit'}


@dataclass(frozen=True)
class _Figures:
    """One model's e-manual figures."""

    velocity_unit_rpm: float           # Goal/Present Velocity at the output
    current_ma: float                  # Goal Torque/Present Current per count
    torque_limit: tuple[int, int]      # Torque Limit (initial, maximum)
    velocity_limit: int                # Velocity Limit initial
    gains: tuple[int, int, int]        # Velocity I, Velocity P, Position P
    half_turn: int                     # Max Position Limit initial: pulses of 180 degrees
    resolution: int                    # pulses per output revolution
    acceleration_limit: int = 255


_item = ItemMaker(eeprom_end=EEPROM_END)


def _common(number: int, *, mode_initial: int, mode_max: int, moving_threshold: int,
            shutdown: int, acceleration_limit: int, velocity_limit: int, velocity_unit: str,
            position: tuple[int, int, int, int], mode_min: int = 0) -> list[Item]:
    """
    Return the items the PRO and the gripper share.

    position: (max limit initial, min limit initial, lowest, highest) of the position limits
    and of Goal Position.
    """
    high, low, lowest, highest = position
    items = [
        *_item.identity(number),
        _item('id', 7, 1, 'RW', 1, 0, 252, description='DYNAMIXEL ID (254 is broadcast)'),
        _item('baud_rate', 8, 1, 'RW', 1, 0, max(BAUD_RATES),
              description='Communication Baud Rate'),
        _item('return_delay_time', 9, 1, 'RW', 250, 0, 255, unit='2 us',
              description='Response Delay Time'),
        _item('operating_mode', 11, 1, 'RW', mode_initial, mode_min, mode_max,
              description='Operating Mode'),
        _item('moving_threshold', 17, 4, 'RW', moving_threshold, 0, INT32_MAX,
              unit=velocity_unit, description='Velocity Threshold for Movement Detection'),
        _item('temperature_limit', 21, 1, 'RW', 80, 0, 100, unit='degC',
              description='Maximum Internal Temperature Limit'),
        _item('max_voltage_limit', 22, 2, 'RW', 400, 0, 400, unit='0.1 V',
              description='Maximum Input Voltage Limit'),
        _item('min_voltage_limit', 24, 2, 'RW', 150, 0, 400, unit='0.1 V',
              description='Minimum Input Voltage Limit'),
        _item('acceleration_limit', 26, 4, 'RW', acceleration_limit, 0, INT32_MAX,
              description='Maximum Acceleration Limit (bounds Goal Acceleration)'),
        _item('velocity_limit', 32, 4, 'RW', velocity_limit, 0, INT32_MAX, unit=velocity_unit,
              description='Maximum Velocity Limit'),
        _item('max_position_limit', 36, 4, 'RW', high, lowest, highest, signed=True,
              unit='pulse', description='Maximum Position Limit'),
        _item('min_position_limit', 40, 4, 'RW', low, lowest, highest, signed=True,
              unit='pulse', description='Minimum Position Limit'),
        _item('shutdown', 48, 1, 'RW', shutdown, 0, 0xFF, description='Shutdown conditions'),
        *indirect_items(INDIRECT_PAIRS, LAST_RAM, first_ram_address=EEPROM_END,
                        eeprom_end=EEPROM_END),
        _item('torque_enable', 562, 1, 'RW', 0, 0, 1, description='Motor Torque On/Off'),
        _item('led_red', 563, 1, 'RW', 0, 0, 0xFF, description='Red LED intensity'),
        _item('led_green', 564, 1, 'RW', 0, 0, 0xFF, description='Green LED intensity'),
        _item('led_blue', 565, 1, 'RW', 0, 0, 0xFF, description='Blue LED intensity'),
        _item('goal_position', 596, 4, 'RW', 0, lowest, highest, signed=True,
              limit='max_position_limit', unit='pulse',
              description='Goal Position (within the position limits in position mode)'),
        _item('goal_velocity', 600, 4, 'RW', 0, -INT32_MAX, INT32_MAX, signed=True,
              limit='velocity_limit', unit=velocity_unit,
              description='Goal Velocity (the speed cap in the position modes; 0: none)'),
        _item('goal_acceleration', 606, 4, 'RW', 0, 0, INT32_MAX, signed=True,
              limit='acceleration_limit',
              description='Goal Acceleration (a profile only with a non-zero Goal Velocity)'),
        _item('moving', 610, 1, 'R', 0, 0, 1, description='Movement Status'),
        _item('present_position', 611, 4, 'R', 0, INT32_MIN, INT32_MAX, signed=True,
              unit='pulse', description='Present Position'),
        _item('present_velocity', 615, 4, 'R', 0, INT32_MIN, INT32_MAX, signed=True,
              unit=velocity_unit, description='Present Velocity'),
        _item('present_input_voltage', 623, 2, 'R', 240, 0, 0xFFFF, unit='0.1 V',
              description='Present Input Voltage'),
        _item('present_temperature', 625, 1, 'R', 25, 0, 0xFF, unit='degC',
              description='Present Internal Temperature'),
        _item('registered_instruction', 890, 1, 'R', 0, 0, 1,
              description='Check Reception of Instruction'),
        _item('status_return_level', 891, 1, 'RW', 2, 0, 2,
              description='Select Types of Status Return'),
        _item('hardware_error_status', 892, 1, 'R', 0, 0, 0xFF,
              description='Hardware Error Status (the Shutdown bits)'),
    ]
    for n in (1, 2, 3, 4):
        items.append(_item(
            f'external_port_mode_{n}', 43 + n, 1, 'RW', 0, 0, 3,
            description=f'External Port Mode {n} (0 analog in, 1 digital out, '
                        '2 digital in pull-up, 3 digital in pull-down)'))
        items.append(_item(f'external_port_data_{n}', 624 + 2 * n, 2, 'RW', 0, 0, 4095,
                           description=f'External Port Data {n} (12-bit analog or digital)'))
    return items


def _sorted(items: list[Item]) -> tuple[Item, ...]:
    return tuple(sorted(items, key=lambda each: each.address))


def _pro_items(number: int, f: _Figures) -> tuple[Item, ...]:
    velocity_unit = f'{f.velocity_unit_rpm:g} rpm'
    current_unit = f'{f.current_ma:.5f} mA'
    torque_initial, torque_max = f.torque_limit
    velocity_i, velocity_p, position_p = f.gains
    items = _common(
        number, mode_initial=3, mode_max=4, moving_threshold=50, shutdown=0x3A,
        acceleration_limit=f.acceleration_limit, velocity_limit=f.velocity_limit,
        velocity_unit=velocity_unit,
        position=(f.half_turn, -f.half_turn, INT32_MIN, INT32_MAX))
    items += [
        _item('homing_offset', 13, 4, 'RW', 0, INT32_MIN, INT32_MAX, signed=True,
              unit='pulse', description='Home Position Offset'),
        _item('torque_limit', 30, 2, 'RW', torque_initial, 0, torque_max, unit=current_unit,
              description='Maximum Torque Limit (a current: bounds Goal Torque)'),
        _item('velocity_i_gain', 586, 2, 'RW', velocity_i, 0, 0xFFFF,
              description='I Gain of Velocity'),
        _item('velocity_p_gain', 588, 2, 'RW', velocity_p, 0, 0xFFFF,
              description='P Gain of Velocity'),
        _item('position_p_gain', 594, 2, 'RW', position_p, 0, 0xFFFF,
              description='P Gain of Position'),
        # Initial 0 (e-manual): outside the torque mode 0 means 'Torque Limit applies'.
        _item('goal_torque', 604, 2, 'RW', 0, -torque_max, torque_max, signed=True,
              limit='torque_limit', unit=current_unit,
              description='Goal Torque (the motor current; a cap outside the torque mode)'),
        _item('present_current', 621, 2, 'R', 0, -32768, 32767, signed=True,
              unit=current_unit, description='Present Current'),
    ]
    return _sorted(items)


# The datasheets publish continuous (rated) torque and current, not stall figures: those
# stand in for the stall point (their ratio is the torque constant), with the no-load speed.
_CONT = ('ROBOTIS e-manual {} specifications (_data/dxl_pro_info.yml): continuous torque and '
         'current stand in for the unpublished stall figures')


def _pro(number: int, name: str, f: _Figures,
         figures: tuple[float, float, float, float], source: str = '') -> Model:
    gear, torque, current, speed = figures
    physics = datasheet(gear, 24.0, ((24.0, torque, current, speed),),
                        _CONT.format(name) + source)
    return Model(
        number=number, name=name, family='PRO', items=_pro_items(number, f),
        modes=dict(PRO_MODES), bauds=dict(BAUD_RATES), current_unit_a=f.current_ma / 1000.0,
        load_unit_ratio=None, velocity_unit_rpm=f.velocity_unit_rpm,
        pulses_per_rev=f.resolution, position_zero_raw=0, pwm_full_raw=NO_PWM_SCALE,
        voltage_unit_v=0.1, indirect=INDIRECT_PAIRS,
        hardware_error_bits=dict(HARDWARE_ERROR_BITS), physics=physics,
        fast_sync_read_firmware=None, roles=dict(ROLES),
        # Goal Acceleration counts 58,000 rev/min^2 of the motor: over the gear (one
        # velocity count is 1 rpm of the motor, so the output unit is velocity_unit_rpm).
        acceleration_unit_rpm2=MOTOR_ACCELERATION_RPM2 * f.velocity_unit_rpm,
        extended_position_limit=INT32_MAX, homing_position_mode_limit=None,
        eeprom_end=EEPROM_END)


# Acceleration Limit: '-' on every page but the H42-20-S300-R's (255); its 255 is assumed.
_H54 = 0.00199234
_M54 = 0.00397746
PRO_MODELS: tuple[Model, ...] = (
    _pro(54024, 'H54-200-S500-R', _Figures(_H54, CURRENT_54_MA, (620, 1860), 17_000,
                                           (14, 399, 32), 250_961, 501_923),
         (501.923, 44.7, 9.3, 33.1)),
    _pro(53768, 'H54-100-S500-R', _Figures(_H54, CURRENT_54_MA, (310, 930), 17_000,
                                           (16, 256, 32), 250_961, 501_923),
         (501.923, 25.3, 5.5, 33.3)),
    _pro(51200, 'H42-20-S300-R', _Figures(0.00329218, CURRENT_42_MA, (465, 1395), 10_300,
                                          (40, 440, 32), 151_875, 303_750),
         (303.75, 5.1, 1.5, 32.7)),
    # The yml's 251.4:1 is rounded: the velocity scale 0.00397746 is 1/251.417.
    _pro(46352, 'M54-60-S250-R', _Figures(_M54, CURRENT_54_MA, (180, 540), 8000,
                                          (16, 256, 32), 125_708, 251_417),
         (251.417, 10.1, 3.0, 33.1)),
    _pro(46096, 'M54-40-S250-R', _Figures(_M54, CURRENT_54_MA, (120, 360), 8000,
                                          (16, 256, 32), 125_708, 251_417),
         (251.417, 3.9, 1.9, 28.4)),
    _pro(43288, 'M42-10-S260-R', _Figures(0.00389076, CURRENT_42_MA, (300, 900), 8000,
                                          (72, 520, 32), 131_593, 263_187),
         (257.0, 1.7, 0.6, 28.0)),
    _pro(38152, 'L54-50-S500-R', _Figures(_H54, CURRENT_54_MA, (120, 360), 8000,
                                          (16, 256, 32), 180_692, 361_384),
         (501.923, 14.0, 1.9, 16.0)),
    _pro(38176, 'L54-50-S290-R', _Figures(0.00346667, CURRENT_54_MA, (120, 360), 8000,
                                          (16, 412, 250), 103_846, 207_692),
         (288.5, 4.8, 1.9, 26.0)),
    # Its control-table page was not found in a version with initial values: Torque Limit
    # 100/300 as the L54-30-S400-R (same L54-30 motor), Velocity Limit 8,000 and the gains
    # as the L54-50-S500-R (same 501.923:1 gear and scale), assumed.
    _pro(37896, 'L54-30-S500-R', _Figures(_H54, CURRENT_54_MA, (100, 300), 8000,
                                          (16, 256, 32), 180_692, 361_384),
         (501.923, 5.4, 1.6, 23.0),
         '; Torque Limit, Velocity Limit and gains assumed from the L54-30-S400-R and '
         'L54-50-S500-R'),
    _pro(37928, 'L54-30-S400-R', _Figures(0.00249657, CURRENT_54_MA, (100, 300), 9000,
                                          (16, 412, 200), 144_197, 288_395),
         (400.5, 2.5, 1.6, 28.7)),
)


# --- RH-P12-RN (35073) -------------------------------------------------------------------------

GRIPPER_CURRENT_MA = 4.02        # its page: 'about 4.02 mA' (820 of them: the 3.33 A peak)
GRIPPER_VELOCITY_RPM = 0.114
GRIPPER_TRAVEL = 1150            # Max Position Limit: closed


def _gripper() -> Model:
    velocity_unit = '0.114 rpm'
    current_unit = '4.02 mA'
    items = _common(
        35073, mode_initial=5, mode_max=5, moving_threshold=10, shutdown=0x30,
        acceleration_limit=255, velocity_limit=100, velocity_unit=velocity_unit,
        position=(GRIPPER_TRAVEL, 0, 0, GRIPPER_TRAVEL))
    items += [
        _item('current_limit', 30, 2, 'RW', 820, 0, 820, unit=current_unit,
              description='Maximum Current Limit'),
        # Initial values '-' on the page: the RH-P12-RN(A)'s P-layout gains are not comparable
        # (another firmware), so 0 (off) is taken for D and I, and P at 32, the PRO pages'
        # common Position P Gain.
        _item('position_d_gain', 590, 2, 'RW', 0, 0, 32767, description='D Gain of Position'),
        _item('position_i_gain', 592, 2, 'RW', 0, 0, 32767, description='I Gain of Position'),
        _item('position_p_gain', 594, 2, 'RW', 32, 0, 32767, description='P Gain of Position'),
        # Goal Current powers on at 0 (page): in mode 5 it is the grip's current cap.
        _item('goal_current', 604, 2, 'RW', 0, -820, 820, signed=True, limit='current_limit',
              unit=current_unit, description='Goal Current (a cap in mode 5)'),
        _item('present_current', 621, 2, 'R', 0, -32768, 32767, signed=True, unit=current_unit,
              description='Present Current'),
    ]
    physics = datasheet(1181.0, 24.0, ((24.0, 1.7, 3.33, 29.7),),
                        'ROBOTIS e-manual RH-P12-RN specifications give 1181:1, 24 V, a 3.33 A '
                        'peak current and a 170 N maximum grip force, no torque nor speed: '
                        'the RH-P12-RN(A) assumption (1.7 N.m, 170 N at 10 mm, at 3.33 A; '
                        '29.7 rpm) is kept for the same hardware')
    return Model(
        number=35073, name='RH-P12-RN', family='RH-P12-RN', items=_sorted(items),
        modes=dict(GRIPPER_MODES), bauds=dict(BAUD_RATES),
        current_unit_a=GRIPPER_CURRENT_MA / 1000.0, load_unit_ratio=None,
        velocity_unit_rpm=GRIPPER_VELOCITY_RPM,
        # A 12-bit absolute encoder (its page: 0.088 degree): 4,096 per turn of the drive.
        pulses_per_rev=4096, position_zero_raw=0, pwm_full_raw=NO_PWM_SCALE,
        voltage_unit_v=0.1, indirect=INDIRECT_PAIRS,
        hardware_error_bits=dict(GRIPPER_ERROR_BITS), physics=physics,
        fast_sync_read_firmware=None,
        # Its page: Goal Acceleration counts 214.577 rev/min^2.
        acceleration_unit_rpm2=214.577, extended_position_limit=GRIPPER_TRAVEL,
        homing_position_mode_limit=None, eeprom_end=EEPROM_END)


GRIPPER = _gripper()


# --- L42-10-S300-R (35072) ---------------------------------------------------------------------

L42_GEAR = 303.75                # _data/dxl_pro_info.yml and the page's spec table
L42_VELOCITY_RPM = 0.114         # its page's Goal/Present Velocity text, workbench info_PRO
L42_VELOCITY_MAX = 1023          # its page: Goal Velocity -1,023 ~ 1,023
L42_TORQUE_LIMIT = 987           # its table: Torque Limit initial and maximum (3.98 A)
L42_HALF_TURN = 2048             # workbench info_PRO: +-2,048 is +-pi, 0 is 0 rad
L42_MOTOR_ACCELERATION_RPM2 = 214  # its page: Goal Acceleration '214 RPM^2 @ Core Motor'
L42_MODES = modes.numbers('velocity', 'position')
L42_SOURCE = (
    'ROBOTIS e-manual L42-10-S300-R specifications (_data/dxl_pro_info.yml): 303.75:1, '
    'continuous 1.2 N.m at 0.8 A standing in for the unpublished stall figures, 29.7 rpm '
    'no-load at 24 V. Its control table as settled in models.pro_legacy: 4,096 pulses per '
    'turn about 0, 0.114 rpm, Goal Torque a current in 8,250/2,048 mA, no Homing Offset, '
    'Position P Gain only; assumed: Velocity Limit 1,023, Acceleration Limit 255, Goal '
    'Acceleration 214 rev/min^2 at the motor')


def _l42() -> Model:
    velocity_unit = f'{L42_VELOCITY_RPM:g} rpm'
    current_unit = f'{CURRENT_42_MA:.5f} mA'
    items = _common(
        35072, mode_initial=3, mode_min=1, mode_max=3, moving_threshold=10, shutdown=0x30,
        # Acceleration Limit: '-' on the page; the other PRO's assumed 255.
        acceleration_limit=255, velocity_limit=L42_VELOCITY_MAX, velocity_unit=velocity_unit,
        # Initial limits 2,048/-2,047 (its table); any int32 (its table's range).
        position=(L42_HALF_TURN, 1 - L42_HALF_TURN, INT32_MIN, INT32_MAX))
    items += [
        _item('torque_limit', 30, 2, 'RW', L42_TORQUE_LIMIT, 0, L42_TORQUE_LIMIT,
              unit=current_unit, description='Maximum Torque Limit (a current: bounds Goal '
                                             'Torque)'),
        # Initial 64 (its current table); range 0..65,535 (its table; the text: 0..32,767).
        _item('position_p_gain', 594, 2, 'RW', 64, 0, 0xFFFF, description='P Gain of Position'),
        _item('goal_torque', 604, 2, 'RW', 0, -L42_TORQUE_LIMIT, L42_TORQUE_LIMIT, signed=True,
              limit='torque_limit', unit=current_unit,
              description='Goal Torque (the motor current cap; 0: Torque Limit applies)'),
        _item('present_current', 621, 2, 'R', 0, -32768, 32767, signed=True,
              unit=current_unit, description='Present Current'),
    ]
    physics = datasheet(L42_GEAR, 24.0, ((24.0, 1.2, 0.8, 29.7),), L42_SOURCE)
    return Model(
        number=35072, name='L42-10-S300-R', family='PRO', items=_sorted(items),
        modes=dict(L42_MODES), bauds=dict(BAUD_RATES), current_unit_a=CURRENT_42_MA / 1000.0,
        load_unit_ratio=None, velocity_unit_rpm=L42_VELOCITY_RPM,
        pulses_per_rev=2 * L42_HALF_TURN, position_zero_raw=0, pwm_full_raw=NO_PWM_SCALE,
        voltage_unit_v=0.1, indirect=INDIRECT_PAIRS,
        hardware_error_bits=dict(HARDWARE_ERROR_BITS), physics=physics,
        fast_sync_read_firmware=None, roles=dict(ROLES),
        # A motor figure (the PRO pages' phrase) carried through the gear to the output.
        acceleration_unit_rpm2=L42_MOTOR_ACCELERATION_RPM2 / L42_GEAR,
        extended_position_limit=INT32_MAX, homing_position_mode_limit=None,
        eeprom_end=EEPROM_END)


L42 = _l42()
MODELS: tuple[Model, ...] = (*PRO_MODELS, GRIPPER, L42)
