"""
The DYNAMIXEL-Y series (YM070-210 and YM080-230, each -M001, -B001, -R051, -R099, -A051, -A099).

One firmware table for all twelve: the SDK ships twelve identical model files. -M001 drives the
output directly, -B001 adds a spring-applied brake, -R051/-R099 a 51:1 or 99:1 reducer,
-A051/-A099 the reducer and the brake. They differ in the figures that follow from the
gear and the frame size (limits, thresholds, Electronic Gear Ratio, brake timing) and in
their datasheets.

The e-manual gives each item its own area rather than splitting the table by address:
EEPROM (written with torque off only), RAM, and Hybrid (gains and profiles: writable whatever
the torque, kept through power-off). Hybrid items are 'ram' here: `Item.area` says whether a
write needs torque off, and they do not. eeprom_end is 512: every item from it on is RAM,
while below it items are EEPROM, RAM or Hybrid each as stated (Bus Watchdog, Status Return
Level, Controller State, Error Code, Hybrid Save are RAM).

Units: positions count 524,288 per output turn with zero at raw 0 on every model, geared or
not: the Electronic Gear Ratio (96/100, factory set to the reducer's ratio) scales Present
/Goal Position and Velocity to the output (the e-manual: goal values are multiplied by it
before the controller sees them; the limits and thresholds of the geared pages are the
direct-drive ones divided by the gear; ROBOTIS's dynamixel_hardware_interface counts
2*pi/524,288 rad per pulse on the YM080-230-R099). The datasheet's 'resolution' of 26,738,688
or 51,904,512 pulses per turn is the motor encoder seen at the output, not the register's
unit. These units hold while Electronic Gear Ratio keeps its factory value. Velocity 0.01 rpm
at the output, current 0.01 A, PWM 0.1 % (1,000 full), Profile Acceleration 10 rev/min^2,
Present Input Voltage 0.01 V but the voltage limits 0.1 V (Model.limit_voltage_unit_v).

Modes: 0 current, 1 velocity, 3 position; no extended position nor PWM mode. Position mode is
multi-turn: goals within Min/Max Position Limit (any int32), and Present Position is the
absolute multi-turn count the servo keeps through power-off (a battery-backed counter; the
Clear instruction zeroes it), not a position within one turn.

Errors: Error Code (153) holds one code (1 over voltage .. 20 position limit reached), not bits,
with Controller State (152) and a 16-entry history; there is no Hardware Error Status and no
Shutdown register, hence no hardware_error_bits. No Moving register either: Moving Status
(541) bit 2 is 'moving'.

Sources: addresses and sizes from the dynamixel-sdk model files (ym070_210_*.model,
ym080_230_*.model, all alike); areas, initial values, ranges and units from the ROBOTIS
e-manual YM070-210-*/YM080-230-* control tables (each of the twelve pages read); meanings from
its control-table item pages (_includes/en/dxl/y); datasheet figures from _data/dxl_y_info.yml.
Where the sources disagree the choice is commented at the item. Fast Sync Read: the e-manual
does not list it for the Y, so none.
"""

from dataclasses import dataclass

from dxl_servo_driver.models import modes
from dxl_servo_driver.models.base import datasheet, Item, Model, Physics
from dxl_servo_driver.models.layout import indirect_pairs, ItemMaker

__all__ = ['FAMILY', 'MODELS', 'ROLES']

