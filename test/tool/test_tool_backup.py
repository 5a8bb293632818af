"""`dxl backup/restore/diff`: the installed executable on a virtual_bus pty."""

import pathlib
import re
from typing import Dict

from dxl_cli import dxl, dxl_executable, on, one_error_line, TIMEOUT_S
import pexpect
from processes import StartVirtualBus, VirtualBusProcess
import pytest
import yaml

# Items a restore puts back in the mid-restore failure test: EEPROM first, then RAM gains.
CHANGED_EEPROM = {'return_delay_time': 7, 'moving_threshold': 20, 'temperature_limit': 70,
                  'max_voltage_limit': 150, 'min_voltage_limit': 100, 'pwm_limit': 800,
                  'current_limit': 1000, 'acceleration_limit': 30000, 'velocity_limit': 400,
                  'max_position_limit': 4000, 'min_position_limit': 100, 'secondary_id': 9,
                  'shutdown': 53, 'drive_mode': 1, 'homing_offset': 10}
CHANGED_RAM = {'velocity_i_gain': 1000, 'velocity_p_gain': 60, 'position_d_gain': 5,
               'position_i_gain': 6, 'position_p_gain': 700, 'feedforward_2nd_gain': 3,
               'feedforward_1st_gain': 4, 'profile_acceleration': 8, 'profile_velocity': 9}


@pytest.fixture
def bus(virtual_bus: StartVirtualBus) -> VirtualBusProcess:
    """Ids 3 and 4 (XM430-W210) and 5 (an XL430-W250), factory-set, at 57,600 bps."""
    return virtual_bus(ids=[3, 4, 5], extra_args=['--models', '1030', '1030', 'XL430-W250',
                                                  '--return-delay-time', '250'])


@pytest.fixture
def saved(bus: VirtualBusProcess, tmp_path: pathlib.Path) -> pathlib.Path:
    """Return a backup of id 3 with its gains and profiles."""
    path = tmp_path / 'id3.yaml'
    done = dxl(*on(bus, 'backup', '3', str(path), '--ram', 'gains,profiles'))
    assert done.returncode == 0, done.stderr
    return path


def edit(path: pathlib.Path, item: str, entry: str) -> pathlib.Path:
    """Return a copy of a backup with one item's line replaced (or added) by `item: entry`."""
    text = path.read_text()
    line = f'  {item}: {entry}'
    pattern = re.compile(rf'^  {re.escape(item)}: .*$', re.MULTILINE)
    text = pattern.sub(line, text) if pattern.search(text) else text + line + '\n'
    edited = path.with_name(f'edited_{item}.yaml')
    edited.write_text(text)
    return edited


def test_backup_holds_model_firmware_and_items_raw_and_si(saved: pathlib.Path) -> None:
    tree = yaml.safe_load(saved.read_text())
    assert tree['model'] == 'XM430-W210' and tree['model_number'] == 1030
    assert isinstance(tree['firmware'], int)
    items = tree['items']
    assert items['return_delay_time'] == {'raw': 250, 'si': 0.0005, 'unit': 's'}
    assert items['velocity_limit']['unit'] == 'rad/s'
    assert items['position_p_gain'] == {'raw': 800}
    assert 'profile_velocity' in items and 'goal_position' not in items
    assert 'model_number' not in items and 'protocol_version' not in items


def test_backup_change_diff_restore_diff_clean(bus: VirtualBusProcess,
                                               saved: pathlib.Path) -> None:
    assert dxl(*on(bus, 'set', '3', 'return_delay_time', '0', '--raw')).returncode == 0
    assert dxl(*on(bus, 'set', '3', 'position_p_gain', '900')).returncode == 0
    assert dxl(*on(bus, 'torque', '3', 'on')).returncode == 0
    done = dxl(*on(bus, 'diff', '3', str(saved)))
    assert done.returncode == 1
    differing = sorted(line.split(':')[0] for line in done.stdout.splitlines()
                       if not line.endswith('differ'))
    assert differing == ['position_p_gain', 'return_delay_time']
    done = dxl(*on(bus, 'restore', '3', str(saved)))
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1].endswith(': return_delay_time, position_p_gain')
    assert 'torque off for EEPROM writes, then back on' in done.stdout
    assert bus.get(3, 'return_delay_time') == 250 and bus.get(3, 'position_p_gain') == 800
    assert bus.get(3, 'torque_enable') == 1
    done = dxl(*on(bus, 'diff', '3', str(saved)))
    assert done.returncode == 0 and 'no difference' in done.stdout
    done = dxl(*on(bus, 'restore', '3', str(saved)))
    assert done.returncode == 0 and 'nothing written' in done.stdout


def test_diff_with_another_servo(bus: VirtualBusProcess) -> None:
    done = dxl(*on(bus, 'diff', '3', '--other', '4'))
    assert done.returncode == 0, done.stdout + done.stderr
    assert dxl(*on(bus, 'set', '4', 'velocity_p_gain', '77')).returncode == 0
    done = dxl(*on(bus, 'diff', '3', '--other', '4'))
    assert done.returncode == 1
    assert done.stdout.splitlines()[0] == 'velocity_p_gain: id 3 50, id 4 77'
    done = dxl(*on(bus, 'diff', '3', '--other', '5'))
    assert done.returncode == 2
    assert 'id 5 is a XL430-W250' in one_error_line(done, 'diff')


