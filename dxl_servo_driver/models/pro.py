"""
The P series, the PRO(A) and the RH-P12-RN(A) gripper: one firmware family, as data.

EEPROM is 0..511 and RAM 512.. (the Indirect Address entries sit in EEPROM, at 168..), positions
count pulses of the output shaft with zero at raw 0, velocity 0.01 rpm, current 1 mA, PWM full
scale 2,009, voltage 0.1 V. The PRO(A) tables are the P ones without Protocol Type, Startup
Configuration and Backup Ready (the dynamixel-sdk *_ra model files); the gripper's is the P
layout without Drive Mode, Startup Configuration and Backup Ready, and only the current and
current-based position modes.

Sources: addresses and sizes from the dynamixel-sdk model files (ph*/pm*, *_ra,
rh_p12_rn); initial values, ranges and units from the ROBOTIS e-manual P-series pages
(PH42-020-S300-R, PH54-100-S500-R, PH54-200-S500-R, PM42-010-S260-R, PM54-040-S250-R,
PM54-060-S250-R) and RH-P12-RN(A) page; resolution, gear ratio and datasheet figures from its
_data/dxl_p_info.yml and _data/dxl_proa_info.yml. The PRO(A) control-table values are taken
as their P counterparts' (the same firmware family; the PRO(A) pages were not compared item by
item). Hardware Error Status bits: the e-manual refers to Shutdown, the X's bits.
"""

from dataclasses import dataclass, replace

from dxl_servo_driver.models import modes, xm430
from dxl_servo_driver.models.base import datasheet, Item, Model, Physics
from dxl_servo_driver.models.layout import indirect_items, indirect_pairs, ItemMaker

__all__ = ['GRIPPER', 'MODELS', 'P_MODELS', 'PRO_A_MODELS']

EEPROM_END = 512
LAST_RAM = 1023          # e-manual: Indirect Address entries take 512..1,023
PWM_FULL = 2009          # PWM Limit: 2,009 counts of 0.0498 % (100 %)
INT32_MIN = -(1 << 31)
INT32_MAX = (1 << 31) - 1
# Baud Rate register value -> bit/s (e-manual P series: 0..9, up to 10.5 Mbps).
BAUD_RATES: dict[int, int] = {
    0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000, 6: 4_000_000,
    7: 4_500_000, 8: 6_000_000, 9: 10_500_000,
}
# Indirect Address 1..128 at 168..422 (EEPROM), Indirect Data 1..128 at 634..761.
INDIRECT_PAIRS = indirect_pairs((168, 634, 128))
P_MODES = modes.numbers('current', 'velocity', 'position', 'extended_position', 'pwm')
GRIPPER_MODES = modes.numbers('current', 'current_based_position')


@dataclass(frozen=True)
class _Figures:
    """One model's e-manual figures."""

    current_limit: int             # mA
    acceleration: tuple[int, int]  # (initial, maximum) rev/min^2
    velocity_limit: int            # 0.01 rpm, also the Moving Threshold maximum
    half_turn: int                 # pulses of 180 degrees: the position limits' range
    position_limit: int            # the power-on Max Position Limit (minus for Min)
    gains: tuple[int, int, int, int, int] = (2209, 6153, 0, 0, 314)  # vel I, P; pos D, I, P


_item = ItemMaker(eeprom_end=EEPROM_END)


