"""The `dxl` tool as a user runs it: the installed executable, to its end or at a terminal."""

import math
import os
import re
import subprocess
import time
from typing import List, Optional, Tuple

from ament_index_python.packages import get_package_prefix
from dxl_servo_driver.models import model_named
import pexpect
from processes import ROOT, VirtualBusProcess

# Generous: a loaded two-core machine; only a failure waits this long.
TIMEOUT_S = 60.0      # a command run to its end
EXPECT_TIMEOUT_S = 30.0   # one expected line of an interactive command
# What one reading may be off by: a pulse of the position, and the 4 decimals written.
TOLERANCE = 0.003
DXL = str(ROOT / 'install' / 'dxl_servo_driver' / 'lib' / 'dxl_servo_driver' / 'dxl')


def dxl_executable() -> str:
    """Return the installed `dxl` (symlink install: the package's modules, live)."""
    path = os.path.join(get_package_prefix('dxl_servo_driver'), 'lib', 'dxl_servo_driver',
                        'dxl')
    assert os.access(path, os.X_OK), f'{path} is not an executable (colcon build first)'
    return path


def dxl(*args: str) -> 'subprocess.CompletedProcess[str]':
    """Run `dxl ARGS` to its end; stdin is not a terminal."""
    return subprocess.run([dxl_executable(), *args], capture_output=True, text=True,
                          stdin=subprocess.DEVNULL, timeout=TIMEOUT_S)


def on(bus: VirtualBusProcess, *args: str) -> List[str]:
    """Return the port arguments for a command on this bus."""
    return [*args, '--port', bus.device]


def one_error_line(done: 'subprocess.CompletedProcess[str]', command: str) -> str:
    """Return the one error line a failed command wrote (asserting that it is one line)."""
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith(f'dxl {command}: error: '), lines[0]
    return lines[0]


def finish(child: 'pexpect.spawn[str]') -> Tuple[int, str]:
    """Wait for the end; return the exit status and what it printed last."""
    child.expect(pexpect.EOF)
    child.close()
    return child.exitstatus if child.exitstatus is not None else -child.signalstatus, \
        child.before


def near(value: float) -> str:
    """Return a regex of how the live display prints a value within TOLERANCE of value."""
    shown = {f'{value + step / 1000.0:+.3f}' for step in range(-2, 3)}
    return '(' + '|'.join(re.escape(text) for text in sorted(shown)) + ')'


def spawn(*args: str, cwd: Optional[str] = None) -> 'pexpect.spawn[str]':
    """Start the installed dxl on a terminal (wide: a live display's line is not wrapped)."""
    return pexpect.spawn(DXL, list(args), encoding='utf-8', timeout=EXPECT_TIMEOUT_S,
                         dimensions=(24, 400), cwd=cwd)


def turn_horn(bus: VirtualBusProcess, ref: str, model: str, rad: float,
              seconds: float = 0.3) -> None:
    """Turn a horn by hand (`turn REF RAD SECONDS`); return once it reads there."""
    answer = bus.control(f'turn {ref} {rad} {seconds}')
    assert answer.startswith('ok'), answer
    table = model_named(model)
    target = table.position_zero_raw + rad * table.pulses_per_rev / (2.0 * math.pi)
    deadline = time.monotonic() + EXPECT_TIMEOUT_S
    while abs(bus.get(ref, 'present_position') - target) > 1.0:
        assert time.monotonic() < deadline, f'the horn of {ref} did not reach {rad}'
        time.sleep(0.02)
