"""
`dxl` commands with --params: the port, baud rate and protocol of the driver's parameter file.

README's tuning line names a joint and a parameter file, no port nor baud rate: with --params
FILE the bus is the file's (not the factory 57,600 bps, which misses servos set up at 1 Mbps)
and a servo may be named by its joint; --port/--baud given still win; a bad file or an unknown
joint is one error line, exit 2. The installed `dxl` on virtual_bus.
"""

import pathlib
from typing import List, Tuple

from dxl_cli import dxl, one_error_line
from dxl_servo_driver.tool.common import EXIT_FAILED, EXIT_USAGE
from processes import StartVirtualBus, VirtualBusProcess
import pytest
import yaml

BAUD = 1000000
# The file's joints: not ids 1.. in order, so that a joint resolved as an id would show.
SHOULDER, ELBOW, GRIPPER = 2, 3, 9


def params_file(path: pathlib.Path, port: str) -> pathlib.Path:
    """Write a parameter file of the bus: two 2.0 joints and a 1.0 gripper; return its path."""
    path.write_text(f"""\
/**:
  ros__parameters:
    port: '{port}'
    baud_rate: {BAUD}
    joints: [shoulder, elbow, gripper]
    shoulder: {{id: {SHOULDER}, operating_mode: position}}
    elbow: {{id: {ELBOW}, operating_mode: position}}
    gripper: {{id: {GRIPPER}, operating_mode: position, protocol: 1.0}}
""")
    return path


@pytest.fixture
def arm(virtual_bus: StartVirtualBus,
        tmp_path: pathlib.Path) -> Tuple[VirtualBusProcess, pathlib.Path]:
    """Return servos set up at 1 Mbps (two XM430, an AX-12A on Protocol 1.0) and their file."""
    bus = virtual_bus([SHOULDER, ELBOW, GRIPPER], BAUD, tmp_path / 'ttyDXL',
                      extra_args=['--models', '1030', '1030', '12'])
    return bus, params_file(tmp_path / 'my_arm.yaml', str(tmp_path / 'ttyDXL'))


def test_the_readme_tuning_line_runs_as_written(arm: Tuple[VirtualBusProcess, pathlib.Path],
                                                tmp_path: pathlib.Path) -> None:
    _, params = arm
    png = tmp_path / 'step.png'
    done = dxl('step', 'shoulder', '--to', '0.5', '--png', str(png), '--params', str(params),
               '--duration', '0.3')
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f'id {SHOULDER} XM430-W210: step '), done.stdout
    assert 'rise ' in done.stdout and png.stat().st_size > 10000


def test_watch_and_selftest_take_the_files_bus_and_joints(
        arm: Tuple[VirtualBusProcess, pathlib.Path]) -> None:
    bus, params = arm
    done = dxl('watch', '--ids', 'shoulder', 'elbow', '--items', 'id', '--duration', '0.5',
               '--params', str(params))
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines and all(f'id {SHOULDER} id=+{SHOULDER}' in line
                         and f'id {ELBOW} id=+{ELBOW}' in line for line in lines), lines
    done = dxl('selftest', 'elbow', '--params', str(params))
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.startswith(f'id {ELBOW}: XM430-W210, firmware 45, {BAUD} bps\n')
    assert 'selftest: PASS' in done.stdout
    # The same servos named by id take the file's port and baud rate too.
    done = dxl('watch', '--ids', str(SHOULDER), '--items', 'id', '--duration', '0.3',
               '--params', str(params))
    assert done.returncode == 0 and f'id {SHOULDER} id=+{SHOULDER}' in done.stdout, done.stderr
    assert bus.get(ELBOW, 'torque_enable') == 0   # selftest left it as it was


def test_one_servo_and_backup_commands_take_joints(arm: Tuple[VirtualBusProcess, pathlib.Path],
                                                   tmp_path: pathlib.Path) -> None:
    bus, params = arm
    done = dxl('set', 'elbow', 'profile_velocity', '7', '--raw', '--params', str(params))
    assert done.returncode == 0, done.stderr
    assert bus.get(ELBOW, 'profile_velocity') == 7 and bus.get(SHOULDER, 'profile_velocity') == 0
    # A joint of its own protocol (1.0 where the bus speaks 2.0) is spoken to in it.
    done = dxl('get', 'gripper', 'id', 'baud_rate', '--params', str(params))
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[0] == f'id = {GRIPPER}'
    backup = tmp_path / 'elbow.yaml'
    done = dxl('backup', 'elbow', str(backup), '--params', str(params))
    assert done.returncode == 0, done.stderr
    assert yaml.safe_load(backup.read_text())['id'] == ELBOW
    done = dxl('diff', 'elbow', '--other', 'shoulder', '--params', str(params))
    assert done.returncode == EXIT_FAILED, done.stdout + done.stderr   # they differ: said
    assert done.stdout.splitlines()[0] == (
        f'profile_velocity: id {ELBOW} 7 (0.167866 rad/s), id {SHOULDER} 0 (0 rad/s)')


def test_port_and_baud_given_win_over_the_files(arm: Tuple[VirtualBusProcess, pathlib.Path],
                                                tmp_path: pathlib.Path) -> None:
    bus, params = arm
    done = dxl('get', 'shoulder', 'id', '--params', str(params), '--baud', '57600')
    assert done.returncode == EXIT_FAILED
    assert f'id {SHOULDER} does not answer at 57600 bps' in one_error_line(done, 'get')
    # A file naming another port: --port names this bus.
    elsewhere = params_file(tmp_path / 'elsewhere.yaml', str(tmp_path / 'no_such_tty'))
    done = dxl('get', 'shoulder', 'id', '--params', str(elsewhere), '--port', bus.device)
    assert done.returncode == 0, done.stderr
    assert done.stdout == f'id = {SHOULDER}\n'


@pytest.mark.parametrize('args, said', [
    (['--params', '{missing}'], 'parameter file {missing} does not exist'),
    (['--params', '{bad}'],
     "--params {bad}: parameter 'shoulder.operating_mode': unknown operating mode 'sideways'"),
    (['--params', '{params}', 'wrist'],
     "no joint 'wrist' in {params} (its joints: shoulder, elbow, gripper)"),
    (['--port', '{port}', 'shoulder'], "'shoulder' is not an id: a joint name needs --params"),
    ([str(SHOULDER)], '--port is needed (or --params FILE'),
])
def test_a_bad_file_or_joint_is_one_line_and_exit_2(
        arm: Tuple[VirtualBusProcess, pathlib.Path], tmp_path: pathlib.Path, args: List[str],
        said: str) -> None:
    bus, params = arm
    bad = tmp_path / 'bad.yaml'
    bad.write_text(params.read_text().replace('operating_mode: position}',
                                              'operating_mode: sideways}', 1))
    names = {'missing': str(tmp_path / 'missing.yaml'), 'bad': str(bad), 'params': str(params),
             'port': bus.device}
    words = [word.format(**names) for word in args]
    if not any(word in ('wrist', 'shoulder', str(SHOULDER)) for word in words):
        words.append('shoulder')
    done = dxl('get', *words, 'id')
    assert done.returncode == EXIT_USAGE, done.stdout + done.stderr
    assert said.format(**names) in one_error_line(done, 'get')
    assert bus.get(SHOULDER, 'id') == SHOULDER
