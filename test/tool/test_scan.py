"""`scan` against virtual_bus subprocesses on pseudo-terminals, and its pure helpers."""

import itertools
import math
import os
import pathlib
import re
import subprocess
from typing import Any, Callable, Dict, List, Optional, Tuple

from ament_index_python.packages import get_package_prefix
from dxl_servo_driver import config
from dxl_servo_driver.bus import (
    Bus, default_bauds, find_one_servo, FoundServo, FRAMERS, MAX_RETURN_DELAY_S, NoServo,
    NotOneServo, OneServo, protocol_1_bauds)
from dxl_servo_driver.errors import CommError
from dxl_servo_driver.models import ALL_MODELS, model_for, modes, xm430
from dxl_servo_driver.models.names import OTHER_MODELS
from dxl_servo_driver.port.serial_device import open_port
from dxl_servo_driver.tool import scan
from dxl_servo_driver.tool.scan_file import build_parameters, choose_baud, render_parameter_file
from dxl_servo_driver.tool.scan_report import describe
import pexpect
from processes import StartVirtualBus, VirtualBusProcess
import pytest
import yaml

MANUAL = model_for(xm430.MODEL_NUMBER)   # the XM430 manual's table

# Tests that expect replies give each one plenty of time: a loaded machine may not schedule the
# virtual_bus process at once. Nothing here measures time.
SLOW_MACHINE_TIMEOUT_MS = '200'
XM430_LINE = 'id {id}: model 1030 (XM430-W210), firmware 45, {baud} bps, mode {mode}, ' \
             'hardware errors: {errors}'

# A model still refused (by its name), whichever names.py has left.
REFUSED = min(OTHER_MODELS)


Starter = Callable[[List[int], int], VirtualBusProcess]


@pytest.fixture
def start(virtual_bus: StartVirtualBus, tmp_path: pathlib.Path) -> Starter:
    """Start virtual_bus instances, each on its own link in tmp_path (stopped by virtual_bus)."""
    links = (tmp_path / f'ttyDXL{n}' for n in itertools.count())
    return lambda ids, baud_bps: virtual_bus(ids, baud_bps, next(links))


def run_scan(capsys: pytest.CaptureFixture, *args: str) -> Tuple[int, List[str], List[str]]:
    """Run scan.main in this process; return (status, stdout lines, stderr lines)."""
    status = scan.main(list(args))
    captured = capsys.readouterr()
    return status, captured.out.splitlines(), captured.err.splitlines()


def with_bus(device: str, baud_bps: int, action: Callable[[Bus], Any]) -> Any:
    """Open the pty through the driver's Bus, run action, close it (scan needs it free)."""
    port = open_port(device, baud_bps)
    try:
        return action(Bus(port, baud_bps, latency_timer_s=0.2))
    finally:
        port.close()


def retried(call: Callable[[], Any], attempts: int = 5) -> Any:
    """Run a bus transaction, again on a failure (a busy machine may answer late)."""
    for attempt in range(attempts):
        try:
            return call()
        except CommError:
            if attempt == attempts - 1:
                raise
    raise AssertionError('unreachable')


def flatten(document: Dict[str, Any]) -> Dict[str, Any]:
    """Return the flat parameters (`joint.id`) of a `/**: ros__parameters:` document."""
    flat: Dict[str, Any] = {}

    def walk(prefix: str, node: Dict[str, Any]) -> None:
        for key, value in node.items():
            if isinstance(value, dict):
                walk(f'{prefix}{key}.', value)
            else:
                flat[prefix + key] = value

    walk('', document['/**']['ros__parameters'])
    return flat


# ---- against virtual_bus ------------------------------------------------------------------------
def test_servos_at_57600_are_found_with_every_field(start: Starter,
                                                    capsys: pytest.CaptureFixture) -> None:
    vb = start([1, 2], 57600)
    status, out, err = run_scan(capsys, '--port', str(vb.link), '--baud', '57600',
                                '--protocol-timeout-ms', SLOW_MACHINE_TIMEOUT_MS,
                                '--protocol', '2.0')
    assert status == scan.EXIT_OK
    assert out == [XM430_LINE.format(id=1, baud=57600, mode='position', errors='none'),
                   XM430_LINE.format(id=2, baud=57600, mode='position', errors='none')]
    assert 'scanning 57600 bps (broadcast ping) ...' in err
    assert any('found 2 servos' in line for line in err)


