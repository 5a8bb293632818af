"""
The supported DYNAMIXEL models: the X series here, the other families from their modules.

Every X model is stated as its differences from the XM430 manual; the MX(2.0) (models.mx)
are too; the P, PRO(A) and RH-P12-RN(A) (models.pro), the PRO on its original firmware and
the first RH-P12-RN (models.pro_legacy), the Y (models.y), the XL-320
(models.xl320) and the Protocol 1.0 models (models.protocol1) have their own layouts. catalog
indexes them all by model number and names the refused ones.

Sources: the XM430 manual and models/xm430.py (authority for 1020 and 1030), the ROBOTIS
model files shipped with dynamixel-sdk 4.1 (addresses and sizes of every model) and the
ROBOTIS e-manual (initial values, ranges, units, datasheet figures).  Where they disagree
the choice is commented at the figure; the manual's own differences are in MANUAL_DIFFERENCES.

Items that later firmware introduced (Drive Mode and Bus Watchdog from v38, Startup
Configuration and Backup Ready from v45, v46 on the X330) are in every table, as the SDK's
model files carry Drive Mode regardless of firmware; tables split by firmware only where
the model files do (the X330's indirect block).
"""

from dataclasses import dataclass, field

from dxl_servo_driver.models import modes, mx, pro, pro_legacy, protocol1, xl320, xm430, y
from dxl_servo_driver.models.base import Item, Model, ModelError, Physics, VoltagePoint
from dxl_servo_driver.models.layout import (
    build, indirect_items, indirect_pairs, is_indirect, item, Overrides, Value)
from dxl_servo_driver.models.names import OTHER_MODELS

__all__ = ['ALL_MODELS', 'FAMILIES', 'MANUAL_DIFFERENCES', 'model_for', 'model_named',
           'SUPPORTED', 'unsupported_reason', 'X_MODELS']

X_FAMILIES: tuple[str, ...] = (
    'XM430/XH430/XD430', 'XM540/XH540/XD540', 'XW430/XW540', 'XL430/2XL430/XC430/2XC430',
    'XL330/XC330/XM335')
# The families as the refusal text and docs/servos.md name them.
FAMILIES: tuple[str, ...] = (
    *X_FAMILIES, 'MX-28/64/106(2.0)', 'P (PH42/PH54/PM42/PM54)', 'PRO(A)',
    'PRO (H42/H54/M42/M54/L42/L54)', 'RH-P12-RN/RH-P12-RN(A)',
    'Y (YM070-210/YM080-230)', 'XL-320', 'AX-12A/12W/18A', 'RX-10/24F/28/64', 'EX-106+',
    'DX-113/116/117', 'MX-12W/28/64/106(1.0)')

SIX_MODES: dict[str, int] = modes.numbers(*modes.NAMES)
# XL430/XC430 have no current sensing, hence no current nor current-based position mode.
FOUR_MODES: dict[str, int] = modes.numbers('velocity', 'position', 'extended_position', 'pwm')
BAUDS_4M5: dict[int, int] = dict(xm430.BAUD_RATES)
# The X330 stops at 4 Mbps: its Baud Rate register takes 0..6.
BAUDS_4M: dict[int, int] = {value: bps for value, bps in xm430.BAUD_RATES.items() if value <= 6}

MANUAL_FIRMWARE = xm430.FIRMWARE_VERSION
# Protocol 2.0 e-manual, Fast Sync Read (0x8A): X430/X540 from firmware v45 (not the 2XL and
# 2XC), X330 from v46.
FAST_SYNC_X = 45
FAST_SYNC_X330 = 46
# The SDK's *_fw52.model files hold the X330 tables up to firmware 52; the plain files the
# later ones (dynamixel_hardware_interface picks *_fwNN for firmware <= NN).
X330_NEW_INDIRECT_FIRMWARE = 53

GAIN_MAX = 16_383          # e-manual gain range (the manual allows 0..32,767, kept for 1020/1030)
PROFILE_MAX = 32_767       # e-manual: time-based profiles count milliseconds up to this
TIME_PROFILE_BIT = 2       # Drive Mode bit 2: time-based profile (firmware v42 on)
LAST_RAM_X = xm430.TABLE_SIZE - 1


def _drive_mode(maximum: int) -> Item:
    # Valid bits per the e-manual's drive-mode table: 0 reverse, 1 master/slave (X540 only),
    # 2 time-based profile (v42+), 3 torque on by goal update (v45+, v46+ on the X330).
    return item('drive_mode', 10, 1, 'RW', 0, 0, maximum,
                description='Drive Mode (bit 0 reverse, 1 dual-joint slave, 2 time-based '
                            'profile, 3 torque on by goal update)')


SECONDARY_ID = item(
    'secondary_id', 12, 1, 'RW', 255, 0, 255,
    description='Secondary (Shadow) ID; 0..252, a value above 252 switches it off')
