"""`dxl watch` on virtual_bus: the live table on a terminal, plain lines, the CSV, Ctrl-C."""

import csv
import math
import os
import pathlib
import subprocess
import time
from typing import List

from ament_index_python.packages import get_package_prefix
from dxl_servo_driver import models
from dxl_servo_driver.tool.session import open_bus, retried
import pexpect
from processes import StartVirtualBus, VirtualBusProcess

TIMEOUT_S = 30.0
# What the servos are told before they are watched: goal positions (rad) and voltages (V).
GOALS = {1: 0.25, 2: -0.5}
VOLTS = {1: 11.1, 2: 13.4}


def dxl() -> str:
    """Return the installed `dxl` executable."""
    return os.path.join(get_package_prefix('dxl_servo_driver'), 'lib', 'dxl_servo_driver', 'dxl')


def tell(device: str, bus_process: VirtualBusProcess) -> None:
    """Tell each servo its goal (written, torque off: it stays) and the simulator its voltage."""
    for servo_id, volts in VOLTS.items():
        assert bus_process.control(f'voltage {servo_id} {volts}').startswith('ok')
    model = models.model_for(1030)
    goal = model.item('goal_position')
    bus = open_bus(device, 1000000)
    try:
        for servo_id, rad in GOALS.items():
            retried(lambda: bus.write_item(servo_id, goal, told_raw(rad)))
    finally:
        bus.close()


def told_raw(rad: float) -> int:
    """Return the raw goal a radian value is written as (2048 at 0, 4096 a turn)."""
    return 2048 + round(rad * 4096 / (2 * math.pi))


def rows_of(path: pathlib.Path) -> List[List[str]]:
    """Return the CSV's rows after its header (only whole lines)."""
    text = path.read_text() if path.exists() else ''
    lines = text.split('\n')[1:-1]   # the header, and a line not yet ended
    return list(csv.reader(lines))


def test_watch_table_csv_and_ctrl_c(virtual_bus: StartVirtualBus, tmp_path: pathlib.Path) -> None:
    bus_process = virtual_bus([1, 2], 1000000)
    tell(bus_process.device, bus_process)
    log = tmp_path / 'watch.csv'
    child = pexpect.spawn(dxl(), ['watch', '--port', bus_process.device, '--baud', '1000000',
                                  '--ids', '1', '2', '--items',
                                  'goal_position,present_input_voltage',
                                  '--csv', str(log)], encoding='utf-8', timeout=TIMEOUT_S,
                          dimensions=(24, 160))
    try:
        # The table, drawn on the terminal: a header, a row per servo with sparklines.
        child.expect('sync read of 2 servos')
        child.expect(r'\n1 +\+0\.25\d+ rad +[▁-█]+ +\+11\.1000 V +[▁-█]+')
        deadline = time.monotonic() + TIMEOUT_S
        while len(rows_of(log)) < 100:
            assert time.monotonic() < deadline, 'fewer than 100 samples recorded'
            time.sleep(0.05)
        child.sendintr()
        child.expect(pexpect.EOF)
    finally:
        child.close(force=True)
    assert child.exitstatus == 0, child.before
    header, *rows = list(csv.reader(log.read_text().splitlines()))
    assert header == ['t_s', 'id', 'goal_position_rad', 'present_input_voltage_V']
    assert len(rows) >= 100
    assert log.read_text().endswith('\n')   # closed whole
    model = models.model_for(1030)
    for servo_id in (1, 2):
        mine = [row for row in rows if row[1] == str(servo_id)]
        assert len(mine) >= 50
        expected_rad = (told_raw(GOALS[servo_id]) - 2048) * 2 * math.pi / model.pulses_per_rev
        for row in mine:
            assert math.isclose(float(row[2]), expected_rad, abs_tol=1e-5), row
            assert math.isclose(float(row[3]), VOLTS[servo_id], abs_tol=1e-6), row
        times = [float(row[0]) for row in mine]
        assert times == sorted(times) and len(set(times)) == len(times)


def test_watch_plain_lines_and_rate(virtual_bus: StartVirtualBus, tmp_path: pathlib.Path) -> None:
    bus_process = virtual_bus([1, 2], 1000000)
    tell(bus_process.device, bus_process)
    log = tmp_path / 'watch.csv'
    done = subprocess.run([dxl(), 'watch', '--port', bus_process.device, '--baud', '1000000',
                           '--ids', '1', '2', '--items', 'present_input_voltage', '--rate', '50',
                           '--duration', '2', '--csv', str(log)],
                          capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines and all('id 1 present_input_voltage=+11.1000V' in line for line in lines)
    assert '\x1b[' not in done.stdout   # no terminal control when not on a terminal
    rows = rows_of(log)
    # 50 Hz for 2 s: 100 refreshes of two servos, never more; fewer only on a loaded machine.
    assert 40 <= len(rows) / 2 <= 102, len(rows)


def test_watch_refuses_an_unknown_item(virtual_bus: StartVirtualBus,
                                       tmp_path: pathlib.Path) -> None:
    bus_process = virtual_bus([1], 1000000)
    log = tmp_path / 'watch.csv'
    done = subprocess.run([dxl(), 'watch', '--port', bus_process.device, '--baud', '1000000',
                           '--ids', '1', '--items', 'present_position,nonsense', '--csv',
                           str(log)], capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "dxl watch: error: id 1 (XM430-W210) has no item 'nonsense'"]
    assert not log.exists()   # nothing written
