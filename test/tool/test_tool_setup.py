"""
`dxl setup`: factory-new servos plugged in one at a time, on virtual_bus, driven as a user would.

The simulator starts every servo unplugged and at the factory settings (`--ids 1 1 1
--unplugged`: id 1, 57,600 bps, Return Delay Time 250); `plug #N` connects the N-th when the
tool asks for it. The tool runs as the installed executable under pexpect (a terminal).
"""

import pathlib
import re
import sys
from typing import List

from dxl_cli import dxl, dxl_executable, on, one_error_line, TIMEOUT_S
import pexpect
from processes import StartVirtualBus, VirtualBusProcess
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
PROMPT = r'Press Enter when it is powered: '
ARM_MODELS = ['XM540-W270', 'XM540-W270', 'XM540-W270', 'XM430-W350', 'XM430-W350',
              'XL430-W250', 'XL330-M288']
# config/arm_sim.yaml: its servos in the order setup takes them (a joint's second servo after it).
ARM_IDS = [1, 2, 7, 3, 4, 5, 6]


def factory_new(virtual_bus: StartVirtualBus, count: int,
                models: List[str] = ()) -> VirtualBusProcess:
    """Return a bus of count factory-new servos (id 1, 57,600 bps, 500 us), all unplugged."""
    extra = ['--ids', *['1'] * count, '--unplugged', '--return-delay-time', '250']
    if models:
        extra += ['--models', *models]
    return virtual_bus(extra_args=extra)


def spawn(bus: VirtualBusProcess, *args: str) -> pexpect.spawn:
    """Start `dxl setup` on the bus in a terminal."""
    child = pexpect.spawn(dxl_executable(), ['setup', '--port', bus.device, *args],
                          encoding='utf-8', timeout=TIMEOUT_S)
    child.logfile_read = sys.stdout   # what the user saw, shown when a test fails
    return child


def settings(bus: VirtualBusProcess, slot: int) -> List[int]:
    """Return [id, baud_rate, return_delay_time] of the slot-th servo."""
    values = []
    for name in ('id', 'baud_rate', 'return_delay_time'):
        answer = bus.control(f'get #{slot} {name}')
        match = re.fullmatch(rf'ok get #{slot} {name}=(\d+)', answer)
        assert match, answer
        values.append(int(match.group(1)))
    return values


def finish(child: pexpect.spawn) -> int:
    """Wait for the end; return the exit status."""
    try:
        child.expect(pexpect.EOF)
    finally:
        child.close()
    return child.exitstatus if child.exitstatus is not None else -child.signalstatus


def test_three_new_servos_plugged_one_by_one(virtual_bus: StartVirtualBus) -> None:
    bus = factory_new(virtual_bus, 3)
    child = spawn(bus, '--ids', '1', '2', '3', '--baud', '1000000')
    for slot in (1, 2, 3):
        child.expect(rf'\[{slot}/3\] Connect servo {slot} of 3 alone \(it becomes id {slot};')
        child.expect(PROMPT)
        assert bus.control(f'plug #{slot}') == f'ok plug #{slot}'
        child.sendline('')
        child.expect(rf'\[{slot}/3\] servo {slot} of 3: id {slot}, 1000000 bps, Return Delay '
                     'Time 0: checked at its new id and baud rate')
    child.expect('done: 3 servo')
    assert finish(child) == 0
    # Baud Rate 3 is 1 Mbps; the earlier servos stayed on the bus through the later ones.
    assert [settings(bus, slot) for slot in (1, 2, 3)] == [[1, 3, 0], [2, 3, 0], [3, 3, 0]]
    done = dxl(*on(bus, 'get', '3', 'return_delay_time', '--baud', '1000000'))
    assert done.returncode == 0 and done.stdout == 'return_delay_time = 0 (0 s)\n'


def test_the_parameter_file_scripted_with_yes(virtual_bus: StartVirtualBus) -> None:
    bus = factory_new(virtual_bus, len(ARM_IDS), ARM_MODELS)
    child = spawn(bus, '--params', str(ROOT / 'config' / 'arm_sim.yaml'), '--yes', '--wait',
                  '60')
    count = len(ARM_IDS)
    for slot, servo_id in enumerate(ARM_IDS, 1):
        child.expect(rf'\[{slot}/{count}\] waiting up to 60 s for the (second )?servo of joint '
                     rf'\w+ \({ARM_MODELS[slot - 1]}\) \(it becomes id {servo_id}\)')
        assert bus.control(f'plug #{slot}') == f'ok plug #{slot}'
        child.expect(rf'\[{slot}/{count}\] .*: id {servo_id}, 1000000 bps, Return Delay Time 0')
    child.expect('done: 7 servo')
    assert finish(child) == 0
    assert [settings(bus, slot) for slot in range(1, count + 1)] == [
        [servo_id, 3, 0] for servo_id in ARM_IDS]


