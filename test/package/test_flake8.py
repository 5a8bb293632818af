"""ament_flake8 over the package, its tests and tools (the ament lint style)."""

import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
PATHS = ['dxl_servo_driver', 'test', 'tools', 'setup.py', 'bench', 'launch', 'examples']


@pytest.mark.flake8
@pytest.mark.linter
def test_flake8() -> None:
    paths = [str(ROOT / p) for p in PATHS if (ROOT / p).exists()]
    # In a process of its own: flake8 forks workers, and forking this test process (threads
    # left by rclpy and the simulators of earlier tests) could hang them. Run from tools/:
    # ament_flake8 walks its working directory for AMENT_IGNORE, and the root holds .venv/.
    done = subprocess.run([sys.executable, '-m', 'ament_flake8.main', *paths],
                          cwd=ROOT / 'tools', capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stdout[-20000:] + done.stderr[-2000:]