def _items(number: int, f: _Figures, *, protocol_type: bool, startup: bool, drive_mode: bool,
           backup: bool, mode_initial: int = 3, extra: tuple[Item, ...] = ()) -> tuple[Item, ...]:
    """Return one table of the family; the flags say which optional items it has."""
    current, velocity = f.current_limit, f.velocity_limit
    acceleration_initial, acceleration_max = f.acceleration
    gains = dict(zip(('velocity_i_gain', 'velocity_p_gain', 'position_d_gain',
                      'position_i_gain', 'position_p_gain'), f.gains))
    items = [
        *_item.identity(number),
        _item('id', 7, 1, 'RW', 1, 0, 252, description='Dynamixel ID (254 is broadcast)'),
        _item('baud_rate', 8, 1, 'RW', 1, 0, 9, description='Communication Baud Rate'),
        _item('return_delay_time', 9, 1, 'RW', 250, 0, 254, unit='2 us',
              description='Response Delay Time'),
        _item('operating_mode', 11, 1, 'RW', mode_initial, 0, 16, description='Operating Mode'),
        _item('secondary_id', 12, 1, 'RW', 255, 0, 255,
              description='Secondary ID; 0..252, a value above 252 switches it off'),
        _item('homing_offset', 20, 4, 'RW', 0, INT32_MIN, INT32_MAX, signed=True,
              unit='pulse', description='Home Position Offset'),
        _item('moving_threshold', 24, 4, 'RW', 20, 0, velocity, unit='0.01 rpm',
              description='Velocity Threshold for Movement Detection'),
        _item('temperature_limit', 31, 1, 'RW', 80, 0, 100, unit='degC',
              description='Maximum Internal Temperature Limit'),
        _item('max_voltage_limit', 32, 2, 'RW', 350, 150, 350, unit='0.1 V',
              description='Maximum Voltage Limit'),
        _item('min_voltage_limit', 34, 2, 'RW', 150, 150, 350, unit='0.1 V',
              description='Minimum Voltage Limit'),
        _item('pwm_limit', 36, 2, 'RW', PWM_FULL, 0, PWM_FULL, unit='0.0498 %',
              description='Maximum PWM Limit'),
        _item('current_limit', 38, 2, 'RW', current, 0, current, unit='1 mA',
              description='Maximum Current Limit'),
        _item('acceleration_limit', 40, 4, 'RW', acceleration_initial, 0, acceleration_max,
              unit='1 rev/min^2', description='Maximum Acceleration Limit'),
        _item('velocity_limit', 44, 4, 'RW', velocity, 0, velocity, unit='0.01 rpm',
              description='Maximum Velocity Limit'),
        _item('max_position_limit', 48, 4, 'RW', f.position_limit, -f.half_turn, f.half_turn,
              signed=True, unit='pulse', description='Maximum Position Limit'),
        _item('min_position_limit', 52, 4, 'RW', -f.position_limit, -f.half_turn,
              f.half_turn, signed=True, unit='pulse', description='Minimum Position Limit'),
        # Bits 0 input voltage, 2 overheating, 3 motor encoder, 4 electrical shock, 5 overload.
        _item('shutdown', 63, 1, 'RW', 0x34, 0, 0x3F, description='Shutdown conditions'),
        _item('torque_enable', 512, 1, 'RW', 0, 0, 1, description='Motor Torque On/Off'),
        _item('led_red', 513, 1, 'RW', 0, 0, 0xFF, description='Red LED intensity'),
        _item('led_green', 514, 1, 'RW', 0, 0, 0xFF, description='Green LED intensity'),
        _item('led_blue', 515, 1, 'RW', 0, 0, 0xFF, description='Blue LED intensity'),
        _item('status_return_level', 516, 1, 'RW', 2, 0, 2,
              description='Select Types of Status Return'),
        _item('registered_instruction', 517, 1, 'R', 0, 0, 1,
              description='Check Reception of Instruction'),
        _item('hardware_error_status', 518, 1, 'R', 0, 0, 0xFF,
              description='Hardware Error Status'),
        *(_item(name, address, 2, 'RW', gains.get(name, 0), 0, 32767, description=text)
          for name, address, text in (
              ('velocity_i_gain', 524, 'I Gain of Velocity'),
              ('velocity_p_gain', 526, 'P Gain of Velocity'),
              ('position_d_gain', 528, 'D Gain of Position'),
              ('position_i_gain', 530, 'I Gain of Position'),
              ('position_p_gain', 532, 'P Gain of Position'),
              ('feedforward_2nd_gain', 536, '2nd Gain of Feed-Forward'),
              ('feedforward_1st_gain', 538, '1st Gain of Feed-Forward'))),
        _item('bus_watchdog', 546, 1, 'RW', 0, 0, 127, unit='20 ms',
              description='Bus Watchdog (0 off, 1..127 on); 255 (-1) when it trips'),
        # Goal PWM / Goal Current power on at their limits, as in the XM430 manual.
        _item('goal_pwm', 548, 2, 'RW', PWM_FULL, -PWM_FULL, PWM_FULL, signed=True,
              limit='pwm_limit', unit='0.0498 %', description='Target PWM Value'),
        _item('goal_current', 550, 2, 'RW', current, -current, current, signed=True,
              limit='current_limit', unit='1 mA', description='Target Current Value'),
        _item('goal_velocity', 552, 4, 'RW', 0, -velocity, velocity, signed=True,
              limit='velocity_limit', unit='0.01 rpm', description='Target Velocity Value'),
        _item('profile_acceleration', 556, 4, 'RW', 0, 0, acceleration_max,
              limit='acceleration_limit', unit='1 rev/min^2',
              description='Acceleration Value of Profile'),
        _item('profile_velocity', 560, 4, 'RW', 0, 0, velocity, limit='velocity_limit',
              unit='0.01 rpm', description='Velocity Value of Profile'),
        _item('goal_position', 564, 4, 'RW', 0, INT32_MIN, INT32_MAX, signed=True,
              limit='max_position_limit', unit='pulse',
              description='Target Position Value (min/max_position_limit in mode 3)'),
        _item('realtime_tick', 568, 2, 'R', 0, 0, 32767, unit='ms',
              description='Count Time in millisecond'),
        _item('moving', 570, 1, 'R', 0, 0, 1, description='Movement Status'),
        _item('moving_status', 571, 1, 'R', 0, 0, 0xFF,
              description='Detailed Information of Movement Status'),
        _item('present_pwm', 572, 2, 'R', 0, -PWM_FULL, PWM_FULL, signed=True,
              unit='0.0498 %', description='Present PWM Value'),
        _item('present_current', 574, 2, 'R', 0, -32768, 32767, signed=True, unit='1 mA',
              description='Present Current Value'),
        _item('present_velocity', 576, 4, 'R', 0, INT32_MIN, INT32_MAX, signed=True,
              unit='0.01 rpm', description='Present Velocity Value'),
        _item('present_position', 580, 4, 'R', 0, INT32_MIN, INT32_MAX, signed=True,
              unit='pulse', description='Present Position Value'),
        _item('velocity_trajectory', 584, 4, 'R', 0, INT32_MIN, INT32_MAX, signed=True,
              unit='0.01 rpm', description='Target Velocity Trajectory Generated by Profile'),
        _item('position_trajectory', 588, 4, 'R', 0, INT32_MIN, INT32_MAX, signed=True,
              unit='pulse', description='Target Position Trajectory Generated by Profile'),
        _item('present_input_voltage', 592, 2, 'R', 240, 0, 0xFFFF, unit='0.1 V',
              description='Present Input Voltage'),
        _item('present_temperature', 594, 1, 'R', 25, 0, 0xFF, unit='degC',
              description='Present Internal Temperature'),
        *indirect_items(INDIRECT_PAIRS, LAST_RAM, first_ram_address=EEPROM_END,
                        eeprom_end=EEPROM_END),
        *extra,
    ]
    for n in (1, 2, 3, 4):
        items.append(_item(
            f'external_port_mode_{n}', 55 + n, 1, 'RW', 3, 0, 3,
            description=f'External Port Mode {n} (0 analog in, 1 digital out, '
                        '2 digital in pull-up, 3 digital in pull-down)'))
        items.append(_item(f'external_port_data_{n}', 598 + 2 * n, 2, 'RW', 0, 0, 4095,
                           description=f'External Port Data {n} (12-bit analog or digital)'))
    # The items only some firmware has: (has it, name, address, size, access, initial,
    # minimum, maximum, description).
    optional = (
        # Bits 0 reverse, 2 time-based profile, 3 torque on by goal update (0..13).
        (drive_mode, 'drive_mode', 10, 1, 'RW', 0, 0, 13,
         'Drive Mode (bit 0 reverse, 2 time-based profile, 3 torque on by goal update)'),
        # 2 is DYNAMIXEL Protocol 2.0, 10 Modbus-RTU.
        (protocol_type, 'protocol_version', 13, 1, 'RW', 2, 2, 10,
         'Protocol Type (2 Protocol 2.0, 10 Modbus-RTU)'),
        (startup, 'startup_configuration', 60, 1, 'RW', 0, 0, 3,
         'Startup Configuration (bit 0 torque on at boot, bit 1 RAM restore)'),
        (backup, 'backup_ready', 878, 1, 'R', 0, 0, 1, 'Backup Ready (a RAM backup is stored)'),
    )
    items.extend(_item(*row[1:-1], description=row[-1]) for row in optional if row[0])
    return tuple(sorted(items, key=lambda each: each.address))


