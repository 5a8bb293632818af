"""
The console's table (sim/control.py COMMANDS) and the adapter faults it reaches on virtual_bus.

Every row is in `virtual_bus --help` and in the console's `help` answer; each `adapter ...` line
sets the FaultEngine between the servos and the pty, and a serial client sees its effect.
"""

import dataclasses
import subprocess
import sys
import time
from typing import Iterator

from dxl_servo_driver.protocol import encode_instruction, Instruction
from dxl_servo_driver.protocol import protocol1
from dxl_servo_driver.sim import control
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.fault_engine import FaultEngine, Faults
from processes import LINE_TIMEOUT_S, ROOT, StartVirtualBus, VirtualBusProcess
import pytest
import serial

BAUD = 1_000_000
PING_1 = encode_instruction(1, Instruction.PING)
REPLY_SIZE = 14   # a Protocol 2.0 ping's status packet
ADAPTER_ROWS = [spec for spec in control.COMMANDS if spec.name.startswith('adapter ')]


# ---------------------------------------------------------------- the table, written out
def entry(lines: list[str], left: str) -> str:
    """Return the --help entry of left: its line, and the next (a long left has it below)."""
    for number, line in enumerate(lines):
        text = line.strip()
        if text == left or text.startswith(left + '  '):
            return line + '\n' + (lines[number + 1] if number + 1 < len(lines) else '')
    raise AssertionError(f'{left!r} is not in virtual_bus --help')


def test_every_row_is_in_virtual_bus_help() -> None:
    done = subprocess.run([sys.executable, '-m', 'dxl_servo_driver.sim.virtual_bus', '--help'],
                          capture_output=True, text=True, timeout=LINE_TIMEOUT_S * 3,
                          cwd=str(ROOT))
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    for spec in control.COMMANDS:
        assert spec.summary in entry(lines, spec.usage), spec.usage
        for arg in spec.args:
            assert arg.meaning in entry(lines, arg.word), arg.word


def test_every_row_is_in_the_console_help_answer(virtual_bus: StartVirtualBus) -> None:
    vb = virtual_bus([1])
    answer = vb.control('help')
    assert answer == f'ok {control.HELP_TEXT}'
    entries = answer.removeprefix('ok commands: ').split(' | ')
    assert entries == [spec.help_usage for spec in control.COMMANDS]
    assert vb.control('get 1 id') == 'ok get 1 id=1'   # one line: the next answer is its own


def test_the_help_answer_keeps_the_commands_it_had() -> None:
    before = ('drop ID P | corrupt ID P | error ID overload|overheat|voltage|encoder|shock | '
              'powercycle ID | unplug ID | plug ID | load ID NM | voltage ID VOLTS | tick ID MS')
    after = 'get ID NAME|ADDRESS | dump ID | stats | help'
    assert control.HELP_TEXT.startswith(f'commands: {before} | adapter ')
    assert control.HELP_TEXT.endswith(f' | {after}')


def test_the_help_answer_lists_the_hand_and_the_servo_references() -> None:
    entries = control.HELP_TEXT.removeprefix('commands: ').split(' | ')
    assert 'turn ID RAD [SECONDS]' in entries
    assert 'stops ID MIN_RAD MAX_RAD|off' in entries
    assert '#N, the N-th of --ids' in control.SERVO_ID.meaning
    # Every command naming a servo takes #N too.
    with_servo = [spec for spec in control.COMMANDS if control.SERVO_ID in spec.args]
    assert {spec.name for spec in with_servo} >= {'plug', 'unplug', 'turn', 'stops', 'get'}
    for spec in with_servo:
        assert control.parse(f'{spec.name} #3 ' + ' '.join(
            '1' if arg.slot == 'number' else 'id' if arg.slot == 'register' else 'overload'
            if arg is control.ERROR_KIND else 'on' for arg in spec.args[1:])).servo == '#3'