def test_an_injected_hardware_error_is_shown_decoded(start: Starter,
                                                     capsys: pytest.CaptureFixture) -> None:
    vb = start([1, 2], 57600)
    answer = vb.control('error 2 overload')
    assert answer is not None and answer.startswith('ok'), answer
    status, out, _ = run_scan(capsys, '--port', str(vb.link), '--baud', '57600',
                              '--protocol-timeout-ms', SLOW_MACHINE_TIMEOUT_MS,
                              '--protocol', '2.0')
    assert status == scan.EXIT_OK
    assert out == [XM430_LINE.format(id=1, baud=57600, mode='position', errors='none'),
                   XM430_LINE.format(id=2, baud=57600, mode='position',
                                     errors='overload (0x20)')]


def test_ids_restrict_the_scan_to_those_ids_at_every_baud(start: Starter,
                                                          capsys: pytest.CaptureFixture) -> None:
    vb = start([1, 2, 3], 57600)
    status, out, err = run_scan(capsys, '--port', str(vb.link), '--ids', '3', '1', '99',
                                '--protocol-timeout-ms', '100')
    assert status == scan.EXIT_OK
    assert out == [XM430_LINE.format(id=1, baud=57600, mode='position', errors='none'),
                   XM430_LINE.format(id=3, baud=57600, mode='position', errors='none')]
    progress = [line for line in err if line.startswith('scanning')]
    # Protocol 1.0 where a 1.0 model runs out of the box.
    ones = protocol_1_bauds()
    assert progress == [line for b in default_bauds() for line in (
        f'scanning {b} bps (ping of 3 id(s)) ...',
        f'scanning {b} bps, Protocol 1.0 (ping of 3 id(s)) ...') if b in ones or '1.0' not in line]
    assert set(default_bauds()) - set(ones) == {2000000, 4000000, 4500000, 6000000, 10500000}


def test_a_full_scan_finds_servos_at_1_mbps_and_the_file_takes_the_main_baud(
        start: Starter, capsys: pytest.CaptureFixture, tmp_path: pathlib.Path) -> None:
    vb = start([1, 2, 3], 57600)
    device = vb.device
    mode = MANUAL.item('operating_mode')
    baud = MANUAL.item('baud_rate')

    def prepare(bus: Bus) -> None:
        retried(lambda: bus.write_item(3, mode, modes.BY_NAME['velocity'].number))
        try:
            # The servo switches baud on this write; its status may not arrive at the old one.
            bus.write_item(2, baud, 3)   # raw 3 = 1 Mbps
        except CommError:
            pass

    with_bus(device, 57600, prepare)
    assert with_bus(device, 1_000_000, lambda bus: retried(lambda: bus.ping(2))) == 1030
    output = tmp_path / 'found.yaml'
    # Protocol 2.0 only: a 1.0 sweep pings every id at every baud (test_scan_finds_...1_0).
    status, out, err = run_scan(capsys, '--port', str(vb.link), '--output', str(output),
                                '--protocol-timeout-ms', SLOW_MACHINE_TIMEOUT_MS,
                                '--protocol', '2.0')
    assert status == scan.EXIT_OK
    assert out == [XM430_LINE.format(id=1, baud=57600, mode='position', errors='none'),
                   XM430_LINE.format(id=3, baud=57600, mode='velocity', errors='none'),
                   XM430_LINE.format(id=2, baud=1000000, mode='position', errors='none')]
    progress = [line for line in err if line.startswith('scanning')]
    # One broadcast ping a baud, its window ended once the line is quiet (1 Mbps: id 2).
    assert progress == [f'scanning {b} bps (broadcast ping) ...' for b in default_bauds()]
    assert any('different baud rates' in line and '1 servo at 1000000 bps' in line
               for line in err)
    text = output.read_text()
    assert 'id 2 answered at 1000000 bps' in text
    parsed = config.validate(flatten(yaml.safe_load(text)))
    assert parsed.port == str(vb.link)
    assert parsed.baud_rate == 57600
    assert [(j.name, j.servo_id, j.operating_mode) for j in parsed.joints] == [
        ('joint_1', 1, 'position'), ('joint_3', 3, 'velocity')]