STARTUP_CONFIGURATION = item(
    'startup_configuration', 60, 1, 'RW', 0, 0, 3,
    description='Startup Configuration (bit 0 torque on at boot, bit 1 RAM restore)')
BUS_WATCHDOG = item(
    'bus_watchdog', 98, 1, 'RW', 0, 0, 127, unit='20 ms',
    description='Bus Watchdog (0 off, 1..127 on); the servo writes 255 (-1) when it trips')
BACKUP_READY = item('backup_ready', 147, 1, 'R', 0, 0, 1,
                    description='Backup Ready (a RAM backup is stored)')
PRESENT_LOAD = item(
    'present_load', 126, 2, 'R', 0, -1000, 1000, signed=True, unit='0.1 %',
    description='Present Load (share of the maximum output torque, sign is direction)')


def _external_ports() -> list[Item]:
    ports = []
    for n in (1, 2, 3):
        ports.append(item(
            f'external_port_mode_{n}', 55 + n, 1, 'RW', 3, 0, 3,
            description=f'External Port Mode {n} (0 analog in, 1 digital out, '
                        '2 digital in pull-up, 3 digital in pull-down)'))
        ports.append(item(
            f'external_port_data_{n}', 150 + 2 * n, 2, 'RW', 0, 0, 4095,
            description=f'External Port Data {n} (12-bit analog or 0/1 digital)'))
    return ports


@dataclass(frozen=True)
class _Family:
    """What a family changes in the manual's layout, and its modes, bauds and features."""

    remove: tuple[str, ...]
    add: tuple[Item, ...]
    modes: dict[str, int]
    bauds: dict[int, int]
    fast_sync_read_firmware: int | None
    override: Overrides = field(default_factory=dict)


# Every family leaves out Acceleration Limit: neither the SDK model files nor the current
# e-manual have it (older e-manual revisions do); only the manual's 1020/1030 keep it.
_COMMON_REMOVE = ('acceleration_limit',)
_COMMON_ADD = (SECONDARY_ID, STARTUP_CONFIGURATION, BUS_WATCHDOG, BACKUP_READY)

X430 = _Family(_COMMON_REMOVE, (*_COMMON_ADD, _drive_mode(13)), SIX_MODES, BAUDS_4M5,
               FAST_SYNC_X)
X540 = _Family(_COMMON_REMOVE, (*_COMMON_ADD, _drive_mode(15), *_external_ports()),
               SIX_MODES, BAUDS_4M5, FAST_SYNC_X)
# The XW models are sealed: no LED.
XW = _Family((*_COMMON_REMOVE, 'led'), (*_COMMON_ADD, _drive_mode(13)), SIX_MODES,
             BAUDS_4M5, FAST_SYNC_X)
XL430 = _Family(
    (*_COMMON_REMOVE, 'current_limit', 'goal_current', 'present_current'),
    (*_COMMON_ADD, _drive_mode(13), PRESENT_LOAD), FOUR_MODES, BAUDS_4M5, FAST_SYNC_X)
# The two-axis 2XL430/2XC430: XL430 tables, but no Fast Sync Read (Protocol 2.0 e-manual).
DUAL_XL430 = _Family(XL430.remove, XL430.add, FOUR_MODES, BAUDS_4M5, None)
X330 = _Family(
    _COMMON_REMOVE, (*_COMMON_ADD, _drive_mode(13)), SIX_MODES, BAUDS_4M, FAST_SYNC_X330,
    # 2 is Protocol 2.0; 20, 21 and 22 the RC protocols (S.BUS, iBUS, RC-PWM).
    {'baud_rate': {'maximum': max(BAUDS_4M)},
     'protocol_version': {'minimum': 2, 'maximum': 22}})


@dataclass(frozen=True)
class _Tuning:
    """One model's e-manual figures for the items the families share."""

    temperature_limit: int
    voltage: tuple[int, int]                  # (min, max) in 0.1 V, also the power-on limits
    current: tuple[int, float] | None         # (Current Limit, mA per count) or no current
    velocity_limit: int
    gains: tuple[int, int, int, int, int]     # velocity I, P; position D, I, P
    shutdown: int = 0x34
    velocity_max: int = 1023
    pwm_slope: tuple[int, str] | None = None  # X330: (initial, unit)
    # Power-on values the page gives where they differ from the manual's layout (XM335).
    initials: tuple[tuple[str, int], ...] = ()


