"""`dxl step` on virtual_bus (XM430-W350, wire timing): metrics, the PNG, the CSV, restoring."""

import csv
import os
import pathlib
import re
import subprocess
from typing import Dict, List, Tuple

from ament_index_python.packages import get_package_prefix
from dxl_servo_driver.tool.session import connect, open_bus, retried
from dxl_servo_driver.tool.step import metrics, Sample
import numpy
import pexpect
from processes import StartVirtualBus
import pytest

TIMEOUT_S = 60.0
METRICS = re.compile(r'^(?P<label>p=\d+ i=\d+ d=\d+)(?: \(as set\))?: rise (?P<rise>[\d.]+) ms, '
                     r'overshoot (?P<over>[\d.]+) %, settling (?P<settle>[\d.]+) ms, '
                     r'steady-state error (?P<error>[-+\d.]+) rad', re.MULTILINE)
# matplotlib's first three colours (tab:blue, tab:orange, tab:green), 0..1.
COLOURS = {'tab:blue': (0.122, 0.467, 0.706), 'tab:orange': (1.0, 0.498, 0.055),
           'tab:green': (0.173, 0.627, 0.173)}


def dxl() -> str:
    """Return the installed `dxl` executable."""
    return os.path.join(get_package_prefix('dxl_servo_driver'), 'lib', 'dxl_servo_driver', 'dxl')


def servo_state(device: str) -> Dict[str, int]:
    """Return what step changes for a while and must restore, read from servo 1."""
    bus = open_bus(device, 1000000)
    try:
        link = connect(bus, 1)
        return {name: retried(lambda: link.read(name)) for name in (
            'torque_enable', 'operating_mode', 'position_p_gain', 'position_i_gain',
            'position_d_gain', 'profile_velocity')}
    finally:
        bus.close()


def first_order(tau_s: float, goal: float, overshoot: float = 0.0) -> List[Sample]:
    """Return a response sampled every ms: 1 - exp(-t/tau), plus a bump of overshoot at 6 tau."""
    samples = [Sample(-0.001, 0.0, 0.0, 0.0, 0.0)]
    for ms in range(0, 1000):
        t = ms / 1000.0
        y = 1.0 - numpy.exp(-t / tau_s)
        if overshoot and 4 * tau_s <= t <= 8 * tau_s:
            y += overshoot * numpy.sin((t - 4 * tau_s) / (4 * tau_s) * numpy.pi)
        samples.append(Sample(t, t, goal * float(y), 0.0, 0.0))
    return samples


def test_metrics_of_a_known_response() -> None:
    # A first-order response: 10-90 % rise is tau ln 9, the 2 % band is entered at tau ln 50.
    found = metrics(first_order(0.05, 0.5), 0.0, 0.5)
    assert found.rise_s == pytest.approx(0.05 * numpy.log(9.0), abs=0.002)
    assert found.settling_s == pytest.approx(0.05 * numpy.log(50.0), abs=0.002)
    assert found.overshoot_pct == 0.0
    assert abs(found.steady_error) < 1e-6
    # A step down is measured the same way.
    down = metrics([Sample(s.t, s.host_t, 1.0 - s.position, 0.0, 0.0)
                    for s in first_order(0.05, 0.5)], 1.0, 0.5)
    assert down.rise_s == pytest.approx(found.rise_s, abs=1e-9)
    bumped = metrics(first_order(0.05, 0.5, overshoot=0.1), 0.0, 0.5)
    assert 9.0 < bumped.overshoot_pct < 10.0
    # Back inside the band on the bump's way down, after 7.5 tau.
    assert bumped.settling_s is not None and 0.37 < bumped.settling_s < 0.4


def colour_pixels(png: pathlib.Path) -> Dict[str, int]:
    """Return how many pixels of each of the first three line colours the PNG has."""
    from matplotlib import image
    pixels = image.imread(str(png))[:, :, :3]
    return {name: int((numpy.abs(pixels - numpy.array(rgb)).max(axis=2) < 0.02).sum())
            for name, rgb in COLOURS.items()}