def test_the_output_file_carries_each_servos_mode(start: Starter, capsys: pytest.CaptureFixture,
                                                  tmp_path: pathlib.Path) -> None:
    vb = start([4, 9], 1_000_000)
    mode = MANUAL.item('operating_mode')
    with_bus(vb.device, 1_000_000, lambda bus: retried(
        lambda: bus.write_item(9, mode, modes.BY_NAME['current_based_position'].number)))
    output = tmp_path / 'bus.yaml'
    status, out, _ = run_scan(capsys, '--port', str(vb.link), '--baud', '1000000', '--output',
                              str(output), '--protocol-timeout-ms', SLOW_MACHINE_TIMEOUT_MS,
                              '--protocol', '2.0')
    assert status == scan.EXIT_OK
    assert len(out) == 2
    flat = flatten(yaml.safe_load(output.read_text()))
    # The pty's answers timed (test_the_file_carries_the_latency_measured holds its value).
    assert flat.pop('latency_timer') >= 1.0
    assert flat == {'port': str(vb.link), 'baud_rate': 1000000, 'protocol': 2.0,
                    'joints': ['joint_4', 'joint_9'],
                    'joint_4.id': 4, 'joint_4.operating_mode': 'position',
                    'joint_4.model': 'XM430-W210',
                    'joint_9.id': 9, 'joint_9.operating_mode': 'current_based_position',
                    'joint_9.model': 'XM430-W210',
                    **{f'{joint}.{key}': value for joint in ('joint_4', 'joint_9')
                       for key, value in (('offset', 0.0), ('reverse', False), ('ratio', 1.0))}}
    parsed = config.validate(flat)
    assert parsed.joint('joint_9').operating_mode == 'current_based_position'
    assert not list(tmp_path.glob('bus.yaml.tmp*'))


@pytest.mark.parametrize('latency_ms', [0, 5])
def test_the_file_carries_the_latency_measured(virtual_bus: StartVirtualBus,
                                               capsys: pytest.CaptureFixture,
                                               tmp_path: pathlib.Path, latency_ms: int) -> None:
    # A pty has no sysfs latency timer: scan times the servos' answers as the node does
    # (driver/adapter.measure_latency_timer) and writes the timer they imply, not Linux's 16 ms.
    # The simulated adapter holds each answer latency_ms (wire timing).
    vb = virtual_bus([3, 7], 1000000, tmp_path / 'ttyDXL', extra_args=[
        '--timing', 'wire', '--latency-ms', str(latency_ms)])
    output = tmp_path / 'bus.yaml'
    status, _, err = run_scan(capsys, '--port', str(vb.link), '--baud', '1000000', '--output',
                              str(output), '--protocol', '2.0', '--protocol-timeout-ms',
                              SLOW_MACHINE_TIMEOUT_MS)
    assert status == scan.EXIT_OK, err
    text = output.read_text()
    written = flatten(yaml.safe_load(text))['latency_timer']
    said = re.search(r'latency_timer: ([\d.]+)  # ms, measured: id (\d+) answered within '
                     r'([\d.]+) ms of its wire time', text)
    assert said and float(said.group(1)) == written, text
    assert said.group(2) in ('3', '7'), text
    delay_ms = float(said.group(3))
    # The answers came no sooner than the adapter let them go (with the servo's Return Delay
    # Time, 500 us), and the timer written is the one that delay implies, to the whole ms
    # (the least an adapter has is 1 ms); the delay is said to 0.1 ms.
    assert delay_ms >= latency_ms, text
    implied = {max(1.0, math.ceil(delay_ms + edge - 0.5)) for edge in (-0.05, 0.05)}
    assert written in implied, text
    assert latency_ms <= written < 16.0, text


