"""
What may be written where: the driver's write rules, one book for parameter files and services.

Registers the driver owns (torque, mode, id, baud, goals, the indirect map), registers nobody
may write (protocol_version), the static range of each item, and the rules between registers
that the servo enforces with a data limit error (a value bounded by a limit register, pairs that
must stay ordered, the homing offset position mode ignores). Pure: no I/O.
"""

from typing import Mapping

from dxl_servo_driver.models import modes
from dxl_servo_driver.models.base import Item, Model

# Registers the driver manages itself; a configuration may not set them.
DRIVER_OWNED = frozenset(
    # status_return_level: the driver needs status packets, and the state block's restart
    # canary is that register.
    {'torque_enable', 'operating_mode', 'id', 'baud_rate', 'goal_position', 'goal_velocity',
     'status_return_level'})
# The indirect map is the driver's too (the state block), whatever a model's count of them.
DRIVER_OWNED_PREFIXES = ('indirect_address_', 'indirect_data_')


def driver_owned(name: str) -> bool:
    """Return whether the driver manages this register itself."""
    return name in DRIVER_OWNED or name.startswith(DRIVER_OWNED_PREFIXES)


# Registers a configuration or write_register may never set, and why.
REFUSED_REGISTERS: dict[str, str] = {
    'protocol_version': "a servo's protocol is the configuration's (<joint>.protocol): "
                        'switched while the node runs, the servo would stop answering in the '
                        'protocol it is spoken to (set it off the bus: scan says what each '
                        'servo speaks)',
}


def writable_register(model: Model, name: str, runtime: bool = False) -> Item:
    """Return the item a configuration (or write_register) may write, or raise ValueError."""
    if not model.has(name):
        raise ValueError(f'unknown register {name!r} (not in the control table of '
                         f'{model.label})')
    item = model.item(name)
    if item.access != 'RW':
        raise ValueError(f'register {name!r} is read-only')
    # By the XM430 manual's name of what it is: the Y's Protocol Type is protocol_version.
    role = model.role_of(item.name)
    if role in REFUSED_REGISTERS:
        raise ValueError(f'register {name!r} cannot be written: {REFUSED_REGISTERS[role]}')
    if not model.mode_register and role in ('min_position_limit', 'max_position_limit'):
        raise ValueError(f'register {name!r} is the mode of the {model.name} (its angle limits: '
                         'both 0 is wheel mode): use set_operating_mode, and '
                         '<joint>.min_position/max_position for the joint limits')
    if driver_owned(role) or role == model.mode_register:
        if runtime:
            raise ValueError(f'{name} is managed by the driver: use the set_torque / '
                             'set_operating_mode / command interfaces')
        raise ValueError(f'register {name!r} is managed by the driver and cannot be configured')
    return item


# value register -> the register that bounds it: the servo refuses a value beyond it (data
# limit error), so the driver refuses it first, from a file or at run time alike.
_BOUNDED_BY = {'profile_velocity': 'velocity_limit', 'profile_acceleration': 'acceleration_limit',
               'goal_pwm': 'pwm_limit', 'goal_current': 'current_limit'}
# (low, high) pairs that must stay ordered.
_ORDERED = (('min_position_limit', 'max_position_limit'),
            ('min_voltage_limit', 'max_voltage_limit'))

# A time-based profile (Drive Mode's time_profile_bit, the e-manual's Profile Configuration):
# Profile Velocity is the time of the whole move and Profile Acceleration the time it
# accelerates, both in ms, 0..32,767 (the e-manual's tables print 32,737 for the time-based
# range, beside 32,767 for the same register velocity-based: the register's range is taken),
# and the acceleration may not exceed half the move. Neither is bounded by Velocity Limit or
# Acceleration Limit then: they are times, not speeds.
PROFILE_REGISTERS = ('profile_velocity', 'profile_acceleration')
TIME_PROFILE_MAX_MS = 32_767


def time_based(model: Model, drive_mode: int | None) -> bool:
    """Return whether this Drive Mode value makes the model's profiles times (ms)."""
    bit = model.time_profile_bit
    return bit is not None and drive_mode is not None and bool(drive_mode >> bit & 1)


def _profile_role(model: Model, name: str) -> str:
    """Return the profile register name is, where a time-based profile may count it in ms."""
    role = model.role_of(name)
    return role if model.time_profile_bit is not None and role in PROFILE_REGISTERS else ''


