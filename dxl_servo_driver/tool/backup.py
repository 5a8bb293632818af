"""
`dxl backup`, `dxl restore`, `dxl diff`: a servo's settings to a YAML file and back.

  dxl backup ID FILE [--ram gains,profiles,limits] --port P [--baud B]
  dxl restore ID FILE [--identity] --port P [--baud B]
  dxl diff ID FILE --port P            dxl diff ID --other ID2 --port P

(or --params FILE for the port, baud rate and protocol, and joints' names for ids:
session.bus_settings).

A backup holds the servo's model (name and number), firmware, and every writable EEPROM item
(plus the RAM groups asked for) by name, raw and in SI units where the item has one. The raw
value is what is restored; the SI value is there to read, and when an edited file's SI value no
longer matches its raw one the file is refused rather than one of them guessed.

restore checks the whole file first (model, every item known, writable, an integer, within its
range and the rules between registers) and writes nothing if any of it is wrong; then it writes
only the items that differ, EEPROM with torque off (put back after), RAM after EEPROM (a profile
is bounded by an EEPROM limit), reads each back, and says which it wrote. The id and the baud
rate are kept in the file but restored only with --identity (a backup is usually restored onto a
replacement servo that already has its place on the bus); diff shows them only with --identity.
"""

import argparse
import datetime
import math
from typing import Any, Dict, List, Mapping, Sequence, Tuple

from dxl_servo_driver.models.base import Item, Model
from dxl_servo_driver.tool.common import (
    add_command, EXIT_FAILED, EXIT_OK, EXIT_OUTPUT, EXIT_USAGE, ToolError)
from dxl_servo_driver.tool.servo import (
    check_write, port_guard, read_items, si_unit, torque_off, value_text, write_verified)
from dxl_servo_driver.tool.session import (
    add_bus_arguments, bus_from_args, connect, from_si, servo_ref, ServoLink, to_si)
import yaml  # type: ignore[import-untyped]

FORMAT = 1
ID_HELP = "the servo id (or, with --params, its joint's name)"
IDENTITY = ('id', 'baud_rate')
# Never in a backup: the tool does not write it (servo.NOT_WRITTEN).
LEFT_OUT = ('protocol_version',)
# RAM groups a backup may add (--ram), by what their names say.
RAM_GROUPS = {
    'gains': lambda name: name.endswith('_gain'),
    'profiles': lambda name: name.startswith('profile_'),
    'limits': lambda name: 'limit' in name,
}


def backup_items(model: Model, ram_groups: Sequence[str]) -> List[Item]:
    """Return the items a backup holds: writable EEPROM ones, then the RAM groups'."""
    chosen = [item for item in model.items if item.area == 'eeprom' and item.access == 'RW'
              and model.role_of(item.name) not in LEFT_OUT]
    for group in ram_groups:
        wanted = RAM_GROUPS[group]
        chosen += [item for item in model.items if item.area == 'ram' and item.access == 'RW'
                   and wanted(item.name) and item not in chosen]
    return chosen


def _ram_groups(text: str) -> List[str]:
    groups = [part.strip() for part in text.split(',') if part.strip()]
    unknown = [group for group in groups if group not in RAM_GROUPS]
    if unknown:
        raise argparse.ArgumentTypeError(f'unknown RAM group {unknown[0]!r} (groups: '
                                         f'{", ".join(RAM_GROUPS)})')
    return groups


def register(sub: 'argparse._SubParsersAction[argparse.ArgumentParser]') -> None:
    """Add backup, restore and diff."""
    parser = add_command(
        sub, 'backup', "save a servo's EEPROM (and RAM groups) to a YAML file",
        "Save a servo's writable EEPROM items (and the RAM groups asked for) to a YAML file: "
        'model, firmware, each item raw and in SI units.',
        'dxl backup 3 elbow.yaml --ram gains,profiles --port /dev/ttyDXL --baud 1000000')
    parser.add_argument('id', type=servo_ref, metavar='ID', help=ID_HELP)
    parser.add_argument('file', metavar='FILE')
    parser.add_argument('--ram', type=_ram_groups, default=[], metavar='GROUPS',
                        help=f'RAM groups to save too, comma-separated: {", ".join(RAM_GROUPS)}')
    add_bus_arguments(parser)
    parser.set_defaults(run=port_guard(run_backup))

    parser = add_command(
        sub, 'restore', 'write a backup back to a servo (only what differs, verified)',
        'Write a backup file back to a servo of the same model: the whole file is checked '
        'first, then only the items that differ are written (EEPROM with torque off, put back '
        'after) and read back.',
        'dxl restore 3 elbow.yaml --port /dev/ttyDXL --baud 1000000')
    parser.add_argument('id', type=servo_ref, metavar='ID', help=ID_HELP)
    parser.add_argument('file', metavar='FILE')
    parser.add_argument('--identity', action='store_true',
                        help="restore the file's id and baud rate too")
    add_bus_arguments(parser)
    parser.set_defaults(run=port_guard(run_restore))

    parser = add_command(
        sub, 'diff', 'compare a servo with a backup file or with another servo',
        'Print the items that differ between a servo and a backup file (or another servo of '
        'the same model). Exit status 1 when something differs.',
        'dxl diff 3 elbow.yaml --port /dev/ttyDXL', 'dxl diff 3 --other 4 --port /dev/ttyDXL')
    parser.add_argument('id', type=servo_ref, metavar='ID', help=ID_HELP)
    parser.add_argument('file', nargs='?', metavar='FILE')
    parser.add_argument('--other', type=servo_ref, metavar='ID2',
                        help='compare with this servo instead of a file')
    parser.add_argument('--identity', action='store_true',
                        help='compare the id and baud rate too')
    add_bus_arguments(parser)
    parser.set_defaults(run=port_guard(run_diff))