def test_scan_finds_servos_of_both_protocols_and_the_file_says_which(
        virtual_bus: StartVirtualBus, capsys: pytest.CaptureFixture,
        tmp_path: pathlib.Path) -> None:
    # An AX-12A (Protocol 1.0 only), an XM430 on 2.0, and one switched to 1.0 by its
    # Protocol Version register (13): one pty, one baud.
    link = tmp_path / 'ttyDXL'
    vb = virtual_bus([1, 2, 3], 57600, link, extra_args=['--models', '12', '1030', '1030'])
    version = MANUAL.item('protocol_version')

    def to_protocol_1(bus: Bus) -> None:
        try:
            bus.write_item(3, version, 1)   # its status comes in 2.0, then it speaks 1.0
        except CommError:
            pass

    with_bus(vb.device, 57600, to_protocol_1)
    assert vb.get(3, 'protocol_version') == 1
    output = tmp_path / 'both.yaml'
    status, out, err = run_scan(capsys, '--port', str(link), '--ids', '1', '2', '3',
                                '--baud', '57600', '--output', str(output),
                                '--protocol-timeout-ms', SLOW_MACHINE_TIMEOUT_MS)
    assert status == scan.EXIT_OK, err
    assert out == [
        XM430_LINE.format(id=2, baud=57600, mode='position', errors='none'),
        'id 1: model 12 (AX-12A), firmware 0, 57600 bps, Protocol 1.0, mode position, '
        'hardware errors: not in its table (each reply says them)',
        'id 3: model 1030 (XM430-W210), firmware 45, 57600 bps, Protocol 1.0, mode position, '
        'hardware errors: none']
    parsed = config.validate(flatten(yaml.safe_load(output.read_text())))
    assert parsed.protocol == 2.0
    assert {joint.servo_id: joint.protocol for joint in parsed.joints} == {
        1: 1.0, 2: 2.0, 3: 1.0}
    assert 'protocol: 1.0  #' in output.read_text()


@pytest.mark.parametrize('extra, what', [
    (['--baud', '115200', '1000000', '--protocol', '2.0'],
     'a broadcast ping at 115200, 1000000 bps, Protocol 2.0'),
    (['--ids', '1', '2', '--baud', '57600'],
     'pings of id(s) 1 2 at 57600 bps, Protocol 2.0 and 1.0'),
])
def test_nothing_found_exits_non_zero_with_the_usual_causes(
        start: Starter, capsys: pytest.CaptureFixture, tmp_path: pathlib.Path,
        extra: List[str], what: str) -> None:
    vb = start([7], 57600)
    output = tmp_path / 'never.yaml'
    status, out, err = run_scan(capsys, '--port', str(vb.link), '--output', str(output), *extra)
    assert status == scan.EXIT_NOT_FOUND
    assert out == []
    text = '\n'.join(err)
    assert f'no servo answered on {vb.link} ({what})' in text
    for cause in ('power', 'baud rate', 'protocol', 'latency timer', 'udev'):
        assert cause in text
    assert not output.exists()


# ---- port and argument errors -------------------------------------------------------------------
def test_a_missing_port_gives_one_clear_line(capsys: pytest.CaptureFixture,
                                             tmp_path: pathlib.Path) -> None:
    missing = tmp_path / 'ttyUSB9'
    status, out, err = run_scan(capsys, '--port', str(missing))
    assert status == scan.EXIT_PORT
    assert out == []
    assert len(err) == 1
    assert err[0].startswith(f'scan: error: port {missing} does not exist')


@pytest.mark.skipif(os.geteuid() == 0, reason='root opens any device')
def test_permission_denied_says_how_to_fix_it(capsys: pytest.CaptureFixture) -> None:
    master, slave = os.openpty()
    try:
        device = os.ttyname(slave)
        os.chmod(device, 0)
        status, _, err = run_scan(capsys, '--port', device, '--baud', '57600')
    finally:
        os.close(slave)
        os.close(master)
    assert status == scan.EXIT_PORT
    assert len(err) == 1 and 'permission denied' in err[0] and 'dialout' in err[0]


@pytest.mark.parametrize('args, message', [
    ([], 'the following arguments are required: --port'),
    (['--port', '/dev/ttyX', '--baud', '1234'], '--baud 1234: no supported model runs at it'),
    (['--port', '/dev/ttyX', '--baud', 'fast'], "invalid int value: 'fast'"),
    (['--port', '/dev/ttyX', '--ids', '253'], '--ids 253: ids are 0..252'),
    (['--port', '/dev/ttyX', '--protocol-timeout-ms', '0'], '--protocol-timeout-ms must be'),
    (['--port', '/dev/ttyX', '--protocol-timeout-ms', 'nan'], '--protocol-timeout-ms must be'),
    (['--port', '/dev/ttyX', '--output', '/no/such/folder/f.yaml'], 'does not exist'),
    (['--port', '/dev/ttyX', '--frobnicate'], 'unrecognized arguments: --frobnicate'),
])
def test_bad_arguments_exit_2_with_one_line(capsys: pytest.CaptureFixture, args: List[str],
                                            message: str) -> None:
    status, out, err = run_scan(capsys, *args)
    assert status == scan.EXIT_USAGE
    assert out == []
    assert len(err) == 1 and err[0].startswith('scan: error: ') and message in err[0], err


