"""
One servo: `dxl info`, `get`, `set`, `torque`, `led`, `reboot`, `reset`.

  dxl info ID --port P [--baud B] [--protocol 1.0|2.0] [--indirect]
  dxl get ID NAME [NAME ...] --port P
  dxl set ID NAME VALUE [--raw] --port P
  dxl torque ID on|off --port P          dxl led ID on|off --port P
  dxl reboot ID --port P                 dxl reset ID [--level all|keep-id|keep-id-baud] [--yes]

Each also takes --params FILE (the driver's parameter file) for the port, baud rate and protocol,
and ID may then be a joint's name (session.bus_settings).

Values are shown raw and, where the item has a unit, in SI beside it (session.to_si). `set`
takes SI by default where the item has a unit (rad, rad/s, A, V, s ...), raw with --raw or where
it has none; Baud Rate also takes a rate in bps, Operating Mode a mode's name. Every write is
range-checked first (registers.check_range, check_register_set), an EEPROM item is written with
torque off (and torque put back after if it was on), and every write is read back.

The helpers here (read_items, write_verified, torque_off, value_text, parse_value) are shared
by backup.py and setup_servos.py.
"""

import argparse
import contextlib
import functools
import sys
import time
from typing import Callable, Dict, Iterator, List, Optional, Sequence

from dxl_servo_driver.errors import CommError, PortError, StatusError
from dxl_servo_driver.models import registers
from dxl_servo_driver.models.base import Item, Model
from dxl_servo_driver.tool.common import EXIT_FAILED, EXIT_OK, EXIT_PORT, EXIT_USAGE, ToolError
from dxl_servo_driver.tool.session import (
    add_bus_arguments, bus_from_args, connect, FACTORY_BAUD, from_si, PATIENCE_S, servo_ref,
    ServoLink, to_si)

# Items read together when they lie this close (bytes between them read and dropped): a table
# read in a few transactions rather than one per item.
READ_GAP = 16
READ_SPAN = 128
READ_ATTEMPTS = 3
# How long a servo may take to answer again after REBOOT or FACTORY_RESET.
RESTART_TIMEOUT_S = 3.0
# FACTORY_RESET's option byte per --level (the XM430 manual).
RESET_LEVELS = {'all': 0xFF, 'keep-id': 0x01, 'keep-id-baud': 0x02}
RESET_SAYS = {'all': 'every setting, the id (back to 1) and the baud rate (back to the '
                     'factory rate) included',
              'keep-id': 'every setting but the id (the baud rate back to the factory rate)',
              'keep-id-baud': 'every setting but the id and the baud rate'}
# Items the tool never writes: written, the servo would answer only in the other protocol.
NOT_WRITTEN = {'protocol_version': 'the servo would then answer only in the other protocol; '
                                   "change it with the manufacturer's tool"}


def si_unit(model: Model, item: Item, timed: bool = False) -> Optional[str]:
    """Return the SI unit an item is shown and set in, None where it has none (raw only)."""
    if not item.unit:
        return None
    _, unit = to_si(model, item, 0, timed)
    return None if unit == item.unit else unit


def time_profile(link: ServoLink) -> bool:
    """Return whether the servo's Drive Mode makes its profile registers times (ms) now."""
    model = link.model
    if model.time_profile_bit is None or not model.has('drive_mode'):
        return False
    drive_mode = read_items(link, [model.item('drive_mode')])['drive_mode']
    return registers.time_based(model, drive_mode)


def value_text(model: Model, item: Item, raw: int, timed: bool = False) -> str:
    """Return how a value is shown: raw, then SI (or the baud rate, the mode) beside it."""
    text = str(raw)
    unit = si_unit(model, item, timed)
    if unit is not None:
        value, _ = to_si(model, item, raw, timed)
        text += f' ({value:.6g} {unit})'
    elif item.name == 'baud_rate' and raw in model.bauds:
        text += f' ({model.bauds[raw]} bps)'
    elif item.name == model.mode_register and model.mode_register:
        names = {number: name for name, number in model.modes.items()}
        if raw in names:
            text += f' ({names[raw]})'
    return text


