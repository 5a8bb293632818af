"""`dxl info/get/set/torque/led/reboot/reset`: the installed executable on a virtual_bus pty."""

import math
from typing import List

from dxl_cli import dxl, dxl_executable, on, one_error_line, TIMEOUT_S
import pexpect
from processes import StartVirtualBus, VirtualBusProcess
import pytest


@pytest.fixture
def bus(virtual_bus: StartVirtualBus) -> VirtualBusProcess:
    """Two factory-set servos, ids 3 and 4, at 57,600 bps."""
    return virtual_bus(ids=[3, 4], extra_args=['--return-delay-time', '250'])


@pytest.mark.parametrize('command', ['info', 'get', 'set', 'torque', 'led', 'reboot', 'reset'])
def test_help_has_an_example(command: str) -> None:
    done = dxl(command, '--help')
    assert done.returncode == 0, done.stderr
    assert 'example' in done.stdout and f'dxl {command} ' in done.stdout


def test_info_shows_the_table_with_changed_values_marked(bus: VirtualBusProcess) -> None:
    done = dxl(*on(bus, 'info', '3'))
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith('id 3: XM430-W210 (model 1030), firmware ')
    assert 'EEPROM:' in lines and 'RAM:' in lines
    assert lines.index('EEPROM:') < lines.index('RAM:')
    delay = next(line for line in lines if ' return_delay_time ' in line)
    assert '250 (0.0005 s)' in delay and '*' not in delay
    ident = next(line for line in lines if line.split()[1:2] == ['id'])
    assert '3' in ident.split() and '* default 1' in ident   # 3 is not the factory id
    assert not any('indirect_data_' in line for line in lines)
    assert any(' present_position ' in line and 'rad)' in line for line in lines)


def test_get_reads_raw_and_si(bus: VirtualBusProcess) -> None:
    done = dxl(*on(bus, 'get', '3', 'velocity_limit', 'baud_rate', 'operating_mode'))
    assert done.returncode == 0, done.stderr
    raw = bus.get(3, 'velocity_limit')
    rad_s = raw * 0.229 * 2.0 * math.pi / 60.0
    assert done.stdout.splitlines() == [f'velocity_limit = {raw} ({rad_s:.6g} rad/s)',
                                        'baud_rate = 1 (57600 bps)',
                                        'operating_mode = 3 (position)']


def test_set_takes_si_units_and_reads_back(bus: VirtualBusProcess) -> None:
    done = dxl(*on(bus, 'set', '3', 'profile_velocity', '2.5'))
    assert done.returncode == 0, done.stderr
    expected = round(2.5 / (0.229 * 2.0 * math.pi / 60.0))
    assert bus.get(3, 'profile_velocity') == expected
    assert 'read back' in done.stdout
    done = dxl(*on(bus, 'set', '3', 'profile_velocity', '7', '--raw'))
    assert done.returncode == 0, done.stderr
    assert bus.get(3, 'profile_velocity') == 7
    assert bus.get(4, 'profile_velocity') == 0   # the other servo untouched


def test_a_time_based_profile_is_set_and_shown_in_seconds(bus: VirtualBusProcess) -> None:
    # Drive Mode's time-based bit: Profile Velocity and Acceleration are ms, so SI is seconds.
    done = dxl(*on(bus, 'set', '3', 'drive_mode', '4', '--raw'))
    assert done.returncode == 0, done.stderr
    for name, seconds, raw in (('profile_velocity', '2.0', 2000),
                               ('profile_acceleration', '0.3', 300)):
        done = dxl(*on(bus, 'set', '3', name, seconds))
        assert done.returncode == 0, done.stderr
        assert bus.get(3, name) == raw
    done = dxl(*on(bus, 'get', '3', 'profile_velocity', 'profile_acceleration'))
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ['profile_velocity = 2000 (2 s)',
                                        'profile_acceleration = 300 (0.3 s)']
    # The other servo, velocity-based, still takes rad/s.
    done = dxl(*on(bus, 'get', '4', 'profile_velocity'))
    assert done.returncode == 0 and 'rad/s' in done.stdout, done.stdout


def test_eeprom_write_with_torque_on_turns_it_off_and_back_on(bus: VirtualBusProcess) -> None:
    assert dxl(*on(bus, 'torque', '3', 'on')).returncode == 0
    assert bus.get(3, 'torque_enable') == 1
    done = dxl(*on(bus, 'set', '3', 'return_delay_time', '0', '--raw'))
    assert done.returncode == 0, done.stderr
    assert bus.get(3, 'return_delay_time') == 0
    assert bus.get(3, 'torque_enable') == 1
    assert 'torque off for the EEPROM write, then back on' in done.stdout
    # By name of a mode and by a rate in bps, where the item is a number.
    done = dxl(*on(bus, 'set', '3', 'operating_mode', 'velocity'))
    assert done.returncode == 0, done.stderr
    assert bus.get(3, 'operating_mode') == 1 and bus.get(3, 'torque_enable') == 1