def test_help_exits_0(capsys: pytest.CaptureFixture) -> None:
    status, out, _ = run_scan(capsys, '--help')
    assert status == 0
    assert any('--protocol-timeout-ms' in line for line in out)


# ---- pure helpers -------------------------------------------------------------------------------
def test_default_bauds_are_the_whole_table_most_common_first() -> None:
    bauds = default_bauds()
    assert bauds[:2] == [57600, 1000000]
    assert bauds[-1] == 9600   # slowest broadcast ping last
    # Every baud some supported model takes: the X's, the Protocol 1.0 ones', the P's.
    assert sorted(bauds) == sorted({bps for model in ALL_MODELS for bps in model.bauds.values()})
    assert {115200, 19200, 200000, 10_500_000} <= set(bauds)


def servo(servo_id: int, baud_bps: int = 57600, model: int = 1030, mode: Optional[int] = 3,
          errors: Optional[int] = 0, firmware: Optional[int] = 45) -> FoundServo:
    """Return a FoundServo as scan_bus would build it."""
    return FoundServo(servo_id, baud_bps, model, firmware, mode, errors)


def test_describe_says_what_could_not_be_read() -> None:
    assert describe(servo(5, model=REFUSED, mode=None, errors=None, firmware=44)) == (
        f'id 5: model {REFUSED} ({OTHER_MODELS[REFUSED][0]}, not supported), firmware 44, '
        '57600 bps, '
        'mode not read (unknown control table), hardware errors: not read')
    assert describe(servo(9, model=9999, mode=None, errors=None)).startswith(
        'id 9: model 9999 (unknown model)')
    # Every supported model is named, and its own table reads its mode.
    assert describe(servo(4, model=1060, mode=16)).startswith(
        'id 4: model 1060 (XL430-W250), firmware 45, 57600 bps, mode pwm')
    assert describe(servo(6, mode=None, errors=None, firmware=None)) == (
        'id 6: model 1030 (XM430-W210), firmware ? (no reply), 57600 bps, mode ? (no reply), '
        'hardware errors: ? (no reply)')
    assert describe(servo(7, mode=2, errors=0x24)).endswith(
        'mode 2 (not a valid mode), hardware errors: overheating, overload (0x24)')
    assert describe(servo(8, errors=0x40)).endswith('hardware errors: unnamed bits (0x40)')


def test_the_baud_with_most_servos_wins_and_a_tie_goes_to_the_first_scanned() -> None:
    assert choose_baud([servo(1, 1000000), servo(2, 57600), servo(3, 57600)]) == 57600
    assert choose_baud([servo(1, 1000000), servo(2, 57600)]) == 1000000


def test_servos_the_node_cannot_drive_are_left_out_as_comments() -> None:
    found = [servo(1), servo(2, model=REFUSED), servo(3, mode=2), servo(4, mode=None),
             servo(5, 1000000), servo(6, mode=16, model=1060)]
    params, comments = build_parameters('/dev/ttyDXL', found, latency_timer_ms=1.0)
    assert params['joints'] == ['joint_1', 'joint_6']
    assert params['joint_6.operating_mode'] == 'pwm'
    assert (params['joint_1.model'], params['joint_6.model']) == ('XM430-W210', 'XL430-W250')
    assert params['latency_timer'] == 1.0
    text = '\n'.join(comments)
    for servo_id in (2, 3, 4, 5):
        assert f'  id {servo_id}' in text
    assert 'set its baud_rate register to 1 (57600 bps)' in text
    with pytest.raises(ValueError, match='no servo the node could drive'):
        build_parameters('/dev/ttyDXL', [servo(2, model=REFUSED)])
    with pytest.raises(ValueError, match='no servo found'):
        build_parameters('/dev/ttyDXL', [])


def test_the_rendered_file_parses_back_to_the_same_parameters() -> None:
    port = "/dev/serial/by-id/usb-FTDI_it's #1: U2D2"   # quote, hash, colon and spaces
    params, comments = build_parameters(
        port, [servo(12, mode=1), servo(3, mode=4, model=1090)], 16.0)
    text = render_parameter_file(params, comments, 'header')
    assert flatten(yaml.safe_load(text)) == params
    # The joint's frame is there to be edited, at the values that leave the joint the servo.
    assert params['joint_3.offset'] == 0.0 and params['joint_3.reverse'] is False
    assert params['joint_3.ratio'] == 1.0 and '      reverse: false  #' in text
    assert config.validate(params).joint('joint_3').model.name == '2XL430-W250'
    assert config.validate(params).joint('joint_12').operating_mode == 'velocity'