def _model(number: int, name: str, family: str, items: tuple[Item, ...],
           pulses_per_rev: int, model_modes: dict[str, int], physics: Physics) -> Model:
    return Model(
        number=number, name=name, family=family, items=items, modes=dict(model_modes),
        bauds=dict(BAUD_RATES), current_unit_a=0.001, load_unit_ratio=None,
        velocity_unit_rpm=0.01, pulses_per_rev=pulses_per_rev, position_zero_raw=0,
        pwm_full_raw=PWM_FULL, voltage_unit_v=0.1, indirect=INDIRECT_PAIRS,
        hardware_error_bits=dict(xm430.HARDWARE_ERROR_BITS), physics=physics,
        fast_sync_read_firmware=None, eeprom_end=EEPROM_END,
        # Profile Acceleration counts 1 rev/min^2; Goal Position in the multi-turn modes takes
        # the whole int32; the e-manual states no position-mode limit on the Homing Offset.
        acceleration_unit_rpm2=1.0, extended_position_limit=INT32_MAX,
        homing_position_mode_limit=None,
        # Drive Mode bit 2: a time-based profile (where the table has a Drive Mode).
        time_profile_bit=2 if any(each.name == 'drive_mode' for each in items) else None)


# The datasheets publish continuous (rated) torque and current, not stall figures: those
# stand in for the stall point (their ratio is the torque constant), with the no-load speed.
_CONT = ('ROBOTIS e-manual {} specifications (_data/dxl_p_info.yml): continuous torque and '
         'current stand in for the unpublished stall figures')
