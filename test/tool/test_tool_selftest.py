"""`dxl selftest` on virtual_bus: a healthy servo passes, a sick one fails saying why."""

import os
import subprocess
from typing import Dict, List

from ament_index_python.packages import get_package_prefix
from dxl_servo_driver.tool.session import connect, open_bus, retried
from processes import StartVirtualBus
import pytest

TIMEOUT_S = 60.0
KEPT = ('torque_enable', 'operating_mode', 'goal_current', 'goal_position', 'profile_velocity')


def dxl() -> str:
    """Return the installed `dxl` executable."""
    return os.path.join(get_package_prefix('dxl_servo_driver'), 'lib', 'dxl_servo_driver', 'dxl')


def selftest(device: str, *extra: str) -> 'subprocess.CompletedProcess[str]':
    """Run `dxl selftest 1` on device."""
    return subprocess.run([dxl(), 'selftest', '1', '--port', device, '--baud', '1000000', *extra],
                          capture_output=True, text=True, timeout=TIMEOUT_S)


def verdicts(output: str) -> Dict[str, List[str]]:
    """Return the verdict lines by result (PASS, FAIL, SKIP)."""
    found: Dict[str, List[str]] = {'PASS': [], 'FAIL': [], 'SKIP': []}
    for line in output.splitlines():
        result = line.split(' ', 1)[0]
        if result in found:
            found[result].append(line)
    return found


def kept(device: str) -> Dict[str, int]:
    """Return the items selftest changes for a while, read from servo 1."""
    bus = open_bus(device, 1000000)
    try:
        link = connect(bus, 1)
        return {name: retried(lambda: link.read(name)) for name in KEPT}
    finally:
        bus.close()


def test_a_healthy_servo_passes_and_is_left_as_it_was(virtual_bus: StartVirtualBus) -> None:
    bus_process = virtual_bus([1], 1000000)
    before = kept(bus_process.device)
    done = selftest(bus_process.device)
    assert done.returncode == 0, done.stdout + done.stderr
    found = verdicts(done.stdout)
    assert [line.split(':')[0] for line in found['PASS']] == [
        'PASS  hardware error', 'PASS  voltage', 'PASS  temperature', 'PASS  move +',
        'PASS  move -'], done.stdout
    assert 'Goal Current 0.301 A' in found['PASS'][3]   # the default, low
    assert done.stdout.rstrip().endswith('selftest: PASS (5 passed, 0 skipped)')
    assert kept(bus_process.device) == before


def test_the_users_current_is_respected(virtual_bus: StartVirtualBus) -> None:
    bus_process = virtual_bus([1], 1000000)
    done = selftest(bus_process.device, '--current', '0.1')
    assert done.returncode == 0, done.stdout + done.stderr
    assert 'Goal Current 0.100 A' in done.stdout   # 37 x 2.69 mA, the nearest to 0.1 A


@pytest.mark.parametrize('fault, failed, reason', [
    ('error 1 overheat', 'hardware error', 'latched: overheating'),
    ('voltage 1 6', 'voltage', '6.0 V is below the limits 9.5..16.0 V'),
])
def test_a_sick_servo_fails_saying_why(virtual_bus: StartVirtualBus, fault: str, failed: str,
                                       reason: str) -> None:
    bus_process = virtual_bus([1], 1000000)
    assert bus_process.control(fault).startswith('ok')
    before = kept(bus_process.device)
    done = selftest(bus_process.device)
    assert done.returncode == 1, done.stdout + done.stderr
    found = verdicts(done.stdout)
    assert any(line.startswith(f'FAIL  {failed}: {reason}') for line in found['FAIL']), (
        done.stdout)
    summary = done.stdout.rstrip().splitlines()[-1]
    assert summary.startswith('selftest: FAIL (') and failed in summary, summary
    if found['FAIL'][0].startswith('FAIL  hardware error'):
        # A latched error keeps the torque off: the moves are skipped, with the reason.
        assert [line.split(':')[0] for line in found['SKIP']] == ['SKIP  move +', 'SKIP  move -']
        assert all('hardware error is latched' in line for line in found['SKIP'])
    assert kept(bus_process.device) == before