def _tuning_overrides(t: _Tuning, input_voltage: int) -> dict[str, dict[str, Value]]:
    low, high = t.voltage
    vmax = t.velocity_max
    overrides: dict[str, dict[str, Value]] = {
        'temperature_limit': {'initial': t.temperature_limit},
        'max_voltage_limit': {'initial': high, 'minimum': low, 'maximum': high},
        'min_voltage_limit': {'initial': low, 'minimum': low, 'maximum': high},
        'velocity_limit': {'initial': t.velocity_limit, 'maximum': vmax},
        'goal_velocity': {'minimum': -vmax, 'maximum': vmax},
        # Bounded by velocity_limit in velocity-based profiles, a time in ms otherwise.
        'profile_velocity': {'maximum': PROFILE_MAX},
        'profile_acceleration': {'limit': None},
        'shutdown': {'initial': t.shutdown},
        'present_input_voltage': {'initial': input_voltage},
        'feedforward_2nd_gain': {'maximum': GAIN_MAX},
        'feedforward_1st_gain': {'maximum': GAIN_MAX},
    }
    names = ('velocity_i_gain', 'velocity_p_gain', 'position_d_gain', 'position_i_gain',
             'position_p_gain')
    for name, gain in zip(names, t.gains):
        overrides[name] = {'initial': gain, 'maximum': GAIN_MAX}
    for name, initial in t.initials:
        overrides[name] = {'initial': initial}
    if t.current is not None:
        limit, milliamps = t.current
        unit = f'{milliamps:g} mA'
        overrides['current_limit'] = {'initial': limit, 'maximum': limit, 'unit': unit}
        # Goal Current powers on at Current Limit, as in the XM430 manual.
        overrides['goal_current'] = {'initial': limit, 'minimum': -limit, 'maximum': limit,
                                     'unit': unit}
        overrides['present_current'] = {'unit': unit}
    return overrides


def _points(*rows: tuple[float, float, float, float]) -> tuple[VoltagePoint, ...]:
    return tuple(VoltagePoint(*row) for row in sorted(rows))


def _physics(gear: float, nominal: float, rows: tuple[tuple[float, float, float, float], ...],
             source: str) -> Physics:
    return Physics(gear, nominal, _points(*rows), source)


def _model(number: int, name: str, family: _Family, tuning: _Tuning, physics: Physics, *,
           banks: tuple[tuple[int, int, int], ...] = ((168, 224, 28), (578, 634, 28)),
           last_ram: int = LAST_RAM_X, firmware: int = MANUAL_FIRMWARE,
           min_firmware: int = 0) -> Model:
    """Return one model: the manual's layout changed by its family and its own figures."""
    pairs = indirect_pairs(*banks)
    add: list[Item] = [*family.add, *indirect_items(pairs, last_ram)]
    if tuning.pwm_slope is not None:
        initial, unit = tuning.pwm_slope
        add.append(item('pwm_slope', 62, 1, 'RW', initial, 1, 255, unit=unit,
                        description='PWM Slope (rate the output PWM may change)'))
    override = _tuning_overrides(tuning, round(physics.nominal_voltage_v * 10))
    # Merged per item: a family's range and a model's initial may touch the same item.
    for key, changes in family.override.items():
        override[key] = {**override.get(key, {}), **changes}
    override['model_number'] = {'initial': number}
    override['firmware_version'] = {'initial': firmware}
    base = (each for each in xm430.ITEMS if not is_indirect(each.name))
    items = build(base, remove=family.remove, add=add, override=override)
    milliamps = tuning.current[1] if tuning.current is not None else None
    return Model(
        number=number, name=name, family=name.split('-')[0], items=items,
        modes=dict(family.modes), bauds=dict(family.bauds),
        current_unit_a=None if milliamps is None else milliamps / 1000.0,
        load_unit_ratio=0.001 if any(new.name == 'present_load' for new in family.add)
        else None,
        velocity_unit_rpm=0.229, pulses_per_rev=4096, position_zero_raw=2048,
        pwm_full_raw=885, voltage_unit_v=0.1, indirect=pairs,
        hardware_error_bits=dict(xm430.HARDWARE_ERROR_BITS), physics=physics,
        min_firmware=min_firmware, fast_sync_read_firmware=family.fast_sync_read_firmware,
        time_profile_bit=TIME_PROFILE_BIT)


def _manual_model(number: int, name: str, physics: Physics) -> Model:
    """Return 1020 or 1030: the XM430 manual's items unchanged plus what the e-manual adds."""
    items = build(xm430.ITEMS, add=(_drive_mode(13), *_COMMON_ADD),
                  override={'model_number': {'initial': number}})
    pairs = xm430.INDIRECT_PAIRS
    return Model(
        number=number, name=name, family=name.split('-')[0], items=items,
        modes=dict(SIX_MODES), bauds=dict(BAUDS_4M5), current_unit_a=2.69e-3,
        load_unit_ratio=None, velocity_unit_rpm=0.229, pulses_per_rev=4096,
        position_zero_raw=2048, pwm_full_raw=885, voltage_unit_v=0.1, indirect=pairs,
        hardware_error_bits=dict(xm430.HARDWARE_ERROR_BITS), physics=physics,
        fast_sync_read_firmware=FAST_SYNC_X, time_profile_bit=TIME_PROFILE_BIT)


