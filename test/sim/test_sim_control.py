"""Control lines of virtual_bus: the parser, and execution against a real SimBus."""

from dxl_servo_driver.models import ALL_MODELS, xm430
from dxl_servo_driver.sim import control
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.control import Command, ControlError, handle_line, parse
import pytest

# An address at which no supported model's table starts a register (control lines accept any).
NOWHERE = next(address for address in range(1, 1024)
               if not any(item.address == address for model in ALL_MODELS
                          for item in model.items))


@pytest.mark.parametrize('line, expected', [
    ('drop 1 0.5', Command('drop', 1, 0.5)),
    ('corrupt 3 1', Command('corrupt', 3, 1.0)),
    ('  DROP   2   0  ', Command('drop', 2, 0.0)),
    ('error 1 overload', Command('error', 1, text='overload')),
    ('error 2 SHOCK', Command('error', 2, text='shock')),
    ('powercycle 252', Command('powercycle', 252)),
    ('unplug 0', Command('unplug', 0)),
    ('plug 7', Command('plug', 7)),
    ('load 1 1.5', Command('load', 1, 1.5)),
    ('voltage 1 11.1', Command('voltage', 1, 11.1)),
    ('tick 1 32760', Command('tick', 1, 32760.0)),
    ('get 1 present_position', Command('get', 1, text='present_position')),
    ('get 1 132', Command('get', 1, text='present_position')),
    ('get 1 0', Command('get', 1, text='model_number')),
    ('get 1 Goal_Position', Command('get', 1, text='goal_position')),
    ('dump 4', Command('dump', 4)),
    ('stats', Command('stats')),
    ('help', Command('help')),
])
def test_good_lines_parse(line: str, expected: Command) -> None:
    assert parse(line) == expected


@pytest.mark.parametrize('line, fragment', [
    ('', 'empty'),
    ('fly 1', 'unknown command'),
    ('drop', 'usage: drop ID PROBABILITY'),
    ('drop 1', 'usage: drop ID PROBABILITY'),
    ('drop 1 0.5 7', 'usage'),
    ('drop x 0.5', 'bad servo id'),
    ('drop 1.5 0.5', 'bad servo id'),
    ('drop 253 0.5', 'bad servo id'),
    ('drop -1 0.5', 'bad servo id'),
    ('drop 1 1.01', 'bad probability'),
    ('drop 1 -0.1', 'bad probability'),
    ('corrupt 1 nan', 'finite'),
    ('corrupt 1 half', 'expected a number'),
    ('error 1 melted', 'bad error kind'),
    ('error 1', 'usage'),
    ('load 1 -2', '>= 0'),
    ('load 1 inf', 'finite'),
    ('voltage 1 -12', '>= 0'),
    ('tick 1 32768', 'bad tick'),
    ('tick 1 -1', 'bad tick'),
    ('tick 1 1.5', 'bad tick'),
    ('tick 1', 'usage: tick ID MS'),
    ('get 1 no_such_register', 'unknown register'),
    (f'get 1 {NOWHERE}', f'no register starts at address {NOWHERE}'),
    ('get 1 -5', 'unknown register'),
    ('stats now', 'usage: stats'),
    ('help me', 'usage: help'),
    ('\x00\xff garbage', 'unknown command'),
])
def test_bad_lines_raise_a_clear_error(line: str, fragment: str) -> None:
    with pytest.raises(ControlError) as info:
        parse(line)
    assert fragment in str(info.value)
    assert '\n' not in str(info.value)


def test_every_register_name_and_address_parses() -> None:
    for item in xm430.ITEMS:
        assert parse(f'get 1 {item.name}').text == item.name
        assert parse(f'get 1 {item.address}').text == item.name


def test_blank_and_comment_lines_get_no_answer() -> None:
    bus = _bus([1])
    assert handle_line('', bus) is None
    assert handle_line('   \n', bus) is None
    assert handle_line('# a comment', bus) is None


# ---------------------------------------------------------------- execution against SimBus
def _bus(ids: list[int]) -> SimBus:
    return SimBus(ids, seed=1, boot_time_s=0.0)


def test_get_reads_a_register_by_name_and_address() -> None:
    bus = _bus([1, 2])
    model = xm430.MODEL_NUMBER
    assert handle_line('get 1 model_number', bus) == f'ok get 1 model_number={model}'
    assert handle_line('get 2 7', bus) == 'ok get 2 id=2'
    assert handle_line('get 1 baud_rate', bus) == 'ok get 1 baud_rate=1'


def test_dump_is_one_line_with_every_register() -> None:
    bus = _bus([3])
    answer = handle_line('dump 3', bus)
    assert answer is not None and answer.startswith('ok dump 3 ')
    assert '\n' not in answer
    pairs = dict(token.split('=') for token in answer.split()[3:])
    assert pairs['id'] == '3'
    assert pairs['model_number'] == str(xm430.MODEL_NUMBER)
    assert set(pairs) == set(bus.registers(3))


def test_fault_commands_reach_the_bus() -> None:
    bus = _bus([1])
    assert handle_line('error 1 overheat', bus) == 'ok error 1 overheat'
    assert bus.read_register(1, 'hardware_error_status') & 0x04
    assert handle_line('drop 1 1.0', bus) == 'ok drop 1 1'
    assert handle_line('corrupt 1 0.25', bus) == 'ok corrupt 1 0.25'
    assert handle_line('load 1 0.5', bus) == 'ok load 1 0.5'
    assert handle_line('voltage 1 11.1', bus) == 'ok voltage 1 11.1'
    assert handle_line('unplug 1', bus) == 'ok unplug 1'
    assert handle_line('plug 1', bus) == 'ok plug 1'
    assert handle_line('powercycle 1', bus) == 'ok powercycle 1'


def test_tick_sets_the_realtime_tick_and_it_counts_on() -> None:
    now = [10.0]
    bus = SimBus([1], clock=lambda: now[0], boot_time_s=0.0)
    assert handle_line('tick 1 32766', bus) == 'ok tick 1 32766'
    assert bus.read_register(1, 'realtime_tick') == 32766
    now[0] += 0.0015
    assert bus.read_register(1, 'realtime_tick') == 32767
    now[0] += 0.001
    assert bus.read_register(1, 'realtime_tick') == 0   # wrapped
    now[0] += 0.5
    assert bus.read_register(1, 'realtime_tick') == 500


def test_unknown_servo_is_an_error_line_not_a_crash() -> None:
    bus = _bus([1])
    for line in ('get 9 id', 'dump 9', 'drop 9 0.5', 'error 9 shock', 'powercycle 9',
                 'unplug 9', 'plug 9', 'load 9 1', 'voltage 9 12', 'tick 9 5'):
        answer = handle_line(line, bus)
        assert answer is not None and answer.startswith('error: '), line
        assert '\n' not in answer


def test_stats_and_help() -> None:
    bus = _bus([1])
    assert handle_line('stats', bus, lambda: 'replies=3') == 'ok stats replies=3'
    assert handle_line('help', bus) == f'ok {control.HELP_TEXT}'
    assert handle_line('bogus', bus) == 'error: unknown command \'bogus\' (try "help")'