def parse_value(model: Model, item: Item, text: str, raw: bool = False,
                timed: bool = False) -> int:
    """Return the raw value a command-line value means (SI unless raw); ToolError if bad."""
    text = text.strip()
    if not raw and item.name == 'baud_rate' and text.isdigit() and int(text) > 7:
        by_rate = {bps: number for number, bps in model.bauds.items()}
        if int(text) not in by_rate:
            raise ToolError(f'{model.name} takes no baud rate of {text} bps (it takes '
                            f'{sorted(by_rate)})', EXIT_USAGE)
        return by_rate[int(text)]
    if not raw and item.name == model.mode_register and text in model.modes:
        return model.modes[text]
    unit = None if raw else si_unit(model, item, timed)
    try:
        if unit is None:
            return int(text, 0)
        return from_si(model, item, float(text), timed)
    except ValueError:
        want = 'an integer' if unit is None else f'a number in {unit}'
        raise ToolError(f'{item.name}: {text!r} is not {want}', EXIT_USAGE) from None


def read_items(link: ServoLink, items: Sequence[Item]) -> Dict[str, int]:
    """Return {name: raw} of items, read a block of neighbours at a time."""
    ordered = sorted(items, key=lambda item: item.address)
    values: Dict[str, int] = {}
    group: List[Item] = []

    def flush() -> None:
        if not group:
            return
        start = group[0].address
        end = max(item.address + item.size for item in group)
        # A second read must agree only where nothing changes by itself: a block holding
        # Present Position or the Realtime Tick differs between two reads on a loaded host.
        steady = not any(item.area == 'ram' and item.access == 'R' for item in group)
        give_up_s = time.monotonic() + PATIENCE_S
        attempt = 0
        while True:
            attempt += 1
            try:
                data = link.bus.read(link.servo_id, start, end - start, confirm=steady)
                break
            except StatusError as exc:
                if len(group) > 1:
                    # A block read runs a few bytes past it (bus.read's tag): at the table's
                    # end the servo refuses it, and its items are read one at a time.
                    for member in list(group):
                        values.update(read_items(link, [member]))
                    group.clear()
                    return
                raise ToolError(f'id {link.servo_id}: {exc}') from exc
            except CommError as exc:
                # A late or garbled reply (a baud rate just changed, a noisy line, a busy
                # computer): again, as session.retried does.
                if attempt >= READ_ATTEMPTS and time.monotonic() >= give_up_s:
                    raise ToolError(f'id {link.servo_id}: {exc}') from exc
        for item in group:
            offset = item.address - start
            values[item.name] = item.decode(data[offset:offset + item.size])
        group.clear()

    for item in ordered:
        if group:
            end = max(member.address + member.size for member in group)
            if (item.address - end > READ_GAP
                    or item.address + item.size - group[0].address > READ_SPAN):
                flush()
        group.append(item)
    flush()
    return values


def check_write(link: ServoLink, item: Item, value: int,
                others: Optional[Dict[str, int]] = None) -> None:
    """Raise ToolError (usage) when value may not be written to item; others: known values."""
    if item.access != 'RW':
        raise ToolError(f'{item.name} is read-only', EXIT_USAGE)
    role = link.model.role_of(item.name)
    if role in NOT_WRITTEN:
        raise ToolError(f'{item.name} is not written by dxl: {NOT_WRITTEN[role]}', EXIT_USAGE)
    try:
        registers.check_range(item, value, link.model)
        related = registers.related_registers(link.model, role)
        # The rules speak the XM430 manual's names (roles); the tables may call them otherwise.
        values = {link.model.role_of(name): raw for name, raw in (others or {}).items()}
        missing = [name for name in related if name not in values]
        if missing:
            read = read_items(link, [link.item(name) for name in missing])
            values.update({name: read[link.item(name).name] for name in missing})
        values[role] = value   # the ordered pairs are judged with both of their values
        registers.check_register_set(link.model, values, role, value, mode_of(link, values))
    except ValueError as exc:
        raise ToolError(str(exc), EXIT_USAGE) from None


def mode_of(link: ServoLink, values: Dict[str, int]) -> str:
    """Return the servo's operating mode by name ('' when its table has no mode register)."""
    register = link.model.mode_register
    if not register:
        return ''
    raw = values.get(register)
    if raw is None:
        raw = read_items(link, [link.item(register)])[register]
    names = {number: name for name, number in link.model.modes.items()}
    return names.get(raw, '')