def test_optional_and_alternative_arguments() -> None:
    assert control.parse('turn #2 1.5').numbers == (1.5,)
    assert control.parse('turn 4 -7 0').numbers == (-7.0, 0.0)
    assert control.parse('stops 1 OFF').text == 'off'
    assert control.parse('stops 1 -0.5 0.5').numbers == (-0.5, 0.5)
    for line, error in (('turn 1', 'usage: turn ID RAD [SECONDS]'),
                        ('turn 1 1 1 1', 'usage: turn ID RAD [SECONDS]'),
                        ('stops 1 off 2', 'usage: stops ID MIN_RAD MAX_RAD|off'),
                        ('stops 1 0', 'usage: stops ID MIN_RAD MAX_RAD|off'),
                        ('turn 1 1 -2', "bad time (s) '-2': expected >= 0"),
                        ('turn 1 nan', "bad angle (rad) 'nan': expected a finite number"),
                        ('turn #x 1', "bad servo '#x'")):
        with pytest.raises(control.ControlError) as info:
            control.parse(line)
        assert error in str(info.value), line
    bus = SimBus([1], boot_time_s=0.0)
    assert control.handle_line('stops 1 1 -1', bus) == \
        'error: bad range 1..-1 rad: expected MIN <= MAX'
    assert control.handle_line('turn 1 0.5', bus) == 'ok turn 1 0.5'


def test_markdown_has_one_row_per_command() -> None:
    text = control.commands_markdown()
    lines = text.splitlines()
    assert lines[0] == '| Command | Arguments | What it does |'
    rows = [line for line in lines if line.startswith('| `')]
    assert len(rows) == len(control.COMMANDS)
    for row, spec in zip(rows, control.COMMANDS):
        # Pipes inside a cell are escaped: each row has exactly its three cells.
        assert row.replace('\\|', '').count('|') == 4, row
        assert row.startswith(f'| `{spec.usage.replace("|", chr(92) + "|")}` |')
        assert spec.summary in row
        for arg in spec.args:
            assert arg.meaning.replace('|', '\\|') in row


def test_names_and_usages_are_unique() -> None:
    names = [spec.name for spec in control.COMMANDS]
    assert len(set(names)) == len(names)
    assert all(spec.summary and '\n' not in spec.summary for spec in control.COMMANDS)


# ---------------------------------------------------------------- adapter lines, in process
@pytest.fixture
def engine() -> FaultEngine:
    return FaultEngine(seed=1)


@pytest.fixture
def bus() -> SimBus:
    return SimBus([1], seed=1, boot_time_s=0.0)


@pytest.mark.parametrize('line, answer, faults', [
    ('adapter echo on', 'ok adapter echo on', Faults(echo=True)),
    ('ADAPTER Echo OFF', 'ok adapter echo off', Faults()),
    ('adapter echo-pieces 4 0.5', 'ok adapter echo-pieces 4 0.5',
     Faults(echo_chunk=4, echo_gap_ms=0.5)),
    ('adapter late 0.25 5 50', 'ok adapter late 0.25 5 50',
     Faults(late_probability=0.25, late_ms=(5.0, 50.0))),
    ('adapter duplicate 1', 'ok adapter duplicate 1', Faults(duplicate_probability=1.0)),
    ('adapter truncate 0.5', 'ok adapter truncate 0.5', Faults(truncate_probability=0.5)),
    ('adapter noise 0.1 2 8', 'ok adapter noise 0.1 2 8',
     Faults(noise_probability=0.1, noise_bytes=(2, 8))),
    ('adapter drop 0.01', 'ok adapter drop 0.01', Faults(drop_probability=0.01)),
    ('adapter delay 1 3.5', 'ok adapter delay 1 3.5', Faults(delay_ms=(1.0, 3.5))),
    ('adapter freezes 0.02 20 100', 'ok adapter freezes 0.02 20 100',
     Faults(freeze_probability=0.02, freeze_ms=(20.0, 100.0))),
])
def test_an_adapter_line_sets_the_engine(engine: FaultEngine, bus: SimBus, line: str,
                                         answer: str, faults: Faults) -> None:
    assert control.handle_line(line, bus, adapter=engine) == answer
    assert engine.faults == faults
    assert control.handle_line('adapter clear', bus, adapter=engine) == 'ok adapter clear'
    assert engine.faults == Faults()