@pytest.mark.parametrize('args, says', [
    (['temperature_limit', '101'], '101 is outside the range of temperature_limit: 0..100'),
    (['model_number', '5'], 'model_number is read-only'),
    (['no_such_item', '5'], "has no item 'no_such_item'"),
    (['profile_velocity', '600', '--raw'], 'profile_velocity 600 exceeds velocity_limit'),
    (['velocity_limit', 'fast'], "velocity_limit: 'fast' is not a number in rad/s"),
    (['protocol_version', '1'], 'protocol_version is not written by dxl'),
])
def test_set_refuses_bad_values_and_writes_nothing(bus: VirtualBusProcess, args: List[str],
                                                   says: str) -> None:
    names = ('temperature_limit', 'profile_velocity', 'velocity_limit', 'protocol_version')
    before = {name: bus.get(3, name) for name in names}
    done = dxl(*on(bus, 'set', '3', *args))
    assert done.returncode == 2, done.stdout + done.stderr
    assert says in one_error_line(done, 'set')
    assert {name: bus.get(3, name) for name in before} == before


def test_set_keeps_limit_pairs_ordered(bus: VirtualBusProcess) -> None:
    assert dxl(*on(bus, 'set', '3', 'max_position_limit', '2000', '--raw')).returncode == 0
    done = dxl(*on(bus, 'set', '3', 'min_position_limit', '3000', '--raw'))
    assert done.returncode == 2
    assert ('min_position_limit 3000 is above max_position_limit (2000)'
            in one_error_line(done, 'set'))
    assert bus.get(3, 'min_position_limit') == 0


def test_set_id_refuses_an_id_taken(bus: VirtualBusProcess) -> None:
    done = dxl(*on(bus, 'set', '3', 'id', '4'))
    assert done.returncode == 2
    error = one_error_line(done, 'set')
    assert 'id 4 is taken: another servo answers to it at 57600 bps' in error
    assert bus.get(3, 'id') == 3
    done = dxl(*on(bus, 'set', '3', 'id', '8'))
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith('id 8: id = 8 (was 3)')
    assert bus.get(8, 'id') == 8


def test_a_missing_servo_is_one_error_line(bus: VirtualBusProcess) -> None:
    done = dxl(*on(bus, 'get', '9', 'id'))
    assert done.returncode == 1
    assert 'id 9 does not answer at 57600 bps' in one_error_line(done, 'get')


def test_a_port_that_cannot_be_opened_is_exit_3() -> None:
    done = dxl('info', '1', '--port', '/dev/ttyDXL_not_there')
    assert done.returncode == 3
    assert '/dev/ttyDXL_not_there' in one_error_line(done, 'info')


def test_torque_led_and_reboot(bus: VirtualBusProcess) -> None:
    for command, item in (('torque', 'torque_enable'), ('led', 'led')):
        assert dxl(*on(bus, command, '4', 'on')).returncode == 0
        assert bus.get(4, item) == 1
    done = dxl(*on(bus, 'reboot', '4'))
    assert done.returncode == 0, done.stderr
    assert 'answering again' in done.stdout
    # A restart puts the RAM back to its defaults.
    assert bus.get(4, 'led') == 0 and bus.get(4, 'torque_enable') == 0
    assert dxl(*on(bus, 'led', '4', 'on')).returncode == 0
    assert dxl(*on(bus, 'led', '4', 'off')).returncode == 0
    assert bus.get(4, 'led') == 0


def test_reset_keeps_id_and_baud_by_default_and_asks_first(bus: VirtualBusProcess) -> None:
    assert dxl(*on(bus, 'set', '3', 'return_delay_time', '0', '--raw')).returncode == 0
    # No terminal and no --yes: refused before anything is sent.
    done = dxl(*on(bus, 'reset', '3'))
    assert done.returncode == 2 and '--yes' in one_error_line(done, 'reset')
    assert bus.get(3, 'return_delay_time') == 0
    # A terminal user who answers no.
    child = pexpect.spawn(dxl_executable(), on(bus, 'reset', '3'), encoding='utf-8',
                          timeout=TIMEOUT_S)
    try:
        child.expect('keeps|restores')
        child.expect(r'Reset it\? \[y/N\] ')
        child.sendline('n')
        child.expect('not reset')
        child.expect(pexpect.EOF)
    finally:
        child.close()
    assert child.exitstatus == 1
    assert bus.get(3, 'return_delay_time') == 0
    # And one who answers yes: every setting back but the id and the baud rate.
    child = pexpect.spawn(dxl_executable(), on(bus, 'reset', '3'), encoding='utf-8',
                          timeout=TIMEOUT_S)
    try:
        child.expect(r'Reset it\? \[y/N\] ')
        child.sendline('y')
        child.expect('reset: id 3 answers at 57600 bps')
        child.expect(pexpect.EOF)
    finally:
        child.close()
    assert child.exitstatus == 0
    assert bus.get(3, 'return_delay_time') == 250 and bus.get(3, 'id') == 3


def test_reset_all_goes_back_to_id_1_at_the_factory_rate(
        virtual_bus: StartVirtualBus) -> None:
    bus = virtual_bus(ids=[5], baud_bps=1_000_000)
    done = dxl(*on(bus, 'reset', '5', '--level', 'all', '--yes', '--baud', '1000000'))
    assert done.returncode == 0, done.stderr
    assert 'answers as id 1 at 57600 bps' in done.stdout
    assert done.stdout.strip().endswith('reset: id 1 answers at 57600 bps')
    done = dxl(*on(bus, 'get', '1', 'id', 'baud_rate'))
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ['id = 1', 'baud_rate = 1 (57600 bps)']