def _x330(number: int, name: str, tuning: _Tuning, physics: Physics) -> tuple[Model, Model]:
    """
    Return the X330's two tables: firmware up to 52, and 53 on.

    Up to v52 the e-manual (every revision before July 2025) and the SDK's *_fw52.model
    agree: 20 indirect entries, addresses at 168.., data at 208..227.  The plain
    *.model files (changed in July 2025 together with an e-manual rewrite of this part)
    move Indirect Data 1 to 224, the X430 layout; with addresses still at 168 there is
    room for 28 entries, data 224..251, as the e-manual's XM335 page (copied from the X330
    one) listed before its own fix.  The count 28 is inferred from that layout: no stored
    source states it for the X330 outright.  Which firmware first moved the block is not
    published either; 53, the first after the _fw52 file's 52, is assumed.
    """
    old = _model(number, name, X330, tuning, physics, banks=((168, 208, 20),), last_ram=227,
                 firmware=X330_NEW_INDIRECT_FIRMWARE - 1)
    new = _model(number, name, X330, tuning, physics, banks=((168, 224, 28),), last_ram=251,
                 firmware=X330_NEW_INDIRECT_FIRMWARE, min_firmware=X330_NEW_INDIRECT_FIRMWARE)
    return old, new


# Datasheet rows: (volts, stall N.m, stall A, no-load rpm), from the e-manual's
# _data/dxl_x_info.yml unless the source says otherwise.
_SPEC = 'ROBOTIS e-manual {} specifications'
_X430_12V = (95, 160)
_V24 = (110, 300)