@contextlib.contextmanager
def torque_off(link: ServoLink, needed: bool = True) -> Iterator[bool]:
    """
    Hold torque off inside the block (EEPROM writes need it); yield whether it was on.

    Torque is put back on afterwards if it was on, at the servo's id then (an id write moves
    it), even when the block failed. A servo that stopped answering cannot be put back: the
    error the block raised says so, and the caller reports it.
    """
    if not needed:
        yield False
        return
    try:
        was_on = bool(link.read('torque_enable'))
        if was_on:
            link.write('torque_enable', 0)
    except CommError as exc:
        raise ToolError(f'id {link.servo_id}: torque could not be switched off: {exc}') from exc
    try:
        yield was_on
    except ToolError as failed:
        if was_on:
            try:
                link.write('torque_enable', 1)
            except CommError:
                raise ToolError(f'{failed}; torque stays off', failed.status) from failed
        raise
    if was_on:
        try:
            link.write('torque_enable', 1)
        except CommError as exc:
            raise ToolError(f'id {link.servo_id}: torque was switched off for an EEPROM '
                            f'write and could not be put back on: {exc}') from exc


def write_verified(link: ServoLink, item: Item, value: int) -> None:
    """
    Write one item and read it back; follow the servo when the item is its id or baud rate.

    The caller holds torque off for an EEPROM item (torque_off). ToolError when the write is
    refused, the servo stops answering or the value read back differs.
    """
    try:
        link.bus.write(link.servo_id, item.address, item.encode(value))
    except CommError as exc:
        raise ToolError(f'id {link.servo_id}: writing {item.name} = {value} failed: '
                        f'{exc}') from exc
    where = ''
    if item.name == 'id':
        link.servo_id = value
        where = f' at its new id {value}'
    elif item.name == 'baud_rate' and value in link.model.bauds:
        link.bus.set_baud(link.model.bauds[value])
        where = f' at its new rate {link.bus.baud_bps} bps'
    back: Optional[int] = None
    for _ in range(3):   # the servo restarts its UART after a baud change: a retry or two
        try:
            back = read_items(link, [item])[item.name]
            break
        except ToolError as exc:
            error = exc
            time.sleep(0.05)
    if back is None:
        raise ToolError(f'id {link.servo_id}: {item.name} was written but does not read '
                        f'back{where}: {error}')
    if back != value:
        raise ToolError(f'id {link.servo_id}: {item.name} written as {value} reads back as '
                        f'{back}')


def set_item(link: ServoLink, item: Item, value: int) -> bool:
    """Write one checked item (torque off for EEPROM, put back); return if torque was on."""
    with torque_off(link, item.area == 'eeprom') as was_on:
        write_verified(link, item, value)
    return was_on


