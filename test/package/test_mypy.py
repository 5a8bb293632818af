"""mypy over the layers below the node (they are type-annotated: ARCHITECTURE.md)."""

import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
CHECKED = ['state_block.py', 'registers.py', 'config.py', 'protocol.py', 'manager.py', 'driver',
           'serial_port.py', 'termios2.py',
           'bus.py', 'scan.py', 'sim', 'tasks.py', 'models', 'transports.py', 'trajectory.py',
           'commands.py', 'gripper.py']


def test_the_layers_below_the_node_type_check() -> None:
    api = pytest.importorskip('mypy.api')
    paths = [str(ROOT / 'dxl_servo_driver' / name) for name in CHECKED]
    out, err, status = api.run(['--ignore-missing-imports', '--no-error-summary',
                                '--cache-dir', '/dev/null', *paths])
    assert status == 0, out + err