def test_step_metrics_png_csv_and_restore(virtual_bus: StartVirtualBus,
                                          tmp_path: pathlib.Path) -> None:
    bus_process = virtual_bus([1], 1000000, extra_args=['--timing', 'wire', '--models',
                                                        'XM430-W350'])
    before = servo_state(bus_process.device)
    png, log = tmp_path / 'step.png', tmp_path / 'step.csv'
    done = subprocess.run([dxl(), 'step', '1', '--port', bus_process.device, '--baud', '1000000',
                           '--from', '0', '--to', '0.5', '--duration', '0.6',
                           '--gains', 'p=400', 'p=1600,d=400', '--png', str(png), '--csv',
                           str(log)], capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stderr
    runs: Dict[str, Tuple[float, float, float, float]] = {
        match['label']: (float(match['rise']), float(match['over']), float(match['settle']),
                         float(match['error']))
        for match in METRICS.finditer(done.stdout)}
    assert list(runs) == ['p=800 i=0 d=0', 'p=400 i=0 d=0', 'p=1600 i=0 d=400'], done.stdout
    for label, (rise_ms, overshoot, settle_ms, error) in runs.items():
        # Plausible for a 0.5 rad step of an unloaded XM430-W350 at the default gains' scale.
        assert 20.0 < rise_ms < 400.0, (label, rise_ms)
        assert 0.0 <= overshoot < 30.0, (label, overshoot)
        assert rise_ms < settle_ms < 600.0, (label, settle_ms)
        assert abs(error) < 0.01, (label, error)
    # Half the proportional gain: slower; twice with damping: faster than half.
    assert runs['p=400 i=0 d=0'][0] > runs['p=800 i=0 d=0'][0]
    assert runs['p=1600 i=0 d=400'][0] < runs['p=400 i=0 d=0'][0]
    # The PNG: a PNG, and each run's line in its colour.
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    pixels = colour_pixels(png)
    assert all(count > 200 for count in pixels.values()), pixels
    # The CSV: every run's samples, back to back from the step on (hundreds a second; a loaded
    # machine has been seen to fall to 50).
    rows = list(csv.DictReader(log.read_text().splitlines()))
    assert {row['gains'] for row in rows} == set(runs)
    for index in range(3):
        mine = [row for row in rows if row['run'] == str(index)]
        assert len(mine) >= 20, len(mine)
        assert float(mine[-1]['position_rad']) == pytest.approx(0.5, abs=0.01)
    assert servo_state(bus_process.device) == before


def test_step_restores_on_ctrl_c(virtual_bus: StartVirtualBus) -> None:
    bus_process = virtual_bus([1], 1000000, extra_args=['--timing', 'wire'])
    before = servo_state(bus_process.device)
    child = pexpect.spawn(dxl(), ['step', '1', '--port', bus_process.device, '--baud', '1000000',
                                  '--to', '0.4', '--duration', '3', '--gains', 'p=200,d=50'],
                          encoding='utf-8', timeout=TIMEOUT_S)
    try:
        # Interrupted in the second run, its gains in force.
        child.expect(r'p=800 i=0 d=0 \(as set\): rise')
        child.sendintr()
        child.expect('dxl step: interrupted')
        child.expect(pexpect.EOF)
    finally:
        child.close(force=True)
    assert child.exitstatus == 130
    assert servo_state(bus_process.device) == before


def test_step_refuses_bad_gains(virtual_bus: StartVirtualBus) -> None:
    bus_process = virtual_bus([1], 1000000)
    done = subprocess.run([dxl(), 'step', '1', '--port', bus_process.device, '--baud', '1000000',
                           '--to', '0.4', '--gains', 'q=3'], capture_output=True, text=True,
                          timeout=TIMEOUT_S)
    assert done.returncode == 2
    assert done.stderr.strip() == ("dxl step: error: --gains 'q=3': each entry is p=N, i=N or "
                                   'd=N')