def test_two_servos_at_once_are_refused_then_one_is_set_up(
        virtual_bus: StartVirtualBus) -> None:
    bus = factory_new(virtual_bus, 2)
    child = spawn(bus, '--ids', '4', '--baud', '57600')
    child.expect(PROMPT)
    for slot in (1, 2):
        assert bus.control(f'plug #{slot}') == f'ok plug #{slot}'
    child.sendline('')
    # Two new servos: both id 1 at 57,600 bps, their replies collide.
    child.expect(r'refused: replies collided at 57600 bps.*connect one servo at a time')
    child.expect(PROMPT)
    assert settings(bus, 1) == [1, 1, 250] and settings(bus, 2) == [1, 1, 250]
    assert bus.control('unplug #2') == 'ok unplug #2'
    child.sendline('')
    child.expect(r'servo 1 of 1: id 4, 57600 bps, Return Delay Time 0')
    assert finish(child) == 0
    assert settings(bus, 1) == [4, 1, 0]
    assert settings(bus, 2) == [1, 1, 250]


def test_two_ids_answering_are_refused(virtual_bus: StartVirtualBus) -> None:
    bus = virtual_bus(ids=[1, 2], extra_args=['--return-delay-time', '250'])
    child = spawn(bus, '--ids', '5', '--baud', '1000000', '--yes', '--wait', '5')
    child.expect(r'dxl setup: error: servo 1 of 1 refused: 2 servos answered at 57600 bps '
                 r'\(id 1, id 2\); connect one servo at a time; set up: none; servo 1 of 1: '
                 'nothing written')
    assert finish(child) == 1
    assert bus.get(1, 'baud_rate') == 1 and bus.get(2, 'baud_rate') == 1


def test_an_id_taken_on_the_bus_is_refused(virtual_bus: StartVirtualBus) -> None:
    bus = virtual_bus(ids=[2, 1], extra_args=['--return-delay-time', '250'])
    # Id 2 is already at the bus's rate: only the new servo, id 1, answers at 57,600 bps.
    assert dxl(*on(bus, 'set', '2', 'baud_rate', '1000000')).returncode == 0
    done = dxl('setup', '--port', bus.device, '--ids', '2', '--baud', '1000000', '--yes',
               '--wait', '5')
    assert done.returncode == 1
    assert ('refused: id 2 is taken: a servo already on the bus (XM430-W210) answers to it at '
            '1000000 bps' in one_error_line(done, 'setup'))
    assert bus.get(1, 'id') == 1 and bus.get(1, 'return_delay_time') == 250


def test_the_wrong_model_and_a_rate_it_cannot_take_are_refused(
        virtual_bus: StartVirtualBus, tmp_path: pathlib.Path) -> None:
    bus = virtual_bus(ids=[1], extra_args=['--return-delay-time', '250'])
    params = tmp_path / 'one.yaml'
    params.write_text('/**:\n  ros__parameters:\n    port: /dev/ttyDXL\n    baud_rate: 1000000\n'
                      '    joints: [elbow]\n    elbow:\n      id: 3\n      model: XM540-W270\n')
    done = dxl('setup', '--port', bus.device, '--params', str(params), '--yes', '--wait', '5')
    assert done.returncode == 1
    assert ('the servo found (id 1 at 57600 bps) is a XM430-W210; the servo of joint elbow is '
            'a XM540-W270 in the file' in one_error_line(done, 'setup'))
    done = dxl('setup', '--port', bus.device, '--ids', '3', '--baud', '10500000', '--yes',
               '--wait', '5')
    assert done.returncode == 1
    assert 'is a XM430-W210, which cannot run at 10500000 bps' in one_error_line(done, 'setup')
    assert bus.get(1, 'id') == 1 and bus.get(1, 'baud_rate') == 1


def test_yes_gives_up_when_no_servo_appears(virtual_bus: StartVirtualBus) -> None:
    bus = factory_new(virtual_bus, 1)
    done = dxl('setup', '--port', bus.device, '--ids', '2', '--yes', '--wait', '1')
    assert done.returncode == 1
    assert 'waiting up to 1 s for servo 1 of 1 (it becomes id 2)' in done.stdout
    assert ('no servo for servo 1 of 1 appeared within 1 s: no servo answered at 57600, '
            '1000000 bps' in one_error_line(done, 'setup'))
    assert settings(bus, 1) == [1, 1, 250]


def test_ctrl_c_at_a_prompt_says_what_was_done(virtual_bus: StartVirtualBus) -> None:
    bus = factory_new(virtual_bus, 2)
    child = spawn(bus, '--ids', '1', '2')
    child.expect(PROMPT)
    assert bus.control('plug #1') == 'ok plug #1'
    child.sendline('')
    child.expect(r'servo 1 of 2: id 1, 1000000 bps')
    child.expect(PROMPT)
    child.sendintr()
    child.expect(r'dxl setup: interrupted; set up: servo 1 of 2 \(id 1\); servo 2 of 2: '
                 r'nothing written\r\n')
    assert finish(child) == 130
    assert settings(bus, 1) == [1, 3, 0]


@pytest.mark.parametrize('args, says', [
    (['--ids', '1', '1'], '--ids: an id is listed twice'),
    (['--ids', '1', '--baud', '12345'], '--baud 12345: no servo takes that rate'),
    (['--ids', '1'], 'stdin is not a terminal: use --yes'),
    (['--params', '/nonexistent.yaml'], 'parameter file /nonexistent.yaml does not exist'),
])
def test_bad_arguments(args: List[str], says: str) -> None:
    done = dxl('setup', '--port', '/dev/ttyDXL_none', *args)
    assert done.returncode == 2
    assert says in one_error_line(done, 'setup')


def test_help_has_an_example() -> None:
    done = dxl('setup', '--help')
    assert done.returncode == 0 and 'dxl setup --port' in done.stdout