def wait_for(link: ServoLink, timeout_s: float = RESTART_TIMEOUT_S) -> bool:
    """Return whether the servo answers a ping within timeout_s (after a restart)."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            link.bus.ping(link.servo_id, probe=True)
            return True
        except CommError:
            if time.monotonic() > deadline:
                return False
            time.sleep(0.05)


Command = Callable[[argparse.Namespace], int]


def port_guard(command: Command) -> Command:
    """Return the command with a port lost on the way (PortError) as its ToolError (exit 3)."""
    @functools.wraps(command)
    def guarded(args: argparse.Namespace) -> int:
        try:
            return command(args)
        except PortError as exc:
            raise ToolError(f'the port was lost: {exc}', EXIT_PORT) from exc
    return guarded


def _parser(sub: 'argparse._SubParsersAction[argparse.ArgumentParser]', name: str,
            help_text: str, example: str) -> argparse.ArgumentParser:
    parser = sub.add_parser(name, help=help_text, description=help_text,
                            epilog=f'example:\n  {example}',
                            formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('id', type=servo_ref, metavar='ID',
                        help="the servo id (or, with --params, its joint's name)")
    return parser


def register(sub: 'argparse._SubParsersAction[argparse.ArgumentParser]') -> None:
    """Add info, get, set, torque, led, reboot and reset."""
    parser = _parser(sub, 'info', "show a servo's control table (EEPROM and RAM), raw and SI, "
                     'values that differ from the default marked',
                     'dxl info 1 --port /dev/ttyDXL --baud 1000000')
    parser.add_argument('--indirect', action='store_true',
                        help='show the indirect address/data items too')
    add_bus_arguments(parser)
    parser.set_defaults(run=port_guard(run_info))

    parser = _parser(sub, 'get', 'read items of a servo by name',
                     'dxl get 1 present_position present_temperature --port /dev/ttyDXL')
    parser.add_argument('names', nargs='+', metavar='NAME', help='item names (snake_case)')
    add_bus_arguments(parser)
    parser.set_defaults(run=port_guard(run_get))

    parser = _parser(sub, 'set', 'write one item of a servo (SI units where it has one), '
                     'checked, EEPROM with torque off, read back',
                     'dxl set 1 profile_velocity 2.5 --port /dev/ttyDXL     # rad/s\n'
                     '  dxl set 1 return_delay_time 0 --raw --port /dev/ttyDXL')
    parser.add_argument('name', metavar='NAME', help='item name (snake_case)')
    parser.add_argument('value', metavar='VALUE', help='the value (SI unless --raw)')
    parser.add_argument('--raw', action='store_true', help='VALUE is the raw register value')
    add_bus_arguments(parser)
    parser.set_defaults(run=port_guard(run_set))

    for name, what in (('torque', 'torque_enable'), ('led', 'led')):
        parser = _parser(sub, name, f"switch a servo's {what} on or off (read back)",
                         f'dxl {name} 1 off --port /dev/ttyDXL')
        parser.add_argument('state', choices=('on', 'off'))
        add_bus_arguments(parser)
        parser.set_defaults(run=port_guard(run_switch), item=what)

    parser = _parser(sub, 'reboot', 'reboot a servo (clears a hardware error) and wait for it',
                     'dxl reboot 1 --port /dev/ttyDXL')
    add_bus_arguments(parser)
    parser.set_defaults(run=port_guard(run_reboot))

    parser = _parser(sub, 'reset', 'factory-reset a servo (asks first unless --yes)',
                     'dxl reset 3 --level keep-id-baud --port /dev/ttyDXL --baud 1000000')
    parser.add_argument('--level', choices=tuple(RESET_LEVELS), default='keep-id-baud',
                        help='what survives the reset (default keep-id-baud)')
    parser.add_argument('--yes', action='store_true', help='do not ask for confirmation')
    add_bus_arguments(parser)
    parser.set_defaults(run=port_guard(run_reset))


def _link(args: argparse.Namespace) -> ServoLink:
    return connect(bus_from_args(args), args.id)


def run_info(args: argparse.Namespace) -> int:
    """Print the control table."""
    link = _link(args)
    model = link.model
    shown = [item for item in model.items
             if args.indirect or not item.name.startswith(('indirect_address_',
                                                           'indirect_data_'))]
    values = read_items(link, shown)
    timed = registers.time_based(model, values.get('drive_mode'))
    print(f'id {link.servo_id}: {model.name} (model {model.number}), firmware '
          f'{link.firmware}, {link.bus.baud_bps} bps, Protocol {link.bus.framer.version}.0')
    print('  (* differs from the factory default, shown after it)')
    for area in ('eeprom', 'ram'):
        print(f'{area.upper()}:')
        for item in shown:
            if item.area != area:
                continue
            raw = values[item.name]
            mark = ''
            if raw != item.initial and item.access == 'RW':
                mark = f'  * default {value_text(model, item, item.initial, timed)}'
            print(f'  {item.address:4d} {item.name:<26} {item.access:<2} '
                  f'{value_text(model, item, raw, timed)}{mark}')
    return EXIT_OK


def run_get(args: argparse.Namespace) -> int:
    """Print items by name."""
    link = _link(args)
    items = [link.item(name) for name in args.names]
    values = read_items(link, items)
    timed = time_profile(link)
    for item in items:
        print(f'{item.name} = {value_text(link.model, item, values[item.name], timed)}')
    return EXIT_OK


def run_set(args: argparse.Namespace) -> int:
    """Write one item, checked, read back."""
    link = _link(args)
    item = link.item(args.name)
    # A profile register is a time where Drive Mode says so: its SI value is in seconds then.
    timed = time_profile(link)
    value = parse_value(link.model, item, args.value, args.raw, timed)
    check_write(link, item, value)
    before = read_items(link, [item])[item.name]
    if link.model.role_of(item.name) == 'id' and value != before and _answers(link, value):
        raise ToolError(f'id {value} is taken: another servo answers to it at '
                        f'{link.bus.baud_bps} bps', EXIT_USAGE)
    if before == value:
        print(f'id {args.id}: {item.name} is already '
              f'{value_text(link.model, item, value, timed)}')
        return EXIT_OK
    was_on = set_item(link, item, value)
    note = ' (torque off for the EEPROM write, then back on)' if was_on else ''
    print(f'id {link.servo_id}: {item.name} = {value_text(link.model, item, value, timed)} '
          f'(was {value_text(link.model, item, before, timed)}), read back{note}')
    return EXIT_OK


def _answers(link: ServoLink, servo_id: int) -> bool:
    """Return whether some servo answers to servo_id on the link's bus (two pings)."""
    for _ in range(2):
        try:
            link.bus.ping(servo_id, probe=True)
            return True
        except CommError:
            continue
    return False


