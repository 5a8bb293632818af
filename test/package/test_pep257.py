"""ament_pep257 over the package, its tests and tools."""

import pathlib

from ament_pep257.main import main
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
PATHS = ['dxl_servo_driver', 'test', 'tools', 'setup.py', 'bench', 'launch', 'examples']


@pytest.mark.linter
@pytest.mark.pep257
def test_pep257() -> None:
    paths = [str(ROOT / p) for p in PATHS if (ROOT / p).exists()]
    rc = main(argv=paths)
    assert rc == 0, 'Found code style errors / warnings'