def render(link: ServoLink, values: Mapping[str, int], ram_groups: Sequence[str]) -> str:
    """Return a backup file's text."""
    model = link.model
    lines = [f'# dxl backup of id {link.servo_id}, '
             f'{datetime.datetime.now().isoformat(timespec="seconds")}',
             '# raw is what `dxl restore` writes; si is there to read (edit raw).',
             f'format: {FORMAT}', f'model: {model.name}', f'model_number: {model.number}',
             f'firmware: {link.firmware}', f'id: {link.servo_id}',
             f'protocol: {link.bus.framer.version}.0',
             f'ram_groups: [{", ".join(ram_groups)}]', 'items:']
    for item in backup_items(model, ram_groups):
        raw = values[item.name]
        unit = si_unit(model, item)
        entry = f'raw: {raw}'
        if unit is not None:
            value, _ = to_si(model, item, raw)
            entry += f', si: {_yaml_float(value)}, unit: {unit}'
        lines.append(f'  {item.name}: {{{entry}}}   # {item.area}')
    return '\n'.join(lines) + '\n'


def _yaml_float(value: float) -> str:
    """Return a float as YAML 1.1 reads it back as one (its exponents need a dot and a sign)."""
    text = f'{value:.9g}'
    mantissa, e, exponent = text.partition('e')
    if '.' not in mantissa:
        mantissa += '.0'
    return mantissa + (e + exponent if e else '')


def run_backup(args: argparse.Namespace) -> int:
    """Save a servo to a file."""
    link = connect(bus_from_args(args), args.id)
    items = backup_items(link.model, args.ram)
    values = read_items(link, items)
    text = render(link, values, args.ram)
    try:
        with open(args.file, 'w', encoding='utf-8') as stream:
            stream.write(text)
    except OSError as exc:
        raise ToolError(f'{args.file} cannot be written: {exc.strerror}', EXIT_OUTPUT) from exc
    print(f'id {args.id} ({link.model.name}): {len(items)} items saved to {args.file}')
    return EXIT_OK


def load(path: str, link: ServoLink) -> Dict[str, int]:
    """
    Return {name: raw} of a backup file for this servo; ToolError naming what is wrong.

    Every item is checked here, before anything is written: known to the servo's table,
    writable, an integer raw value within its range, and an SI value (if any) that matches it.
    """
    try:
        with open(path, encoding='utf-8') as stream:
            tree = yaml.safe_load(stream)
    except OSError as exc:
        raise ToolError(f'{path} cannot be read: {exc.strerror}', EXIT_USAGE) from exc
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        where = f' at line {mark.line + 1}' if mark is not None else ''
        raise ToolError(f'{path}: not a backup file (invalid YAML{where})', EXIT_USAGE) from exc
    if not isinstance(tree, dict) or not isinstance(tree.get('items'), dict):
        raise ToolError(f'{path}: not a backup file (no "items:" mapping)', EXIT_USAGE)
    model = link.model
    if tree.get('model') != model.name:
        raise ToolError(f'{path} is a backup of a {tree.get("model")}; id {link.servo_id} is '
                        f'a {model.name}: refused', EXIT_USAGE)
    values: Dict[str, int] = {}
    for name, entry in tree['items'].items():
        values[str(name)] = _entry_value(path, model, str(name), entry)
    return values