def test_the_default_scan_says_its_time_and_finishes(start: Starter,
                                                     capsys: pytest.CaptureFixture) -> None:
    """
    `scan --port P` alone: every baud, both protocols, two servos at 57,600 found.

    A Protocol 1.0 ping of every id that waited the adapter's latency timer at every one of 17
    bauds would take minutes on a bus that answers at once, and the README's "find the servos"
    step would time out. The plan's own estimate, said before it starts, is under 30 s; the time
    it really takes depends on the machine and is not judged here.
    """
    vb = start([1, 2], 57600)
    status, out, err = run_scan(capsys, '--port', str(vb.link))
    assert status == scan.EXIT_OK, err
    assert out == [XM430_LINE.format(id=1, baud=57600, mode='position', errors='none'),
                   XM430_LINE.format(id=2, baud=57600, mode='position', errors='none')]
    said = err[0].split('about ')
    assert err[0].startswith('scan: 17 baud rates, Protocol 2.0 and 1.0: about '), err[0]
    assert int(said[1].split(' s ')[0]) < 30, err[0]
    assert any('found 2 servos (tried 57600, 1000000' in line for line in err)


def test_stop_at_first_ends_at_the_first_baud_with_servos(start: Starter,
                                                          capsys: pytest.CaptureFixture) -> None:
    vb = start([4, 9], 1000000)
    status, out, err = run_scan(capsys, '--port', str(vb.link), '--stop-at-first',
                                '--protocol-timeout-ms', SLOW_MACHINE_TIMEOUT_MS)
    assert status == scan.EXIT_OK, err
    assert out == [XM430_LINE.format(id=i, baud=1000000, mode='position', errors='none')
                   for i in (4, 9)]
    assert [line for line in err if line.startswith('scanning')] == [
        'scanning 57600 bps (broadcast ping) ...',
        'scanning 57600 bps, Protocol 1.0 (ping of 253 id(s)) ...',
        'scanning 1000000 bps (broadcast ping) ...',
        'scanning 1000000 bps, Protocol 1.0 (ping of 253 id(s)) ...']
    assert any('found 2 servos (tried 57600, 1000000 bps)' in line for line in err)


@pytest.mark.parametrize('protocol', [1.0, 2.0])
def test_a_ping_sweep_names_every_servo_that_answers(virtual_bus: StartVirtualBus,
                                                     tmp_path: pathlib.Path,
                                                     protocol: float) -> None:
    ids = [1, 7, 200]
    models = ['12', '12', '12'] if protocol == 1.0 else ['1020', '1020', '1020']
    vb = virtual_bus(ids, 1000000, tmp_path / 'ttyDXL', extra_args=['--models', *models])
    sweep = with_bus(vb.device, 1000000,
                     lambda bus: bus.ping_sweep(range(253), FRAMERS[protocol]))
    assert sweep.answered == ids and sweep.garbled == [] and sweep.noise == 0, sweep


# ---- the fast scan, its progress, Ctrl-C, `dxl scan`, find_one_servo ----------------------------
def installed(name: str) -> str:
    """Return an installed executable of the package (`scan`, `dxl`)."""
    return os.path.join(get_package_prefix('dxl_servo_driver'), 'lib', 'dxl_servo_driver', name)


# A spawned command on a loaded machine: only a failure waits this long.
SPAWN_TIMEOUT_S = 120.0