# name, P number, PRO(A) number and name, pulses per revolution, figures, physics
# (gear ratio; N.m, A, no-load rpm at 24 V).
_P_TABLE: tuple[tuple[str, int, int, str, int, _Figures, tuple[float, float, float, float]],
                ...] = (
    ('PH42-020-S300-R', 2000, 51201, 'H42-20-S300-R(A)', 607_500,
     _Figures(4500, (10765, 4_306_173), 2920, 303_750, 303_454), (303.75, 5.1, 1.5, 32.7)),
    ('PH54-100-S500-R', 2010, 53769, 'H54-100-S500-R(A)', 1_003_846,
     _Figures(15900, (10639, 4_255_632), 2920, 501_923, 501_433), (501.923, 25.3, 5.5, 33.3)),
    ('PH54-200-S500-R', 2020, 54025, 'H54-200-S500-R(A)', 1_003_846,
     _Figures(22740, (3_992_644, 3_992_644), 2900, 501_923, 501_433),
     (501.923, 44.7, 9.3, 33.1)),
    ('PM42-010-S260-R', 2100, 43289, 'M42-10-S260-R(A)', 526_374,
     _Figures(1461, (10867, 4_346_756), 2600, 263_187, 262_931), (257.019, 1.7, 0.6, 28.0)),
    ('PM54-040-S250-R', 2110, 46097, 'M54-40-S250-R(A)', 502_834,
     _Figures(4470, (11037, 4_414_976), 2840, 251_417, 251_173), (251.417, 3.9, 1.9, 28.4)),
    ('PM54-060-S250-R', 2120, 46353, 'M54-60-S250-R(A)', 502_834,
     _Figures(7980, (11145, 4_457_932), 2830, 251_417, 251_173), (251.417, 10.1, 3.0, 33.1)),
)