FAMILY = 'Y'
EEPROM_END = 512
LAST_ADDRESS = 919       # Backup Ready: the end of the table, and of the indirect range
PULSES_PER_REV = 524_288
PWM_FULL = 1000          # PWM Limit: 1,000 counts of 0.1 %
CURRENT_LIMIT = 2080     # 0.01 A
INT32_MIN = -(1 << 31)
INT32_MAX = (1 << 31) - 1
EGEAR_MAX = 1_045_576
EEPROM, RAM = 'eeprom', 'ram'
# Hybrid (the e-manual's third area): written whatever the torque, so RAM to the driver.
HYBRID = RAM
# Baud Rate (Bus) value -> bit/s (the e-manual; value 7 runs at 4,421,053, -1.2 %).
BAUD_RATES: dict[int, int] = {
    0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000, 6: 4_000_000,
    7: 4_500_000, 8: 6_000_000, 9: 10_500_000,
}
# Indirect Address 1..128 at 256..510 (EEPROM), Indirect Data 1..128 at 634..761 (RAM).
INDIRECT_PAIRS = indirect_pairs((256, 634, 128))
Y_MODES = modes.numbers('current', 'velocity', 'position')
# The driver's (XM430 manual's) name -> the Y's own: same meaning, another name.
ROLES: dict[str, str] = {
    'baud_rate': 'baud_rate_bus',
    'protocol_version': 'protocol_type',
    'secondary_id': 'secondary_shadow_id',
    # Two temperatures, two limits: the motor's is the one the X's single pair stands for
    # (its overheating error stops the motor), the inverter's stays under its own name.
    'present_temperature': 'present_motor_temperature',
    'temperature_limit': 'motor_temperature_limit',
}
# Gains (Hybrid, 4 bytes, 0..2^31-1), the same on every page: velocity I, P, FF; position D,
# I, P, FF. Position FF and Velocity FF are not the X's feedforward 1st/2nd gains: unmapped.
GAINS: tuple[tuple[str, int, int, str], ...] = (
    ('velocity_i_gain', 212, 2_446_559, 'Velocity I Gain'),
    ('velocity_p_gain', 216, 24_778, 'Velocity P Gain'),
    ('velocity_ff_gain', 220, 0, 'Velocity FF Gain'),
    ('position_d_gain', 224, 9_090, 'Position D Gain'),
    ('position_i_gain', 228, 0, 'Position I Gain'),
    ('position_p_gain', 232, 6_283_185, 'Position P Gain'),
    ('position_ff_gain', 236, 0, 'Position FF Gain'))


@dataclass(frozen=True)
class _Figures:
    """One model's page: what differs from its siblings."""

    number: int
    name: str
    gear: int                           # Electronic Gear Ratio Numerator (the reducer)
    brake: bool                         # -B001, -A0xx
    threshold: int                      # In-Position and Moving Threshold
    motor_temperature_limit: int        # degC
    acceleration: tuple[int, int]       # Acceleration Limit initial, maximum (10 rev/min^2)
    velocity: tuple[int, int]           # Velocity Limit initial, maximum (0.01 rpm)
    physics: tuple[float, float, float]  # maximum torque N.m, maximum current A, no-load rpm


_make = ItemMaker(eeprom_end=EEPROM_END)


def _item(name: str, address: int, size: int, area: str, access: str, initial: int,
          minimum: int, maximum: int, unit: str = '', description: str = '', *,
          signed: bool = False, limit: str | None = None) -> Item:
    # The Y's page states each item's area (some below 512 are RAM, some both: HYBRID) and
    # gives unit and description as columns: its rows keep that order.
    return _make(name, address, size, access, initial, minimum, maximum, signed=signed,
                 limit=limit, unit=unit, description=description, area=area)


def _s32(name: str, address: int, area: str, access: str, initial: int, unit: str,
         description: str, limit: str | None = None) -> Item:
    return _item(name, address, 4, area, access, initial, INT32_MIN, INT32_MAX, unit,
                 description, signed=True, limit=limit)