@pytest.mark.parametrize('return_delay_time, latency_ms', [(0, '1'), (250, '16'), (254, '1')])
def test_the_fast_scan_finds_ids_0_and_252_in_both_protocols_at_any_return_delay(
        virtual_bus: StartVirtualBus, capsys: pytest.CaptureFixture, tmp_path: pathlib.Path,
        return_delay_time: int, latency_ms: str) -> None:
    # Ids 0 and 252 in Protocol 2.0 (XM430) and in 1.0 (AX-12A) on one line: the two
    # protocols' servos never answer each other's pings. Wire timing: the Return Delay Time
    # (up to 508 us) and the adapter's latency are waited as on a real bus.
    vb = virtual_bus([0, 252, 0, 252], 1000000, tmp_path / 'ttyDXL', extra_args=[
        '--models', '1030', '1030', '12', '12', '--timing', 'wire', '--latency-ms', latency_ms,
        '--return-delay-time', str(return_delay_time)])
    status, out, err = run_scan(capsys, '--port', str(vb.link), '--baud', '57600', '1000000',
                                '--protocol-timeout-ms', SLOW_MACHINE_TIMEOUT_MS)
    assert status == scan.EXIT_OK, err
    ax = ('id {id}: model 12 (AX-12A), firmware 0, 1000000 bps, Protocol 1.0, mode position, '
          'hardware errors: not in its table (each reply says them)')
    assert out == [XM430_LINE.format(id=0, baud=1000000, mode='position', errors='none'),
                   XM430_LINE.format(id=252, baud=1000000, mode='position', errors='none'),
                   ax.format(id=0), ax.format(id=252)]
    assert not any('warning' in line for line in err), err


def test_servos_sharing_an_id_are_reported_not_missed(virtual_bus: StartVirtualBus,
                                                      capsys: pytest.CaptureFixture,
                                                      tmp_path: pathlib.Path) -> None:
    # Two new servos (id 1 at 57600, Return Delay Time 500 us) collide; id 5 answers cleanly.
    # The same in Protocol 1.0: two AX-12A with id 9.
    vb = virtual_bus([1, 1, 5, 9, 9], 57600, tmp_path / 'ttyDXL', extra_args=[
        '--models', '1030', '1030', '1030', '12', '12', '--timing', 'wire',
        '--return-delay-time', '250'])
    status, out, err = run_scan(capsys, '--port', str(vb.link), '--baud', '57600',
                                '--protocol-timeout-ms', SLOW_MACHINE_TIMEOUT_MS)
    assert status == scan.EXIT_OK, err
    assert out == [XM430_LINE.format(id=5, baud=57600, mode='position', errors='none')]
    warnings = [line for line in err if line.startswith('scan: warning:')]
    assert warnings == [
        'scan: warning: id 1 at 57600 bps: garbled replies (two servos with the same id, or a '
        'noisy line?)',
        'scan: warning: id 9 at 57600 bps (Protocol 1.0): garbled replies (two servos with the '
        'same id, or a noisy line?)'], err


def test_a_terminal_shows_one_redrawn_progress_line_and_the_estimate_first(
        start: Starter) -> None:
    vb = start([1, 2], 57600)
    child = pexpect.spawn(installed('scan'), ['--port', str(vb.link), '--baud', '57600',
                                              '1000000', '--protocol', '2.0'],
                          encoding='utf-8', timeout=SPAWN_TIMEOUT_S)
    try:
        child.expect(r'scan: 2 baud rates, Protocol 2\.0: about [\d.]+ s where nobody answers')
        # The bar: baud k of n, the protocol, elapsed, the time left, the servos found so far.
        child.expect(r'\r\x1b\[K\[[#.]{10}\] baud 1 of 2: 57600 bps, P2\.0 \| \d+ s, \d+ s left '
                     r'\| 0 found')
        child.expect(r'id 2: model 1030')
        child.expect(r'\[[#.]{10}\] baud 2 of 2: 1000000 bps, P2\.0 \| \d+ s, \d+ s left '
                     r'\| 2 found')
        child.expect('scan: found 2 servos')
        child.expect(pexpect.EOF)
        # No 'scanning ...' lines on a terminal: the bar says it.
        assert 'scanning' not in child.before
    finally:
        child.close(force=True)
    assert child.exitstatus == scan.EXIT_OK


def test_ctrl_c_keeps_what_was_found_writes_the_file_and_exits_130(
        start: Starter, tmp_path: pathlib.Path) -> None:
    vb = start([1, 2], 57600)
    output = tmp_path / 'partial.yaml'
    child = pexpect.spawn(installed('scan'), ['--port', str(vb.link), '--output', str(output)],
                          encoding='utf-8', timeout=SPAWN_TIMEOUT_S)
    try:
        # Found at the first baud; then interrupted while the other 16 are still to come.
        child.expect(r'id 2: model 1030')
        child.expect(r'baud 1 of 17: 57600 bps, P1\.0')
        child.sendintr()
        child.expect(r'scan: interrupted: found 2 servos \(tried 57600')
        child.expect(f'scan: wrote {output} \\(2 joints at 57600 bps\\)')
        child.expect(pexpect.EOF)
    finally:
        child.close(force=True)
    assert child.exitstatus == scan.EXIT_INTERRUPTED
    parsed = config.validate(flatten(yaml.safe_load(output.read_text())))
    assert [(j.name, j.servo_id) for j in parsed.joints] == [('joint_1', 1), ('joint_2', 2)]