def related_registers(model: Model, name: str) -> tuple[str, ...]:
    """Return the registers whose values check_register_set needs to judge a write of name."""
    related: list[str] = []
    if name in _BOUNDED_BY and model.has(_BOUNDED_BY[name]):
        related.append(_BOUNDED_BY[name])
    for low, high in _ORDERED:
        if name == low:
            related.append(high)
        elif name == high:
            related.append(low)
    if _profile_role(model, name):
        # The Drive Mode says what they count; the other one of the pair, the half rule.
        other = [each for each in PROFILE_REGISTERS if each != name]
        related += ['drive_mode', *other]
    elif name == 'drive_mode' and model.time_profile_bit is not None:
        # Bit 2 changes what the profile registers count: they are judged again.
        related += [each for each in (*PROFILE_REGISTERS, 'velocity_limit', 'acceleration_limit')
                    if model.has(each)]
    return tuple(related)


def _check_profile(model: Model, values: Mapping[str, int], name: str, value: int) -> None:
    """
    Raise ValueError when a write leaves the profile registers wrong for what they count.

    name is profile_velocity, profile_acceleration or drive_mode (its bit 2 changes their
    meaning: both are judged again); values holds the others (related_registers).
    """
    new = {**values, name: value}
    drive_mode = new.get('drive_mode')
    timed = time_based(model, drive_mode)
    judged = PROFILE_REGISTERS if name == 'drive_mode' else (name,)
    because = f' (drive_mode {drive_mode} sets bit {model.time_profile_bit}' if timed else (
        f' (drive_mode {drive_mode}: a velocity-based profile' if drive_mode is not None
        else ' (a velocity-based profile')
    for register in judged:
        if register not in new or not model.has(register):
            continue
        amount = new[register]
        if timed:
            if not 0 <= amount <= TIME_PROFILE_MAX_MS:
                raise ValueError(f'{register} {amount} is outside the range of a time-based '
                                 f'profile: 0..{TIME_PROFILE_MAX_MS} ms{because})')
            continue
        item = model.item(register)
        if not item.minimum <= amount <= item.maximum:
            unit = f' {item.unit}' if item.unit else ''
            raise ValueError(f'{amount} is outside the range of {register}: '
                             f'{item.minimum}..{item.maximum}{unit}{because}; drive_mode bit '
                             f'{model.time_profile_bit} makes it a time, 0..'
                             f'{TIME_PROFILE_MAX_MS} ms)')
        bound = _BOUNDED_BY[register]
        if bound in new and amount > new[bound]:
            raise ValueError(f'{register} {amount} exceeds {bound} ({new[bound]}){because})')
    total, rise = new.get('profile_velocity'), new.get('profile_acceleration')
    if timed and total and rise is not None and 2 * rise > total:
        raise ValueError(f'profile_acceleration {rise} ms is more than half of '
                         f'profile_velocity {total} ms: a time-based profile accelerates for '
                         'at most half of its time (the e-manual)')


def check_register_set(model: Model, values: Mapping[str, int], name: str, value: int,
                       mode: str) -> None:
    """
    Raise ValueError when setting name to value contradicts the servo's other registers.

    values holds the current values of (at least) related_registers(name); mode is the joint's
    operating mode; model the servo's (its homing rule). The one rule book for parameter files
    and write_register. A bound the model does not have (no acceleration_limit outside the
    XM430 manual's models) is not checked.
    """
    if _profile_role(model, name) or (name == 'drive_mode' and model.time_profile_bit is not None):
        _check_profile(model, values, model.role_of(name), value)
    else:
        bound = _BOUNDED_BY.get(name)
        if bound is not None and bound in values and abs(value) > values[bound]:
            raise ValueError(f'{name} {value} exceeds {bound} ({values[bound]})')
    for low, high in _ORDERED:
        if low not in values or high not in values:
            continue
        if name == low and value > values[high]:
            raise ValueError(f'{low} {value} is above {high} ({values[high]})')
        if name == high and value < values[low]:
            raise ValueError(f'{high} {value} is below {low} ({values[low]})')
    ignored = model.homing_position_mode_limit
    if (name == 'homing_offset' and mode in modes.SINGLE_TURN and ignored is not None
            and abs(value) > ignored):
        raise ValueError(f'position mode ignores a homing offset beyond +-{ignored} (the '
                         f'{model.name} manual); use extended_position for larger offsets')


def check_range(item: Item, value: int, model: Model | None = None) -> None:
    """
    Raise ValueError when a raw value is outside the item's static range.

    Given the model, a profile register that a time-based profile may count in ms is judged
    against the wider of its two ranges here; check_register_set judges it against the one
    its Drive Mode gives.
    """
    low, high = item.minimum, item.maximum
    unit = f' {item.unit}' if item.unit else ''
    if model is not None and _profile_role(model, item.name):
        high = max(high, TIME_PROFILE_MAX_MS)
        unit = f' ({item.unit or "raw"}, or ms in a time-based profile)'
    if not low <= value <= high:
        raise ValueError(f'{value} is outside the range of {item.name}: '
                         f'{low}..{high}{unit}')