def _entry_value(path: str, model: Model, name: str, entry: Any) -> int:
    """Return the raw value of one item entry of a backup file, checked alone."""
    if not model.has(name):
        raise ToolError(f'{path}: item {name!r} is not in the {model.name} table', EXIT_USAGE)
    item = model.item(name)
    if item.access != 'RW' or model.role_of(item.name) in LEFT_OUT:
        raise ToolError(f'{path}: item {name!r} cannot be written (read-only or left out of '
                        'backups)', EXIT_USAGE)
    if not isinstance(entry, dict) or 'raw' not in entry:
        raise ToolError(f'{path}: item {name!r}: expected {{raw: INTEGER, ...}}', EXIT_USAGE)
    raw = entry['raw']
    if isinstance(raw, bool) or not isinstance(raw, int):
        raise ToolError(f'{path}: item {name!r}: raw {raw!r} is not an integer', EXIT_USAGE)
    if not item.minimum <= raw <= item.maximum:
        raise ToolError(f'{path}: item {name!r}: raw {raw} is outside its range '
                        f'{item.minimum}..{item.maximum}', EXIT_USAGE)
    if 'si' in entry:
        si = entry['si']
        if isinstance(si, bool) or not isinstance(si, (int, float)) or not math.isfinite(si):
            raise ToolError(f'{path}: item {name!r}: si {si!r} is not a number', EXIT_USAGE)
        if from_si(model, item, float(si)) != raw:
            raise ToolError(f'{path}: item {name!r}: si {si} does not match raw {raw} (edit '
                            'raw; si is only there to read)', EXIT_USAGE)
    return raw


def plan(link: ServoLink, wanted: Mapping[str, int], identity: bool) -> List[Tuple[Item, int]]:
    """
    Return (item, raw) to write, EEPROM first, after checking the rules between registers.

    The rules (a profile within its limit, ordered limit pairs, ...) are judged on what the
    servo will hold once every item is written: its present values overlaid with the file's.
    """
    model = link.model
    items = [model.item(name) for name in wanted
             if identity or model.role_of(model.item(name).name) not in IDENTITY]
    present = read_items(link, items)
    final = dict(present)
    final.update({item.name: wanted[item.name] for item in items})
    writes: List[Tuple[Item, int]] = []
    for item in items:
        check_write(link, item, final[item.name], final)
        if present[item.name] != final[item.name]:
            writes.append((item, final[item.name]))
    # EEPROM before RAM; the id and baud rate last of all, as the servo moves with them.
    writes.sort(key=lambda pair: (model.role_of(pair[0].name) in IDENTITY,
                                  pair[0].area != 'eeprom'))
    return writes


def run_restore(args: argparse.Namespace) -> int:
    """Write a backup back to a servo."""
    link = connect(bus_from_args(args), args.id)
    wanted = load(args.file, link)
    writes = plan(link, wanted, args.identity)
    if not writes:
        print(f'id {args.id}: already as in {args.file}; nothing written')
        return EXIT_OK
    written: List[str] = []
    eeprom = any(item.area == 'eeprom' for item, _ in writes)
    try:
        with torque_off(link, eeprom) as was_on:
            for item, value in writes:
                write_verified(link, item, value)
                written.append(item.name)
                print(f'  {item.name} = {value_text(link.model, item, value)}', flush=True)
    except ToolError as exc:
        # The item in hand when it failed may or may not hold its new value (the write may have
        # gone through, its read-back not): said apart from both lists.
        rest = [item.name for item, _ in writes if item.name not in written]
        unsure = f'; unsure: {rest[0]}' if rest else ''
        raise ToolError(f'{exc}; written: {", ".join(written) or "nothing"}{unsure}; not '
                        f'written: {", ".join(rest[1:]) or "nothing"}') from exc
    note = ' (torque off for EEPROM writes, then back on)' if was_on else ''
    print(f'id {link.servo_id}: {len(written)} item(s) restored from {args.file}, each read '
          f'back{note}: {", ".join(written)}')
    return EXIT_OK


def run_diff(args: argparse.Namespace) -> int:
    """Print what differs between a servo and a file or another servo."""
    if (args.file is None) == (args.other is None):
        raise ToolError('give either FILE or --other ID2', EXIT_USAGE)
    bus = bus_from_args(args)
    link = connect(bus, args.id)
    model = link.model
    if args.file is not None:
        wanted = load(args.file, link)
        theirs = args.file
    else:
        other = connect(bus, args.other)
        if other.model.name != model.name:
            raise ToolError(f'id {args.other} is a {other.model.name}, id {args.id} a '
                            f'{model.name}: their tables differ', EXIT_USAGE)
        wanted = read_items(other, backup_items(model, tuple(RAM_GROUPS)))
        theirs = f'id {args.other}'
    items = [model.item(name) for name in wanted
             if args.identity or model.role_of(model.item(name).name) not in IDENTITY]
    present = read_items(link, items)
    differing = [item for item in items if present[item.name] != wanted[item.name]]
    for item in differing:
        print(f'{item.name}: id {args.id} {value_text(model, item, present[item.name])}, '
              f'{theirs} {value_text(model, item, wanted[item.name])}')
    if not differing:
        print(f'id {args.id} and {theirs}: no difference in {len(items)} items')
        return EXIT_OK
    print(f'{len(differing)} of {len(items)} items differ')
    return EXIT_FAILED
