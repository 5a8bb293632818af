"""mypy over the layers below the node (they are type-annotated: ARCHITECTURE.md)."""

import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
# Every layer below the node, and the tool's scan (the `scan` executable).
CHECKED = ['errors.py', 'timerslack.py', 'protocol', 'models', 'port', 'config', 'bus', 'driver',
           'arm', 'sim', 'tool/scan.py', 'tool/scan_file.py', 'tool/scan_report.py']


def test_the_layers_below_the_node_type_check() -> None:
    api = pytest.importorskip('mypy.api')
    paths = [str(ROOT / 'dxl_servo_driver' / name) for name in CHECKED]
    out, err, status = api.run(['--ignore-missing-imports', '--no-error-summary',
                                '--cache-dir', '/dev/null', *paths])
    assert status == 0, out + err