def _items(f: _Figures) -> tuple[Item, ...]:
    """Return one model's table from its page's figures."""
    acceleration, acceleration_max = f.acceleration
    velocity, velocity_max = f.velocity
    # Brake timing: the braked models engage their brake 20 ms after torque off and wait
    # 200 ms before taking goals; excitation in %, times in ms.
    brake_delay, goal_delay, excitation, overexcitation_ms = (
        (20, 200, 30, 200) if f.brake else (0, 0, 0, 0))
    items = [
        _item('model_number', 0, 2, EEPROM, 'R', f.number, 0, 0xFFFF,
              description='Model Number'),
        _item('model_information', 2, 4, EEPROM, 'R', 0, 0, 0xFFFFFFFF,
              description='Model Information'),
        # '-' in the e-manual: the simulator reports 0.
        _item('firmware_version', 6, 1, EEPROM, 'R', 0, 0, 0xFF,
              description='Firmware Version'),
        _item('id', 7, 1, EEPROM, 'RW', 1, 0, 252, description='ID (254 is broadcast)'),
        # 2 bytes on the Y (1 on the X); the servo writes -1 when it trips, hence signed.
        _item('bus_watchdog', 8, 2, RAM, 'RW', 0, 0, 127, '20 ms',
              'Bus Watchdog (0 off, 1..127 on); -1 when it trips', signed=True),
        # The e-manual's range is 0..252 with an initial 255: above 252 switches it off.
        _item('secondary_shadow_id', 10, 1, EEPROM, 'RW', 255, 0, 255,
              description='Secondary(Shadow) ID; 0..252, above 252 off'),
        # The table's range is 2 only: Modbus-RTU (10) is announced as TBD.
        _item('protocol_type', 11, 1, EEPROM, 'RW', 2, 2, 2,
              description='Protocol Type (2 DYNAMIXEL Protocol 2.0)'),
        _item('baud_rate_bus', 12, 1, EEPROM, 'RW', 1, 0, 9,
              description='Baud Rate (Bus)'),
        _item('return_delay_time', 13, 1, EEPROM, 'RW', 250, 0, 254, '2 us',
              'Return Delay Time'),
        _item('status_return_level', 15, 1, RAM, 'RW', 2, 0, 2,
              description='Status Return Level'),
        _item('registered_instruction', 16, 1, RAM, 'R', 0, 0, 1,
              description='Registered Instruction'),
        # Bits 0 reverse, 2 time-based profile, 6 dynamic brake at torque off (0..77: the
        # table's range also admits bit 3, which the bit list calls unused).
        _item('drive_mode', 32, 1, EEPROM, 'RW', 0, 0, 77,
              description='Drive Mode (bit 0 reverse, 2 time-based profile, 6 dynamic brake)'),
        _item('operating_mode', 33, 1, EEPROM, 'RW', 3, 0, 3,
              description='Operating Mode (0 current, 1 velocity, 3 position)'),
        _item('startup_configuration', 34, 1, EEPROM, 'RW', 0, 0, 1,
              description='Startup Configuration (bit 0 torque on at boot)'),
        _item('position_limit_threshold', 38, 2, EEPROM, 'RW', 0, 0, 32767, 'pulse',
              'Position Limit Threshold (beyond the limits by more: error 20)'),
        _item('in_position_threshold', 40, 4, EEPROM, 'RW', f.threshold, 0, INT32_MAX,
              'pulse', 'In-Position Threshold'),
        _item('following_error_threshold', 44, 4, EEPROM, 'RW', 0, 0, INT32_MAX, 'pulse',
              'Following Error Threshold (0 off)'),
        # Compared with Present Velocity; the table's unit reads '5 pulse/ms', its item page's
        # '1 pulse': kept as the table gives it.
        _item('moving_threshold', 48, 4, EEPROM, 'RW', f.threshold, 0, INT32_MAX,
              '5 pulse/ms', 'Moving Threshold (Moving Status bit 2 above it)'),
        _s32('homing_offset', 52, EEPROM, 'RW', 0, 'pulse',
             'Homing Offset (added to the actual position)'),
        _item('inverter_temperature_limit', 56, 1, EEPROM, 'RW', 80, 0, 100, 'degC',
              'Inverter Temperature Limit'),
        _item('motor_temperature_limit', 57, 1, EEPROM, 'RW', f.motor_temperature_limit, 0,
              100, 'degC', 'Motor Temperature Limit'),
        _item('max_voltage_limit', 60, 2, EEPROM, 'RW', 320, 240, 400, '0.1 V',
              'Max Voltage Limit'),
        # 2 bytes (the SDK model file); the e-manual's 4 would overlap PWM Limit at 64.
        _item('min_voltage_limit', 62, 2, EEPROM, 'RW', 160, 160, 400, '0.1 V',
              'Min Voltage Limit'),
        _item('pwm_limit', 64, 2, EEPROM, 'RW', PWM_FULL, 0, PWM_FULL, '0.1 %', 'PWM Limit'),
        # Every page, the YM080 ones included, gives 0..2,080 (20.8 A), although the YM080
        # datasheet's maximum current is 22.4 A and an unused include page gives it 0..2,240:
        # the pages' table is kept.
        _item('current_limit', 66, 2, EEPROM, 'RW', CURRENT_LIMIT, 0, CURRENT_LIMIT, '0.01 A',
              'Current Limit'),
        _item('acceleration_limit', 68, 4, EEPROM, 'RW', acceleration, 0, acceleration_max,
              '10 rev/min^2', 'Acceleration Limit'),
        _item('velocity_limit', 72, 4, EEPROM, 'RW', velocity, 0, velocity_max, '0.01 rpm',
              'Velocity Limit'),
        _s32('max_position_limit', 76, EEPROM, 'RW', PULSES_PER_REV // 2, 'pulse',
             'Max Position Limit'),
        _s32('min_position_limit', 84, EEPROM, 'RW', -PULSES_PER_REV // 2, 'pulse',
             'Min Position Limit'),
        # Motor pulses per register pulse = Numerator / Denominator: the units above hold at
        # the factory values (the reducer's ratio over 1).
        _item('electronic_gearratio_numerator', 96, 4, EEPROM, 'RW', f.gear, 1, EGEAR_MAX,
              description='Electronic Gear Ratio Numerator'),
        _item('electronic_gearratio_denominator', 100, 4, EEPROM, 'RW', 1, 1, EGEAR_MAX,
              description='Electronic Gear Ratio Denominator'),
        _item('safe_stop_time', 104, 2, EEPROM, 'RW', 200, 0, 32767, 'ms', 'Safe Stop Time'),
        _item('brake_delay', 106, 2, EEPROM, 'RW', brake_delay, 0, 32767, 'ms',
              'Brake Delay'),
        _item('goal_update_delay', 108, 2, EEPROM, 'RW', goal_delay, 0, 32767, 'ms',
              'Goal Update Delay (after the brake releases)'),
        _item('overexcitation_voltage', 110, 1, EEPROM, 'RW', 100, 0, 100, '%',
              'Overexcitation Voltage (brake)'),
        _item('normal_excitation_voltage', 111, 1, EEPROM, 'RW', excitation, 0, 100, '%',
              'Normal Excitation Voltage (brake)'),
        _item('overexcitation_time', 112, 2, EEPROM, 'RW', overexcitation_ms, 0, 32767, 'ms',
              'Overexcitation Time (brake)'),
        _item('present_velocity_lpf_frequency', 132, 2, EEPROM, 'RW', 0, 0, 32767, '0.1 Hz',
              'Present Velocity LPF Frequency'),
        _item('goal_current_lpf_frequency', 134, 2, EEPROM, 'RW', 0, 0, 32767, '0.1 Hz',
              'Goal Current LPF Frequency'),
        _item('position_ff_lpf_time', 136, 2, EEPROM, 'RW', 0, 0, 512, '0.2 ms',
              'Position FF LPF Time'),
        _item('velocity_ff_lpf_time', 138, 2, EEPROM, 'RW', 0, 0, 512, '0.2 ms',
              'Velocity FF LPF Time'),
        _item('controller_state', 152, 1, RAM, 'R', 0, 0, 0xFF,
              description='Controller State (5 running, 8 hardware fault)'),
        _item('error_code', 153, 1, RAM, 'R', 0, 0, 0xFF,
              description='Error Code (0 none; one code, not bits)'),
        *(_item(f'error_code_history_{n}', 153 + n, 1, RAM, 'R', 0, 0, 0xFF,
                description=f'Error Code History {n}') for n in range(1, 17)),
        _item('hybrid_save', 170, 1, RAM, 'RW', 0, 0, 2,
              description='Hybrid Save (0 changed, 1 save request, 2 saved)'),
        *(_item(name, address, 4, HYBRID, 'RW', initial, 0, INT32_MAX, description=text)
          for name, address, initial, text in GAINS),
        _item('profile_acceleration', 240, 4, HYBRID, 'RW', acceleration, 0, acceleration_max,
              '10 rev/min^2', 'Profile Acceleration', limit='acceleration_limit'),
        _item('profile_velocity', 244, 4, HYBRID, 'RW', velocity, 0, velocity_max,
              '0.01 rpm', 'Profile Velocity (0: no profile)', limit='velocity_limit'),
        _item('profile_acceleration_time', 248, 4, HYBRID, 'RW', 400, 0, 262_144, '0.2 ms',
              'Profile Acceleration Time (time-based profile)'),
        _item('profile_time', 252, 4, HYBRID, 'RW', 800, 0, 524_288, '0.2 ms',
              'Profile Time (time-based profile)'),
        _item('torque_enable', 512, 1, RAM, 'RW', 0, 0, 1, description='Torque Enable'),
        _item('led', 513, 1, RAM, 'RW', 0, 0, 1, description='LED'),
        _item('pwm_offset', 516, 2, RAM, 'RW', 0, -PWM_FULL, PWM_FULL, '0.1 %', 'PWM Offset',
              signed=True, limit='pwm_limit'),
        _item('current_offset', 518, 2, RAM, 'RW', 0, -CURRENT_LIMIT, CURRENT_LIMIT,
              '0.01 A', 'Current Offset', signed=True, limit='current_limit'),
        _item('velocity_offset', 520, 4, RAM, 'RW', 0, -velocity_max, velocity_max,
              '0.01 rpm', 'Velocity Offset', signed=True, limit='velocity_limit'),
        # Goal PWM and Goal Current power on at 0 (the e-manual), not at their limits.
        _item('goal_pwm', 524, 2, RAM, 'RW', 0, -PWM_FULL, PWM_FULL, '0.1 %', 'Goal PWM',
              signed=True, limit='pwm_limit'),
        _item('goal_current', 526, 2, RAM, 'RW', 0, -CURRENT_LIMIT, CURRENT_LIMIT, '0.01 A',
              'Goal Current', signed=True, limit='current_limit'),
        _item('goal_velocity', 528, 4, RAM, 'RW', 0, -velocity_max, velocity_max, '0.01 rpm',
              'Goal Velocity', signed=True, limit='velocity_limit'),
        _s32('goal_position', 532, RAM, 'RW', 0, 'pulse',
             'Goal Position (within Min/Max Position Limit)', limit='max_position_limit'),
        _item('moving_status', 541, 1, RAM, 'R', 0, 0, 0xFF,
              description='Moving Status (bit 0 in position, 1 profile ongoing, 2 moving, '
                          '3 following error, 4-5 profile type, 6 within the limits)'),
        _item('realtime_tick', 542, 2, RAM, 'R', 0, 0, 32767, 'ms',
              'Realtime Tick (wraps to 0 after 32,767)'),
        _item('present_pwm', 544, 2, RAM, 'R', 0, -PWM_FULL, PWM_FULL, '0.1 %', 'Present PWM',
              signed=True),
        _item('present_current', 546, 2, RAM, 'R', 0, -32768, 32767, '0.01 A',
              'Present Current', signed=True),
        _s32('present_velocity', 548, RAM, 'R', 0, '0.01 rpm', 'Present Velocity'),
        _s32('present_position', 552, RAM, 'R', 0, 'pulse',
             'Present Position (absolute multi-turn)'),
        _s32('position_trajectory', 560, RAM, 'R', 0, 'pulse', 'Position Trajectory'),
        # The table's unit is '1 pulse/s', but its item page has it equal Goal Velocity at a
        # velocity profile's end: Goal Velocity's unit is kept.
        _s32('velocity_trajectory', 564, RAM, 'R', 0, '0.01 rpm', 'Velocity Trajectory'),
        # '-' in the e-manual: the simulator powers on at the nominal 24.00 V.
        _item('present_input_voltage', 568, 2, RAM, 'R', 2400, 0, 0xFFFF, '0.01 V',
              'Present Input Voltage'),
        _item('present_inverter_temperature', 570, 1, RAM, 'R', 25, 0, 0xFF, 'degC',
              'Present Inverter Temperature'),
        _item('present_motor_temperature', 571, 1, RAM, 'R', 25, 0, 0xFF, 'degC',
              'Present Motor Temperature'),
        _item('backup_ready', 919, 1, RAM, 'R', 0, 0, 1, description='Backup Ready'),
    ]
    # The e-manual's indirect range is 0..919: any item, EEPROM and Hybrid ones included.
    for n, (address, data) in enumerate(INDIRECT_PAIRS, start=1):
        items.append(_item(f'indirect_address_{n}', address, 2, EEPROM, 'RW', data, 0,
                           LAST_ADDRESS, description=f'Indirect Address {n} (0..919)'))
        items.append(_item(f'indirect_data_{n}', data, 1, RAM, 'RW', 0, 0, 0xFF,
                           description=f'Indirect Data {n}'))
    return tuple(sorted(items, key=lambda each: each.address))