def _physics(name: str, figures: tuple[float, float, float, float]) -> Physics:
    gear, torque, current, speed = figures
    return datasheet(gear, 24.0, ((24.0, torque, current, speed),), _CONT.format(name))


P_MODELS: tuple[Model, ...] = tuple(
    _model(number, name, 'P', _items(number, figures, protocol_type=True, startup=True,
                                     drive_mode=True, backup=True),
           pulses, P_MODES, _physics(name, physics))
    for name, number, _, _, pulses, figures, physics in _P_TABLE)
PRO_A_MODELS: tuple[Model, ...] = tuple(
    _model(number, name, 'PRO(A)', _items(number, figures, protocol_type=False, startup=False,
                                          drive_mode=True, backup=False),
           pulses, P_MODES, _physics(name, physics))
    for _, _, number, name, pulses, figures, physics in _P_TABLE)

# RH-P12-RN(A), the gripper on this firmware (model 35074; the older RH-P12-RN, 35073, has
# the PRO layout and is refused). The e-manual page: positions 0 (open) .. 1,150 (closed);
# Current Limit 1,984 mA; Velocity Limit and Moving Threshold maximum 2,970; Acceleration
# Limit 3,447 of 0..1,378,788; Operating Mode 5 at power-on. Its voltage limits read 150..300
# with an initial 350: the P range 150..350 is kept. Its gains are '-': the PH54-200's assumed.
_GRIPPER_FIGURES = _Figures(1984, (3447, 1_378_788), 2970, 1150, 1150)


def _gripper() -> Model:
    items = {each.name: each for each in _items(
        35074, _GRIPPER_FIGURES, protocol_type=True, startup=False, drive_mode=False,
        backup=False, mode_initial=5)}
    # Positions of the finger drive, not of a turn: 0..1,150, homing offset likewise.
    items['max_position_limit'] = _item(
        'max_position_limit', 48, 4, 'RW', 1150, 0, 1150, signed=True, unit='pulse',
        description='Maximum Position Limit (1,150 closed)')
    items['min_position_limit'] = _item(
        'min_position_limit', 52, 4, 'RW', 0, 0, 1150, signed=True, unit='pulse',
        description='Minimum Position Limit (0 open)')
    items['homing_offset'] = _item('homing_offset', 20, 4, 'RW', 0, 0, 1150, signed=True,
                                   unit='pulse', description='Home Position Offset')
    items['moving_threshold'] = _item('moving_threshold', 24, 4, 'RW', 80, 0, 2970,
                                      unit='0.01 rpm',
                                      description='Velocity Threshold for Movement Detection')
    physics = datasheet(1181.0, 24.0, ((24.0, 1.7, 3.33, 29.7),),
                        'ROBOTIS e-manual RH-P12-RN(A) specifications give 1181:1, 24 V, a '
                        '3.33 A peak current and a 170 N maximum grip force, no torque nor '
                        'speed: assumed 1.7 N.m (170 N at 10 mm) at 3.33 A, and the Velocity '
                        'Limit 29.7 rpm as the no-load speed')
    # Its encoder is a 12-bit absolute one (4,096 per turn of the drive); the SDK's type info
    # maps 740 pulses to 1.099 rad instead (about 4,231 per turn): the e-manual's is kept.
    gripper = _model(35074, 'RH-P12-RN(A)', 'RH-P12-RN',
                     tuple(sorted(items.values(), key=lambda each: each.address)), 4096,
                     GRIPPER_MODES, physics)
    # No multi-turn: its current-based position mode reaches the finger's travel only.
    return replace(gripper, extended_position_limit=1150)


GRIPPER = _gripper()
MODELS: tuple[Model, ...] = (*P_MODELS, *PRO_A_MODELS, GRIPPER)
