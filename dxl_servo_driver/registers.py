"""
What may be written where: the driver's write rules, one book for parameter files and services.

Registers the driver owns (torque, mode, id, baud, goals, the indirect map), registers nobody
may write (protocol_version), the static range of each item, and the rules between registers
that the servo enforces with a data limit error (a value bounded by a limit register, pairs that
must stay ordered, the homing offset position mode ignores). Pure: no I/O.
"""

from typing import Mapping

from dxl_servo_driver.models import Item, Model, modes

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
    return tuple(related)


def check_register_set(model: Model, values: Mapping[str, int], name: str, value: int,
                       mode: str) -> None:
    """
    Raise ValueError when setting name to value contradicts the servo's other registers.

    values holds the current values of (at least) related_registers(name); mode is the joint's
    operating mode; model the servo's (its homing rule). The one rule book for parameter files
    and write_register. A bound the model does not have (no acceleration_limit outside the
    XM430 manual's models) is not checked.
    """
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


def check_range(item: Item, value: int) -> None:
    """Raise ValueError when a raw value is outside the item's static range."""
    if not item.minimum <= value <= item.maximum:
        unit = f' {item.unit}' if item.unit else ''
        raise ValueError(f'{value} is outside the range of {item.name}: '
                         f'{item.minimum}..{item.maximum}{unit}')