# The datasheets give continuous and maximum torque and current and the no-load speed, all at
# 24 V; the maximum (peak) figures stand in for the stall point, whose ratio is the torque
# constant (the continuous ones give about 15 % less).
_SOURCE = ('ROBOTIS e-manual {} specifications (_data/dxl_y_info.yml): maximum torque and '
           'current as the stall point, 24 V only')


def _model(f: _Figures) -> Model:
    torque, current, speed = f.physics
    physics: Physics = datasheet(float(f.gear), 24.0, ((24.0, torque, current, speed),),
                                 _SOURCE.format(f.name + '-RH'))
    return Model(
        number=f.number, name=f.name, family=FAMILY, items=_items(f), modes=dict(Y_MODES),
        bauds=dict(BAUD_RATES), current_unit_a=0.01, load_unit_ratio=None,
        velocity_unit_rpm=0.01, pulses_per_rev=PULSES_PER_REV, position_zero_raw=0,
        pwm_full_raw=PWM_FULL, voltage_unit_v=0.01, indirect=INDIRECT_PAIRS,
        hardware_error_bits={}, physics=physics, fast_sync_read_firmware=None,
        roles=dict(ROLES), acceleration_unit_rpm2=10.0,
        # No extended position mode; position mode's goals span the int32 limits. The
        # e-manual states no position-mode rule on the Homing Offset.
        extended_position_limit=INT32_MAX, homing_position_mode_limit=None,
        eeprom_end=EEPROM_END, limit_voltage_unit_v=0.1)


