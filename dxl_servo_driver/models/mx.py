"""
The MX series on Protocol 2.0 firmware: MX-28(2.0), MX-64(2.0), MX-106(2.0), as data.

Their tables are the XM430 manual's layout (models.xm430) with its Acceleration Limit kept
(the SDK model files and the e-manual both have it), plus Drive Mode, Secondary ID and Bus
Watchdog, and without the X's later Startup Configuration and Backup Ready (neither the
model files nor the e-manual pages have them). The MX-28(2.0) senses no current: Present
Load instead, and no current nor current-based position mode.

Sources: addresses and sizes from the dynamixel-sdk model files (mx_28, mx_64, mx_106);
initial values, ranges, units and datasheet figures from the ROBOTIS e-manual MX-28(2.0),
MX-64(2.0), MX-106(2.0) pages and its _data/dxl_mx_info.yml. Fast Sync Read: the Protocol
2.0 e-manual lists it for the X series only, so none here.
"""

from dxl_servo_driver.models import modes, xm430
from dxl_servo_driver.models.base import datasheet, Item, Model, Physics
from dxl_servo_driver.models.layout import build, indirect_items, is_indirect, item, Value

__all__ = ['FAMILY', 'MODELS']

FAMILY = 'MX(2.0)'
GAIN_MAX = 16_383     # e-manual gain range
PROFILE_MAX = 32_767  # a time-based profile (Drive Mode bit 2) counts milliseconds to this
CURRENT_MA = 3.36     # e-manual: 'about 3.36 mA' per count (MX-64/106)


def _drive_mode(maximum: int) -> Item:
    # MX-28/64: bit 0 reverse, bit 2 time-based profile (0..5); the MX-106 adds bit 1,
    # the dual-joint slave (0..7). The X's bit 3 (torque on by goal update) is not in the
    # MX pages.
    return item('drive_mode', 10, 1, 'RW', 0, 0, maximum,
                description='Drive Mode (bit 0 reverse, 1 dual-joint slave on the MX-106, '
                            '2 time-based profile)')


_SECONDARY_ID = item(
    'secondary_id', 12, 1, 'RW', 255, 0, 255,
    description='Secondary (Shadow) ID; 0..252, a value above 252 switches it off')
_BUS_WATCHDOG = item(
    'bus_watchdog', 98, 1, 'RW', 0, 0, 127, unit='20 ms',
    description='Bus Watchdog (0 off, 1..127 on); the servo writes 255 (-1) when it trips')
_PRESENT_LOAD = item(
    'present_load', 126, 2, 'R', 0, -1000, 1000, signed=True, unit='0.1 %',
    description='Present Load (share of the maximum output torque, sign is direction)')


def _model(number: int, name: str, velocity_limit: int, current_limit: int | None,
           drive_max: int, physics: Physics) -> Model:
    """Return one MX(2.0) model: the manual's layout, its Acceleration Limit kept."""
    add: list[Item] = [_drive_mode(drive_max), _SECONDARY_ID, _BUS_WATCHDOG,
                       *indirect_items(xm430.INDIRECT_PAIRS, xm430.TABLE_SIZE - 1)]
    remove: tuple[str, ...] = ()
    override: dict[str, dict[str, Value]] = {
        'model_number': {'initial': number},
        'velocity_limit': {'initial': velocity_limit},
        'profile_velocity': {'maximum': PROFILE_MAX},
        # e-manual MX(2.0) gains: velocity I 1,920, P 100; position P 850, D and I 0.
        'velocity_i_gain': {'initial': 1920, 'maximum': GAIN_MAX},
        'velocity_p_gain': {'initial': 100, 'maximum': GAIN_MAX},
        'position_d_gain': {'maximum': GAIN_MAX},
        'position_i_gain': {'maximum': GAIN_MAX},
        'position_p_gain': {'initial': 850, 'maximum': GAIN_MAX},
        'feedforward_2nd_gain': {'maximum': GAIN_MAX},
        'feedforward_1st_gain': {'maximum': GAIN_MAX},
    }
    if current_limit is None:
        remove = ('current_limit', 'goal_current', 'present_current')
        add.append(_PRESENT_LOAD)
        model_modes = modes.numbers('velocity', 'position', 'extended_position', 'pwm')
    else:
        unit = f'{CURRENT_MA:g} mA'
        override['current_limit'] = {'initial': current_limit, 'maximum': current_limit,
                                     'unit': unit}
        override['goal_current'] = {'initial': current_limit, 'minimum': -current_limit,
                                    'maximum': current_limit, 'unit': unit}
        override['present_current'] = {'unit': unit}
        model_modes = modes.numbers(*modes.NAMES)
    base = (each for each in xm430.ITEMS if not is_indirect(each.name))
    items = build(base, remove=remove, add=add, override=override)
    return Model(
        number=number, name=name, family=FAMILY, items=items, modes=model_modes,
        bauds=dict(xm430.BAUD_RATES),
        current_unit_a=None if current_limit is None else CURRENT_MA / 1000.0,
        load_unit_ratio=0.001 if current_limit is None else None,
        velocity_unit_rpm=0.229, pulses_per_rev=4096, position_zero_raw=2048,
        pwm_full_raw=885, voltage_unit_v=0.1, indirect=xm430.INDIRECT_PAIRS,
        hardware_error_bits=dict(xm430.HARDWARE_ERROR_BITS), physics=physics,
        fast_sync_read_firmware=None, time_profile_bit=2)


_SPEC = 'ROBOTIS e-manual {} specifications'

# Velocity Limit initial values are those of the stored e-manual page revisions (380, 435,
# 360); the firmware version the pages give as '-' is left at the XM430 base's 45.
MODELS: tuple[Model, ...] = (
    _model(30, 'MX-28(2.0)', 380, None, 5, datasheet(
        193.0, 12.0, ((11.1, 2.3, 1.3, 50), (12.0, 2.5, 1.4, 55), (14.8, 3.1, 1.7, 67)),
        _SPEC.format('MX-28(2.0)'))),
    _model(311, 'MX-64(2.0)', 435, 1941, 5, datasheet(
        200.0, 12.0, ((11.1, 5.5, 3.9, 58), (12.0, 6.0, 4.1, 63), (14.8, 7.3, 5.2, 78)),
        _SPEC.format('MX-64(2.0)'))),
    _model(321, 'MX-106(2.0)', 360, 2047, 7, datasheet(
        225.0, 12.0, ((11.1, 8.0, 4.8, 41), (12.0, 8.4, 5.2, 45), (14.8, 10.0, 6.3, 55)),
        _SPEC.format('MX-106(2.0)'))),
)