def run_switch(args: argparse.Namespace) -> int:
    """Switch torque or the LED on or off."""
    link = _link(args)
    item = link.item(args.item)
    write_verified(link, item, 1 if args.state == 'on' else 0)
    print(f'id {args.id}: {item.name} {args.state}')
    return EXIT_OK


def run_reboot(args: argparse.Namespace) -> int:
    """Reboot a servo and wait for it to answer again."""
    link = _link(args)
    if not link.model.reboot:
        raise ToolError(f'{link.model.name} has no REBOOT instruction (Protocol 1.0): cycle its '
                        'power instead')
    try:
        link.bus.reboot(link.servo_id)
    except CommError as exc:
        raise ToolError(f'id {args.id}: reboot failed: {exc}') from exc
    if not wait_for(link):
        raise ToolError(f'id {args.id} acknowledged the reboot but does not answer '
                        f'{RESTART_TIMEOUT_S:g} s later')
    print(f'id {args.id}: rebooted, answering again')
    return EXIT_OK


def run_reset(args: argparse.Namespace) -> int:
    """Factory-reset a servo, after confirmation."""
    link = _link(args)
    model = link.model
    factory_bps = model.bauds.get(model.item('baud_rate').initial, FACTORY_BAUD)
    factory_id = model.item('id').initial
    if link.bus.framer.reset_params(RESET_LEVELS[args.level]) is None:
        raise ToolError(f'Protocol {link.bus.framer.version}.0 servos reset everything, the id '
                        'and the baud rate included: use --level all', EXIT_USAGE)
    new_id = factory_id if args.level == 'all' else link.servo_id
    new_bps = link.bus.baud_bps if args.level == 'keep-id-baud' else factory_bps
    print(f'id {args.id} ({model.name}): a factory reset restores {RESET_SAYS[args.level]}. '
          f'Afterwards it answers as id {new_id} at {new_bps} bps, torque off.')
    if not args.yes:
        if not sys.stdin.isatty():
            raise ToolError('not confirmed: stdin is not a terminal (use --yes)', EXIT_USAGE)
        answer = input('Reset it? [y/N] ').strip().lower()
        if answer not in ('y', 'yes'):
            print('not reset')
            return EXIT_FAILED
    try:
        link.bus.factory_reset(link.servo_id, RESET_LEVELS[args.level])
    except CommError as exc:
        raise ToolError(f'id {args.id}: factory reset failed: {exc}') from exc
    except ValueError as exc:   # BadRequest: Protocol 1.0 resets everything
        raise ToolError(str(exc), EXIT_USAGE) from exc
    link.servo_id = new_id
    link.bus.set_baud(new_bps)
    if not wait_for(link):
        raise ToolError(f'id {args.id} acknowledged the reset but id {new_id} does not answer '
                        f'at {new_bps} bps {RESTART_TIMEOUT_S:g} s later')
    print(f'reset: id {new_id} answers at {new_bps} bps')
    return EXIT_OK