_MODELS: list[Model] = [
    # --- XM430/XH430/XD430 ---------------------------------------------------------------
    _manual_model(1020, 'XM430-W350', _physics(
        353.5, 12.0, ((11.1, 3.8, 2.1, 43), (12.0, 4.1, 2.3, 46), (14.8, 4.8, 2.7, 57)),
        'XM430 manual (identical to the e-manual XM430-W350 specifications)')),
    # The XM430 manual's is model 1030 and the authority for it: its figures win over the
    # e-manual's XM430-W210 ones (212.6:1, 3.0 N.m at 2.3 A, 77 rpm at 12 V), see
    # MANUAL_DIFFERENCES.
    _manual_model(1030, 'XM430-W210', _physics(
        353.5, 12.0, ((11.1, 3.8, 2.1, 43), (12.0, 4.1, 2.3, 46), (14.8, 4.8, 2.7, 57)),
        'XM430 manual (model 1030; the e-manual XM430-W210 specifications differ: 212.6:1, '
        '2.7/3.0/3.7 N.m, 70/77/95 rpm)')),
    _model(1000, 'XH430-W350', X430, _Tuning(80, _X430_12V, (648, 2.69), 130,
                                             (1920, 100, 0, 0, 900)), _physics(
        353.5, 12.0, ((11.1, 3.1, 1.2, 27), (12.0, 3.4, 1.3, 30), (14.8, 4.2, 1.5, 37)),
        _SPEC.format('XH430-W350'))),
    _model(1010, 'XH430-W210', X430, _Tuning(80, _X430_12V, (648, 2.69), 210,
                                             (1920, 100, 0, 0, 900)), _physics(
        212.6, 12.0, ((11.1, 2.2, 1.2, 46), (12.0, 2.5, 1.3, 50), (14.8, 3.1, 1.5, 62)),
        _SPEC.format('XH430-W210'))),
    # The 24 V XH430-V count current in 1.34 mA (e-manual), half the W's unit.
    _model(1040, 'XH430-V350', X430, _Tuning(80, _V24, (689, 1.34), 285,
                                             (1920, 100, 0, 0, 800)), _physics(
        353.5, 24.0, ((24.0, 3.3, 0.7, 31),), _SPEC.format('XH430-V350')
        + '; a single voltage is published')),
    _model(1050, 'XH430-V210', X430, _Tuning(80, _V24, (689, 1.34), 380,
                                             (1920, 100, 0, 0, 800)), _physics(
        212.6, 24.0, ((24.0, 2.6, 0.7, 52),), _SPEC.format('XH430-V210')
        + '; a single voltage is published')),
    # XD430: the e-manual states its control table is the XH430's; its torque and speed
    # figures (X430 comparison table) are the XH430-W's too.  The gear ratio is not
    # published for the XD: the XH430-W's is assumed.
    _model(1001, 'XD430-T350', X430, _Tuning(80, _X430_12V, (648, 2.69), 130,
                                             (1920, 100, 0, 0, 900)), _physics(
        353.5, 12.0, ((11.1, 3.1, 1.2, 27), (12.0, 3.4, 1.3, 30), (14.8, 4.2, 1.5, 37)),
        'ROBOTIS e-manual X430 comparison table (XD430-T350-R); gear ratio not published, '
        'the XH430-W350 353.5:1 assumed')),
    _model(1011, 'XD430-T210', X430, _Tuning(80, _X430_12V, (648, 2.69), 210,
                                             (1920, 100, 0, 0, 900)), _physics(
        212.6, 12.0, ((11.1, 2.2, 1.2, 46), (12.0, 2.5, 1.3, 50), (14.8, 3.1, 1.5, 62)),
        'ROBOTIS e-manual X430 comparison table (XD430-T210-R); gear ratio not published, '
        'the XH430-W210 212.6:1 assumed; control table taken as the XH430-W210 one, as the '
        'e-manual says they are identical')),
    # --- XM540/XH540/XD540 ---------------------------------------------------------------
    _model(1120, 'XM540-W270', X540, _Tuning(80, _X430_12V, (2047, 2.69), 128,
                                             (1920, 100, 0, 0, 800)), _physics(
        272.5, 12.0, ((11.1, 10.0, 4.2, 28), (12.0, 10.6, 4.4, 30), (14.8, 12.9, 5.5, 37)),
        _SPEC.format('XM540-W270'))),
    _model(1130, 'XM540-W150', X540, _Tuning(80, _X430_12V, (2047, 2.69), 230,
                                             (1920, 100, 0, 0, 800)), _physics(
        152.3, 12.0, ((11.1, 6.9, 4.2, 50), (12.0, 7.3, 4.4, 53), (14.8, 8.9, 5.5, 66)),
        _SPEC.format('XM540-W150'))),
    _model(1100, 'XH540-W270', X540, _Tuning(80, _X430_12V, (2047, 2.69), 167,
                                             (1920, 100, 0, 0, 800)), _physics(
        272.5, 12.0, ((11.1, 9.2, 4.5, 36), (12.0, 9.9, 4.9, 39), (14.8, 11.7, 5.9, 46)),
        _SPEC.format('XH540-W270'))),
    _model(1110, 'XH540-W150', X540, _Tuning(80, _X430_12V, (2047, 2.69), 300,
                                             (1920, 100, 0, 0, 800)), _physics(
        152.3, 12.0, ((11.1, 6.6, 4.5, 66), (12.0, 7.1, 4.9, 70), (14.8, 8.5, 5.9, 86)),
        _SPEC.format('XH540-W150'))),
    # Unlike the XH430-V, the e-manual gives the XH540-V the W's 2.69 mA unit.
    _model(1140, 'XH540-V270', X540, _Tuning(80, _V24, (2047, 2.69), 128,
                                             (1920, 100, 0, 0, 800)), _physics(
        272.5, 24.0, ((24.0, 9.2, 2.4, 34),), _SPEC.format('XH540-V270')
        + '; a single voltage is published')),
    _model(1150, 'XH540-V150', X540, _Tuning(80, _V24, (2047, 2.69), 230,
                                             (1920, 100, 0, 0, 800)), _physics(
        152.3, 24.0, ((24.0, 6.4, 2.4, 60),), _SPEC.format('XH540-V150')
        + '; a single voltage is published')),
    _model(1101, 'XD540-T270', X540, _Tuning(80, _X430_12V, (2047, 2.69), 167,
                                             (1920, 100, 0, 0, 800)), _physics(
        272.5, 12.0, ((11.1, 9.2, 4.5, 36), (12.0, 9.9, 4.9, 39), (14.8, 11.7, 5.9, 46)),
        'ROBOTIS e-manual X540 comparison table (XD540-T270-R); gear ratio not published, '
        'the XH540-W270 272.5:1 assumed; control table taken as the XH540-W270 one')),
    _model(1111, 'XD540-T150', X540, _Tuning(80, _X430_12V, (2047, 2.69), 300,
                                             (1920, 100, 0, 0, 800)), _physics(
        152.3, 12.0, ((11.1, 6.6, 4.5, 66), (12.0, 7.1, 4.9, 70), (14.8, 8.5, 5.9, 86)),
        'ROBOTIS e-manual X540 comparison table (XD540-T150-R); gear ratio not published, '
        'the XH540-W150 152.3:1 assumed; control table taken as the XH540-W150 one')),
    # --- XW430/XW540 ---------------------------------------------------------------------
    # XW430 Current Limit 2,047 is as published, although it is far above the stall
    # current the XW430-T333 quotes.
    _model(1270, 'XW430-T333', XW, _Tuning(80, _X430_12V, (2047, 2.69), 139,
                                           (1920, 100, 0, 0, 900)), _physics(
        333.3, 12.0, ((11.1, 2.9, 1.2, 29), (12.0, 3.1, 1.3, 31), (14.8, 3.6, 1.5, 39)),
        'ROBOTIS e-manual X430 comparison table (XW430-T333-R); gear ratio not published, '
        '333.3:1 assumed from the name')),
    # 1280 is not in the SDK's dynamixel.model (its xw430_t200.model file is); the number
    # is the e-manual's.
    _model(1280, 'XW430-T200', XW, _Tuning(80, _X430_12V, (2047, 2.69), 235,
                                           (1920, 100, 0, 0, 900)), _physics(
        200.0, 12.0, ((11.1, 6.4, 4.5, 49), (12.0, 6.9, 4.9, 53), (14.8, 8.3, 5.9, 66)),
        'ROBOTIS e-manual X430 comparison table (XW430-T200-R), as published although its '
        'torque and current equal the XW540-T140 row and may be a copying error; gear '
        'ratio not published, 200:1 assumed from the name')),
    _model(1170, 'XW540-T260', XW, _Tuning(80, _X430_12V, (2047, 2.69), 167,
                                           (1920, 100, 0, 0, 800)), _physics(
        260.6, 12.0, ((11.1, 8.8, 4.5, 37), (12.0, 9.5, 4.9, 40), (14.8, 11.2, 5.9, 48)),
        _SPEC.format('XW540-T260'))),
    _model(1180, 'XW540-T140', XW, _Tuning(80, _X430_12V, (2047, 2.69), 304,
                                           (1920, 100, 0, 0, 800)), _physics(
        145.6, 12.0, ((11.1, 6.4, 4.5, 67), (12.0, 6.9, 4.9, 72), (14.8, 8.3, 5.9, 88)),
        _SPEC.format('XW540-T140'))),
    _model(1310, 'XW540-H260', XW, _Tuning(80, _V24, (1188, 2.69), 145,
                                           (1920, 100, 0, 0, 800)), _physics(
        260.6, 24.0, ((24.0, 8.8, 2.4, 35.6),),
        'not published (a special-order model whose e-manual page has no datasheet '
        'figures); assumed: 24 V as its 11.0..30.0 V limits suggest, the XW540-T260 '
        '260.6:1 gear, and the XH540-V270 24 V figures scaled by 260.6/272.5 '
        '(9.2 -> 8.8 N.m, 34 -> 35.6 rpm, 2.4 A)')),
    # --- XL430/2XL430/XC430/2XC430 -------------------------------------------------------
    # Present Load instead of current; no Current Limit nor Goal Current.
    _model(1060, 'XL430-W250', XL430, _Tuning(72, (60, 140), None, 265,
                                              (1000, 100, 4000, 0, 640)), _physics(
        258.5, 11.1, ((9.0, 1.0, 1.0, 47), (11.1, 1.4, 1.3, 57), (12.0, 1.5, 1.4, 61)),
        _SPEC.format('XL430-W250'))),
    _model(1090, '2XL430-W250', DUAL_XL430, _Tuning(72, (60, 140), None, 250,
                                                    (1800, 100, 2000, 0, 640)), _physics(
        257.4, 11.1, ((9.0, 1.0, 1.0, 47), (11.1, 1.4, 1.3, 57), (12.0, 1.5, 1.4, 61)),
        _SPEC.format('2XL430-W250') + ' (per axis)')),
    _model(1070, 'XC430-W150', XL430, _Tuning(80, (60, 160), None, 460,
                                              (1920, 100, 0, 0, 460)), _physics(
        159.59, 12.0, ((9.0, 1.2, 1.1, 80), (11.1, 1.4, 1.3, 99), (12.0, 1.6, 1.4, 106)),
        _SPEC.format('XC430-W150'))),
    _model(1080, 'XC430-W240', XL430, _Tuning(80, (60, 160), None, 306,
                                              (1920, 100, 0, 0, 700)), _physics(
        245.22, 12.0, ((9.0, 1.4, 1.1, 52), (11.1, 1.7, 1.3, 65), (12.0, 1.9, 1.4, 70)),
        _SPEC.format('XC430-W240'))),
    _model(1160, '2XC430-W250', DUAL_XL430, _Tuning(80, (60, 160), None, 275,
                                                    (1920, 100, 0, 0, 700)), _physics(
        257.4, 12.0, ((9.0, 1.3, 1.1, 48), (11.1, 1.6, 1.3, 59), (12.0, 1.8, 1.4, 64)),
        _SPEC.format('2XC430-W250') + ' (per axis)')),
    # --- XL330/XC330: 1 mA current unit, velocity up to 2,047, PWM Slope ------------------
    *_x330(1190, 'XL330-M077', _Tuning(
        70, (35, 70), (1150, 1.0), 1620, (1600, 300, 0, 0, 400), shutdown=0x35,
        velocity_max=2047, pwm_slope=(140, '1.977 mV/ms')), _physics(
        77.5, 5.0, ((3.7, 0.180, 1.11, 278), (5.0, 0.215, 1.47, 383), (6.0, 0.228, 1.74, 456)),
        _SPEC.format('XL330-M077'))),
    *_x330(1200, 'XL330-M288', _Tuning(
        70, (35, 70), (1750, 1.0), 445, (1600, 180, 0, 0, 400), shutdown=0x35,
        velocity_max=2047, pwm_slope=(140, '1.977 mV/ms')), _physics(
        288.4, 5.0, ((3.7, 0.42, 1.11, 76), (5.0, 0.52, 1.47, 103), (6.0, 0.60, 1.74, 123)),
        _SPEC.format('XL330-M288'))),
    *_x330(1210, 'XC330-T181', _Tuning(
        70, (55, 140), (910, 1.0), 510, (1200, 40, 0, 0, 900), velocity_max=2047,
        pwm_slope=(255, '3.955 mV/ms')), _physics(
        180.62, 11.1, ((9.0, 0.65, 0.61, 83), (11.1, 0.76, 0.80, 104), (12.0, 0.80, 0.88, 113)),
        _SPEC.format('XC330-T181'))),
    *_x330(1220, 'XC330-T288', _Tuning(
        70, (55, 140), (910, 1.0), 320, (1200, 40, 0, 0, 900), velocity_max=2047,
        pwm_slope=(255, '3.955 mV/ms')), _physics(
        288.35, 11.1, ((9.0, 0.76, 0.61, 52), (11.1, 0.92, 0.80, 65), (12.0, 1.00, 0.88, 71)),
        _SPEC.format('XC330-T288'))),
    *_x330(1230, 'XC330-M181', _Tuning(
        70, (35, 70), (2352, 1.0), 545, (1400, 100, 500, 0, 1200), velocity_max=2047,
        pwm_slope=(140, '1.977 mV/ms')), _physics(
        180.62, 5.0, ((3.7, 0.52, 1.34, 95), (5.0, 0.60, 1.80, 129), (6.0, 0.66, 2.15, 155)),
        _SPEC.format('XC330-M181'))),
    *_x330(1240, 'XC330-M288', _Tuning(
        70, (35, 70), (2352, 1.0), 350, (1600, 50, 500, 0, 1100), velocity_max=2047,
        pwm_slope=(140, '1.977 mV/ms')), _physics(
        288.35, 5.0, ((3.7, 0.69, 1.34, 59), (5.0, 0.93, 1.80, 81), (6.0, 1.10, 2.15, 97)),
        _SPEC.format('XC330-M288'))),
    # --- XM335: the X330 electronics in a 323:1 finger actuator -------------------------------
    # Its e-manual page as fixed (the first revision copied the X330 table): one table, 28
    # indirect entries at 168/224 (no older firmware split is published for it; the
    # simulated firmware is the X330's first with that block), 1 Mbps and a 1,024..3,072
    # position window at power-on. Fast Sync Read from v46 as on the X330 is
    # assumed (the Protocol 2.0 page seen does not list it; the driver gives Fast Sync up when
    # a servo does not answer it).
    _model(1710, 'XM335-T323', X330, _Tuning(
        70, (55, 140), (910, 1.0), 280, (1800, 50, 0, 0, 2000), velocity_max=2047,
        pwm_slope=(255, '3.955 mV/ms'),
        initials=(('baud_rate', 3), ('max_position_limit', 3072),
                  ('min_position_limit', 1024))), _physics(
        323.04, 11.1, ((11.1, 1.03, 0.80, 53),),
        'XM335-T323-T e-manual specifications, not in the stored e-manual data: as copied '
        'by two independent third-party sources (a product catalogue: 323.04:1, 1.03 N.m at '
        '0.80 A and 53 rpm at 11.1 V; a robot-hand project: 53 rpm); one voltage; they agree '
        'with the XC330-T288 11.1 V figures scaled by 323.04/288.35 (0.92 -> 1.03 N.m)'),
        banks=((168, 224, 28),), last_ram=251, firmware=X330_NEW_INDIRECT_FIRMWARE),
]