def test_every_adapter_setting_is_reachable(engine: FaultEngine, bus: SimBus) -> None:
    lines = ['adapter echo on', 'adapter echo-pieces 3 1', 'adapter late 1 1 2',
             'adapter duplicate 1', 'adapter truncate 1', 'adapter noise 1 2 3', 'adapter drop 1',
             'adapter delay 1 2', 'adapter freezes 1 1 2']
    for line in lines:
        assert control.handle_line(line, bus, adapter=engine) == f'ok {line}'
    defaults = Faults()
    unchanged = [item.name for item in dataclasses.fields(Faults)
                 if getattr(engine.faults, item.name) == getattr(defaults, item.name)]
    assert unchanged == []
    assert {spec.name.split()[1] for spec in ADAPTER_ROWS} == {
        line.split()[1] for line in lines} | {'freeze', 'clear', 'stats'}


def test_adapter_freeze_and_stats(engine: FaultEngine, bus: SimBus) -> None:
    assert control.handle_line('adapter freeze 5000', bus, adapter=engine) == \
        'ok adapter freeze 5000'
    assert engine.engaged(time.monotonic())
    assert control.handle_line('adapter stats', bus, adapter=engine) == (
        'ok adapter stats replies=0 passed_bytes=0 echoed_bytes=0 freezes=1 late=0 duplicated=0 '
        'truncated=0 noise=0 noise_bytes=0 dropped=0 delayed=0 overflow_bytes=0')
    assert control.handle_line('adapter clear', bus, adapter=engine) == 'ok adapter clear'
    assert not engine.engaged(time.monotonic())


def test_only_a_fault_that_is_on_engages_the_adapter(engine: FaultEngine, bus: SimBus) -> None:
    # Disengaged, virtual_bus writes the replies to the pty itself, unchanged and on time.
    for line in ('adapter late 0 1 2', 'adapter freezes 0 1 2', 'adapter noise 0 1 2',
                 'adapter echo-pieces 2 1', 'adapter delay 0 0', 'adapter echo off'):
        assert control.handle_line(line, bus, adapter=engine) == f'ok {line}'
        assert not engine.engaged(time.monotonic()), line
    for line in ('adapter delay 0 1', 'adapter echo on', 'adapter drop 0.5'):
        assert control.handle_line(line, bus, adapter=engine) == f'ok {line}'
        assert engine.engaged(time.monotonic()), line
        assert control.handle_line('adapter clear', bus, adapter=engine) == 'ok adapter clear'


@pytest.mark.parametrize('line, error', [
    ('adapter', 'error: usage: adapter echo|echo-pieces|late|duplicate|truncate|noise|drop|'
                'delay|freezes|freeze|clear|stats ...'),
    ('adapter fly', 'error: unknown command \'adapter fly\' (try "help")'),
    ('adapter echo', 'error: usage: adapter echo on|off'),
    ('adapter echo maybe', "error: bad switch 'maybe': expected on|off"),
    ('adapter late 2 1 1', "error: bad probability '2': expected 0..1"),
    ('adapter late 0.5 1', 'error: usage: adapter late PROBABILITY MIN_MS MAX_MS'),
    ('adapter delay 50 5', 'error: bad range 50..5 ms: expected MIN <= MAX'),
    ('adapter delay -1 5', "error: bad duration (ms) '-1': expected >= 0"),
    ('adapter delay 1 inf', "error: bad duration (ms) 'inf': expected a finite number"),
    ('adapter noise 1 0 3', "error: bad size (bytes) '0': expected an integer >= 1"),
    ('adapter noise 1 5 3', 'error: bad range 5..3 bytes: expected MIN <= MAX'),
    ('adapter echo-pieces 1.5 0', "error: bad size (bytes) '1.5': expected an integer >= 0"),
    ('adapter freeze x', "error: bad duration (ms) 'x': expected a number"),
    ('adapter stats now', 'error: usage: adapter stats'),
])
def test_bad_adapter_lines_are_one_error_line(engine: FaultEngine, bus: SimBus, line: str,
                                              error: str) -> None:
    assert control.handle_line(line, bus, adapter=engine) == error
    assert engine.faults == Faults()