# Per page: number, name, gear, brake, thresholds, motor temperature limit, Acceleration
# Limit and Velocity Limit (initial, maximum: a geared model's maxima are the direct-drive
# ones divided by its gear), datasheet (max N.m, max A, no-load rpm).
_070, _080 = (44_000, 38_520_000), (24_800, 21_336_000)
MODELS: tuple[Model, ...] = tuple(_model(figures) for figures in (
    _Figures(4000, 'YM070-210-M001', 1, False, 1000, 80, _070, (550_000, 642_200),
             (0.64, 20.8, 5675)),
    _Figures(4010, 'YM070-210-B001', 1, True, 1000, 80, _070, (550_000, 642_200),
             (0.64, 20.8, 5675)),
    _Figures(4020, 'YM070-210-R051', 51, False, 19, 60, (313, 755_294), (3921, 12_592),
             (16.3, 20.8, 111.3)),
    _Figures(4030, 'YM070-210-R099', 99, False, 10, 60, (161, 389_090), (2020, 6486),
             (31.7, 20.8, 57.3)),
    _Figures(4040, 'YM070-210-A051', 51, True, 19, 60, (313, 755_294), (3921, 12_592),
             (16.3, 20.8, 111.3)),
    _Figures(4050, 'YM070-210-A099', 99, True, 10, 60, (161, 389_090), (2020, 6486),
             (31.7, 20.8, 57.3)),
    _Figures(4120, 'YM080-230-M001', 1, False, 1000, 80, _080, (310_000, 355_600),
             (1.24, 22.4, 3190)),
    _Figures(4130, 'YM080-230-B001', 1, True, 1000, 80, _080, (310_000, 355_600),
             (1.24, 22.4, 3190)),
    _Figures(4140, 'YM080-230-R051', 51, False, 19, 60, (313, 418_352), (3921, 6972),
             (31.6, 22.4, 62.5)),
    _Figures(4150, 'YM080-230-R099', 99, False, 10, 60, (161, 215_515), (2020, 3591),
             (61.4, 22.4, 32.2)),
    _Figures(4160, 'YM080-230-A051', 51, True, 19, 60, (313, 418_352), (3921, 6972),
             (31.6, 22.4, 62.5)),
    _Figures(4170, 'YM080-230-A099', 99, True, 10, 60, (161, 215_515), (2020, 3591),
             (61.4, 22.4, 32.2)),
))