def _index(models: list[Model]) -> dict[int, tuple[Model, ...]]:
    table: dict[int, list[Model]] = {}
    for model in models:
        table.setdefault(model.number, []).append(model)
    return {number: tuple(sorted(variants, key=lambda each: each.min_firmware))
            for number, variants in sorted(table.items())}


X_MODELS: tuple[Model, ...] = tuple(
    variant for variants in _index(_MODELS).values() for variant in variants)
# The other families, each from its own module.
_MODELS += mx.MODELS + pro.MODELS + pro_legacy.MODELS + y.MODELS + xl320.MODELS + protocol1.MODELS
SUPPORTED: dict[int, tuple[Model, ...]] = _index(_MODELS)
ALL_MODELS: tuple[Model, ...] = tuple(
    variant for variants in SUPPORTED.values() for variant in variants)
_BY_NAME: dict[str, int] = {model.name.upper(): model.number for model in ALL_MODELS}
# Names sold beside a supported model that report its number and table: the XC430 with ball
# bearings (their pages: model 1070 and 1080, 'other specifications are the same'; sold as
# -T150BB/-T240BB too).
_BY_NAME.update({'XC430-W150BB': 1070, 'XC430-T150BB': 1070, 'XC430-W240BB': 1080,
                 'XC430-T240BB': 1080})
