"""ament_flake8 over the package, its tests and tools (the ament lint style)."""

import pathlib

from ament_flake8.main import main_with_errors
import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
PATHS = ['dxl_servo_driver', 'test', 'tools', 'setup.py', 'bench', 'launch']


@pytest.mark.flake8
@pytest.mark.linter
def test_flake8() -> None:
    paths = [str(ROOT / p) for p in PATHS if (ROOT / p).exists()]
    rc, errors = main_with_errors(argv=paths)
    assert rc == 0, 'Found %d code style errors / warnings:\n' % len(errors) + '\n'.join(errors)