def test_identity_is_restored_only_when_asked(bus: VirtualBusProcess,
                                              saved: pathlib.Path) -> None:
    # The backup of id 3 restored onto id 4: everything but its id.
    assert dxl(*on(bus, 'set', '4', 'velocity_limit', '300', '--raw')).returncode == 0
    done = dxl(*on(bus, 'restore', '4', str(saved)))
    assert done.returncode == 0, done.stderr
    assert bus.get(4, 'velocity_limit') == 480 and bus.get(4, 'id') == 4


@pytest.mark.parametrize('item, entry, says', [
    ('no_such_item', '{raw: 1}', "item 'no_such_item' is not in the XM430-W210 table"),
    ('temperature_limit', '{raw: 250}', "item 'temperature_limit': raw 250 is outside its "
                                        'range 0..100'),
    ('temperature_limit', '{raw: hot}', "item 'temperature_limit': raw 'hot' is not an integer"),
    ('temperature_limit', '{raw: 70.5}', "item 'temperature_limit': raw 70.5 is not an "
                                         'integer'),
    ('velocity_limit', '{raw: 480, si: 1.0, unit: rad/s}', "item 'velocity_limit': si 1.0 "
                                                           'does not match raw 480'),
    ('model_number', '{raw: 1030}', "item 'model_number' cannot be written"),
    ('profile_velocity', '{raw: 600}', 'profile_velocity 600 exceeds velocity_limit (480)'),
])
def test_a_bad_file_is_refused_whole(bus: VirtualBusProcess, saved: pathlib.Path, item: str,
                                     entry: str, says: str) -> None:
    # A valid change first, so that a partial restore would show.
    changed = edit(saved, 'shutdown', '{raw: 20}')
    bad = edit(changed, item, entry)
    done = dxl(*on(bus, 'restore', '3', str(bad)))
    assert done.returncode == 2, done.stdout + done.stderr
    assert says in one_error_line(done, 'restore')
    assert bus.get(3, 'shutdown') == 52
    assert done.stdout == ''


def test_files_that_are_not_backups_are_refused(bus: VirtualBusProcess,
                                                tmp_path: pathlib.Path) -> None:
    for name, text, says in (('tab.yaml', 'items:\n\tx: 1\n', 'invalid YAML at line 2'),
                             ('list.yaml', '- 1\n', 'no "items:" mapping'),
                             ('missing.yaml', None, 'cannot be read')):
        path = tmp_path / name
        if text is not None:
            path.write_text(text)
        done = dxl(*on(bus, 'restore', '3', str(path)))
        assert done.returncode == 2
        assert says in one_error_line(done, 'restore')


def test_a_backup_of_another_model_is_refused_by_name(bus: VirtualBusProcess,
                                                      saved: pathlib.Path) -> None:
    done = dxl(*on(bus, 'restore', '5', str(saved)))
    assert done.returncode == 2
    assert ('is a backup of a XM430-W210; id 5 is a XL430-W250: refused'
            in one_error_line(done, 'restore'))


def changed_backup(saved: pathlib.Path) -> pathlib.Path:
    """Return a copy of a backup with every item of CHANGED_EEPROM and CHANGED_RAM changed."""
    path = saved
    for item, raw in {**CHANGED_EEPROM, **CHANGED_RAM}.items():
        path = edit(path, item, f'{{raw: {raw}}}')
    return path


def test_a_servo_lost_mid_restore_says_what_was_written(virtual_bus: StartVirtualBus,
                                                        tmp_path: pathlib.Path) -> None:
    # Replies held by a 10 ms adapter latency: the restore lasts long enough (each item is a
    # write and two reads) that the servo is unplugged when a few items are written.
    bus = virtual_bus(ids=[3], extra_args=['--timing', 'wire', '--latency-ms', '10'])
    saved = tmp_path / 'id3.yaml'
    assert dxl(*on(bus, 'backup', '3', str(saved), '--ram', 'gains,profiles')).returncode == 0
    wanted = changed_backup(saved)
    child = pexpect.spawn(dxl_executable(), on(bus, 'restore', '3', str(wanted)),
                          encoding='utf-8', timeout=TIMEOUT_S)
    try:
        child.expect(r'  (\w+) = ')
        first = child.match.group(1)
        assert bus.control('unplug 3') == 'ok unplug 3'
        child.expect(r'dxl restore: error: (.*); written: (.*); unsure: (\w+); not written: '
                     r'(.*)\r\n')
        written = child.match.group(2).split(', ')
        unsure = child.match.group(3)
        not_written = child.match.group(4).split(', ')
        child.expect(pexpect.EOF)
    finally:
        child.close()
    assert child.exitstatus == 1
    assert written[0] == first and not_written
    assert sorted([*written, unsure, *not_written]) == sorted({**CHANGED_EEPROM, **CHANGED_RAM})
    assert bus.control('plug 3') == 'ok plug 3'
    # EEPROM survives the power cycle: what was said written is, what was not is not.
    eeprom: Dict[str, int] = {name: bus.get(3, name) for name in CHANGED_EEPROM}
    for name in CHANGED_EEPROM:
        if name == unsure:
            continue
        if name in written:
            assert eeprom[name] == CHANGED_EEPROM[name], name
        else:
            assert eeprom[name] != CHANGED_EEPROM[name], name


def test_help_has_examples() -> None:
    for command in ('backup', 'restore', 'diff'):
        done = dxl(command, '--help')
        assert done.returncode == 0 and f'dxl {command} ' in done.stdout