_PROTOCOLS = ' and '.join(
    f'Protocol {version:.1f}' for version in sorted({model.protocol for model in ALL_MODELS}))


def unsupported_reason(number: int) -> str:
    """Return why this model number is refused, naming the model when known; '' if supported."""
    if number in SUPPORTED:
        return ''
    families = ', '.join(FAMILIES)
    known = OTHER_MODELS.get(number)
    if known is None:
        what = f'model number {number} is not a DYNAMIXEL model this driver knows'
    else:
        name, kind = known
        what = (f'model number {number} is the {name}, {kind}, which this driver does not '
                'support')
    return f'{what}; supported: DYNAMIXEL {families} ({_PROTOCOLS})'


def model_for(number: int, firmware: int | None = None) -> Model:
    """
    Return the table for this model number and firmware version.

    Without a firmware version the newest table is returned.  A firmware older than every
    variant's min_firmware cannot happen (the first variant starts at 0).
    """
    variants = SUPPORTED.get(number)
    if variants is None:
        raise ModelError(unsupported_reason(number))
    if firmware is None:
        return variants[-1]
    if firmware < 0:
        raise ModelError(f'firmware version {firmware} is negative')
    chosen = variants[0]
    for variant in variants:
        if variant.min_firmware <= firmware:
            chosen = variant
    return chosen