def test_dxl_scan_is_the_same_command(start: Starter, tmp_path: pathlib.Path) -> None:
    shown = subprocess.run([installed('dxl'), 'scan', '--help'], capture_output=True, text=True,
                           timeout=SPAWN_TIMEOUT_S)
    assert shown.returncode == 0, shown.stderr
    for option in ('--port', '--baud', '--ids', '--protocol', '--stop-at-first', '--output',
                   '--protocol-timeout-ms'):
        assert option in shown.stdout
    vb = start([3, 4], 57600)
    output = tmp_path / 'dxl.yaml'
    trace = tmp_path / 'scan.trace'
    done = subprocess.run([installed('dxl'), 'scan', '--port', str(vb.link), '--baud', '57600',
                           '--protocol', '2.0', '--protocol-timeout-ms', SLOW_MACHINE_TIMEOUT_MS,
                           '--output', str(output), '--trace', str(trace)],
                          capture_output=True, text=True, timeout=SPAWN_TIMEOUT_S)
    assert done.returncode == scan.EXIT_OK, done.stderr
    assert done.stdout.splitlines() == [
        XM430_LINE.format(id=i, baud=57600, mode='position', errors='none') for i in (3, 4)]
    assert 'dxl scan: found 2 servos (tried 57600 bps)' in done.stderr
    assert 'Written by `dxl scan --port' in output.read_text()
    # Like every dxl command, --trace: the broadcast ping went out, as the trace says.
    assert ' tx ff ff fd 00 fe 03 00 01 31 42\n' in trace.read_text()
    bad = subprocess.run([installed('dxl'), 'scan', '--port', str(vb.link), '--baud', '1234'],
                         capture_output=True, text=True, timeout=SPAWN_TIMEOUT_S)
    assert bad.returncode == scan.EXIT_USAGE
    assert bad.stderr.startswith('dxl scan: error: --baud 1234: no supported model'), bad.stderr


def find_one(device: str, bauds: Optional[List[int]] = None) -> OneServo:
    """Run find_one_servo on a port opened as scan opens it."""
    port = open_port(device, 57600)
    try:
        bus = Bus(port, 57600, latency_timer_s=0.2, return_delay_s=MAX_RETURN_DELAY_S)
        return find_one_servo(bus, bauds, bauds_1=protocol_1_bauds())
    finally:
        port.close()


def test_find_one_servo_says_what_answered_at_the_first_baud(virtual_bus: StartVirtualBus,
                                                             tmp_path: pathlib.Path) -> None:
    one = virtual_bus([7], 1000000, tmp_path / 'ttyAX',
                      extra_args=['--models', '12', '--timing', 'wire'])
    assert find_one(one.device) == OneServo(7, 12, 1.0, 1000000)
    xm = virtual_bus([1], 57600, tmp_path / 'ttyXM', extra_args=['--timing', 'wire'])
    assert find_one(xm.device) == OneServo(1, 1030, 2.0, 57600)


def test_find_one_servo_refuses_two_servos_and_collisions(virtual_bus: StartVirtualBus,
                                                          tmp_path: pathlib.Path) -> None:
    two = virtual_bus([1, 2], 57600, tmp_path / 'ttyTwo', extra_args=['--timing', 'wire'])
    with pytest.raises(NotOneServo, match=r'2 servos answered at 57600 bps \(id 1, id 2\)'):
        find_one(two.device)
    # The factory state: every new servo is id 1 at 57,600 bps, Return Delay Time 500 us.
    same = virtual_bus([1, 1], 57600, tmp_path / 'ttySame', extra_args=[
        '--timing', 'wire', '--return-delay-time', '250'])
    with pytest.raises(NotOneServo, match='replies collided at 57600 bps') as caught:
        find_one(same.device)
    assert caught.value.collided and caught.value.baud_bps == 57600
    nobody = virtual_bus([1], 57600, tmp_path / 'ttyNone', extra_args=['--unplugged'])
    with pytest.raises(NoServo, match='no servo answered at 57600, 1000000 bps'):
        find_one(nobody.device, [57600, 1000000])