def test_adapter_lines_without_an_adapter_are_an_error(bus: SimBus) -> None:
    for spec in ADAPTER_ROWS:
        line = ' '.join([spec.name] + ['1' if arg.slot == 'number' else 'on'
                                       for arg in spec.args])
        assert control.handle_line(line, bus) == \
            "error: no adapter here: the adapter commands act on virtual_bus's pty", line


# ---------------------------------------------------------------- on virtual_bus, as a client
@pytest.fixture
def vb(virtual_bus: StartVirtualBus) -> VirtualBusProcess:
    return virtual_bus([1, 2], BAUD, extra_args=['--seed', '7'])


@pytest.fixture
def port(vb: VirtualBusProcess) -> Iterator[serial.Serial]:
    with serial.Serial(vb.device, BAUD, timeout=LINE_TIMEOUT_S) as ser:
        yield ser


def ping(ser: serial.Serial, servo_id: int = 1) -> bytes:
    """Send a ping; return its plain reply (the adapter without faults), for comparisons."""
    ser.reset_input_buffer()
    ser.write(encode_instruction(servo_id, Instruction.PING))
    reply = ser.read(REPLY_SIZE)
    assert len(reply) == REPLY_SIZE, reply.hex()
    return reply


def test_echo_on_the_pty(vb: VirtualBusProcess, port: serial.Serial) -> None:
    reply = ping(port)
    assert vb.control('adapter echo on') == 'ok adapter echo on'
    port.write(PING_1)
    assert port.read(len(PING_1) + REPLY_SIZE) == PING_1 + reply
    assert vb.control('adapter echo-pieces 3 20') == 'ok adapter echo-pieces 3 20'
    start_s = time.monotonic()
    port.write(PING_1)
    assert port.read(len(PING_1) + REPLY_SIZE) == PING_1 + reply
    assert time.monotonic() - start_s >= 0.02 * (len(PING_1) // 3 - 1)  # the pieces' gaps
    assert vb.control('adapter echo off') == 'ok adapter echo off'
    assert ping(port) == reply
    stats = vb.control('adapter stats')
    assert f' echoed_bytes={2 * len(PING_1)} ' in stats, stats


def test_duplicate_truncate_noise_and_drop_on_the_pty(vb: VirtualBusProcess,
                                                      port: serial.Serial) -> None:
    reply = ping(port, 2)
    assert vb.control('adapter duplicate 1') == 'ok adapter duplicate 1'
    port.write(encode_instruction(2, Instruction.PING))
    assert port.read(2 * REPLY_SIZE) == reply + reply
    assert vb.control('adapter clear') == 'ok adapter clear'
    assert vb.control('adapter truncate 1') == 'ok adapter truncate 1'
    port.timeout = 0.3
    port.write(encode_instruction(2, Instruction.PING))
    cut = port.read(REPLY_SIZE)
    assert 1 <= len(cut) < REPLY_SIZE and reply.startswith(cut), cut.hex()
    assert vb.control('adapter truncate 0') == 'ok adapter truncate 0'
    port.timeout = LINE_TIMEOUT_S
    assert vb.control('adapter noise 1 5 5') == 'ok adapter noise 1 5 5'
    port.write(encode_instruction(2, Instruction.PING))
    data = port.read(5 + REPLY_SIZE)
    assert len(data) == 5 + REPLY_SIZE and data.endswith(reply), data.hex()
    assert vb.control('adapter noise 0 1 1') == 'ok adapter noise 0 1 1'
    assert vb.control('adapter drop 1') == 'ok adapter drop 1'
    port.timeout = 0.3
    port.write(encode_instruction(2, Instruction.PING))
    assert port.read(1) == b''
    assert vb.control('adapter clear') == 'ok adapter clear'
    port.timeout = LINE_TIMEOUT_S
    assert ping(port, 2) == reply
    counts = dict(item.split('=') for item in vb.control('adapter stats').split()[3:])
    assert {name: counts[name] for name in ('duplicated', 'truncated', 'noise', 'dropped')} == \
        {'duplicated': '1', 'truncated': '1', 'noise': '1', 'dropped': '1'}


def test_delay_freeze_and_late_on_the_pty(vb: VirtualBusProcess, port: serial.Serial) -> None:
    reply_1, reply_2 = ping(port, 1), ping(port, 2)
    assert vb.control('adapter delay 150 150') == 'ok adapter delay 150 150'
    start_s = time.monotonic()
    assert ping(port) == reply_1
    assert time.monotonic() - start_s >= 0.15
    assert vb.control('adapter delay 0 0') == 'ok adapter delay 0 0'
    start_s = time.monotonic()   # before the line: the freeze begins after this
    assert vb.control('adapter freeze 200') == 'ok adapter freeze 200'
    assert ping(port) == reply_1
    assert time.monotonic() - start_s >= 0.2
    assert vb.control('adapter freezes 1 150 150') == 'ok adapter freezes 1 150 150'
    start_s = time.monotonic()
    assert ping(port) == reply_1
    assert time.monotonic() - start_s >= 0.15
    assert vb.control('adapter freezes 0 0 0') == 'ok adapter freezes 0 0 0'
    assert vb.control('adapter clear') == 'ok adapter clear'
    assert vb.control('adapter late 1 300 300') == 'ok adapter late 1 300 300'
    start_s = time.monotonic()
    assert ping(port, 1) == reply_1
    assert vb.control('adapter late 0 0 0') == 'ok adapter late 0 0 0'
    assert port.read(REPLY_SIZE) in (reply_1, reply_2)   # a copy of one of the earlier replies
    assert time.monotonic() - start_s >= 0.3
    assert ping(port, 1) == reply_1   # nothing else was held


def test_adapter_on_wire_timing(virtual_bus: StartVirtualBus) -> None:
    vb = virtual_bus([1], BAUD, extra_args=['--timing', 'wire', '--latency-ms', '1'])
    with serial.Serial(vb.device, BAUD, timeout=LINE_TIMEOUT_S) as port:
        reply = ping(port)
        assert vb.control('adapter duplicate 1') == 'ok adapter duplicate 1'
        port.write(PING_1)
        assert port.read(2 * REPLY_SIZE) == reply + reply
        assert vb.control('adapter clear') == 'ok adapter clear'
        assert ping(port) == reply
    stats = vb.control('stats')
    assert stats.startswith('ok stats replies=')


def test_protocol_1_servos_have_a_protocol_1_adapter(virtual_bus: StartVirtualBus) -> None:
    vb = virtual_bus([1], BAUD, extra_args=['--models', 'AX-12A'])
    ping_1 = protocol1.encode_instruction(1, protocol1.Instruction1.PING)
    with serial.Serial(vb.device, BAUD, timeout=LINE_TIMEOUT_S) as port:
        port.write(ping_1)
        reply = port.read(6)
        assert reply[:3] == b'\xff\xff\x01' and len(reply) == 6, reply.hex()
        # Cut by the 1.0 framing, the reply is a packet: duplicated whole.
        assert vb.control('adapter duplicate 1') == 'ok adapter duplicate 1'
        port.write(ping_1)
        assert port.read(12) == reply + reply
    counts = vb.control('adapter stats')
    assert ' duplicated=1 ' in counts and ' passed_bytes=0 ' in counts, counts