def model_named(name: str) -> Model:
    """Return the newest table of the model with this name ('XL430-W250', any case, -T/-R/-RH)."""
    key = name.strip().upper()
    # The e-manual names the Y with a '-RH' ending ('YM070-210-M001-RH').
    for suffix in ('-T/R', '-T', '-R', '-RH'):
        if key not in _BY_NAME and key.endswith(suffix):
            key = key[:-len(suffix)]
    number = _BY_NAME.get(key)
    if number is None:
        raise ModelError(f'no supported model is named {name!r}; supported: DYNAMIXEL '
                         + ', '.join(FAMILIES))
    return model_for(number)


MANUAL_DIFFERENCES: tuple[str, ...] = (
    'The manual has no Drive Mode (address 10, 1 byte); 1020 and 1030 get it from the SDK '
    'model file and the e-manual: initial 0, bits 0, 2 and 3 valid (0..13).',
    'The manual has no Secondary(Shadow) ID (address 12, 1 byte); added from the model file '
    'and the e-manual: initial 255, 0..252 usable, anything above 252 switches it off.',
    'The manual has no Bus Watchdog (address 98, 1 byte); added from the model file and the '
    'e-manual: initial 0 (off), 1..127 in 20 ms steps, 255 (-1) reports a tripped watchdog.',
    'The manual has no Startup Configuration (address 60) and no Backup Ready (address 147); '
    'the current e-manual has both (firmware v45 on) but the SDK model file has neither. '
    'Added from the e-manual.',
    'The manual has Acceleration Limit (address 40, 4 bytes, initial 32,767); the SDK model '
    'file and the current e-manual do not (older e-manual revisions do). Kept for 1020 and '
    '1030 because the manual is the authority for them; every other model leaves it out and '
    'its profile_acceleration has no limit register.',
    "The manual names address 13 'Protocol Version'; the SDK model file names it 'Protocol "
    "Type'. The manual's name protocol_version is kept.",
    'The manual gives Velocity Limit initial 480; the e-manual gives 350 for the XM430-W350 '
    "and 330 for the XM430-W210. The manual's value is kept for both.",
    'The manual gives Velocity P Gain initial 50; the e-manual gives 100 for both XM430. The '
    "manual's value is kept.",
    "The manual allows gains up to 32,767; the e-manual gives 0..16,383. The manual's range is "
    'kept for 1020 and 1030, the e-manual one used elsewhere.',
    'The manual bounds Profile Velocity by Velocity Limit (0..1,023); the e-manual gives '
    '0..32,767, since a time-based profile (Drive Mode bit 2) counts milliseconds there. '
    "The manual's range is kept for 1020 and 1030, the e-manual one used elsewhere.",
    "The manual's Model Number initial is 1030; model 1020 reports 1020.",
    "The manual's datasheet figures (353.5:1, 4.1 N.m at 2.3 A and 46 rpm at 12 V) are the "
    'XM430-W350 ones although its model number is 1030 (XM430-W210, 212.6:1, 3.0 N.m at '
    '2.3 A, 77 rpm at 12 V in the e-manual). The manual is the authority for 1030: both 1020 '
    'and 1030 use its figures (torque constant 4.1/2.3 N.m/A, simulator physics).',
    "The SDK model file's 'Indirect Address Write/Read' and 'Indirect Data Write/Read' rows "
    'are aliases of Indirect Address/Data 1 and 29, not further items.',
)
