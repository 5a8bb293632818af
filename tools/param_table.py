"""Print the README's parameter reference table from dxl_servo_driver/config.py."""

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))

from dxl_servo_driver.config import PARAMS  # noqa: E402 - after the path set-up


def rows() -> list:
    """Return the table's lines."""
    lines = ['| name | type | default | unit | range | description |',
             '|---|---|---|---|---|---|']
    for spec in PARAMS:
        if spec.choices:
            allowed = ', '.join(str(c) for c in spec.choices)
        elif spec.minimum is not None:
            allowed = f'{spec.minimum:g} .. {spec.maximum:g}'
        else:
            allowed = ''
        default = spec.default if spec.default != [] else '(required)'
        if isinstance(default, bool):
            default = str(default).lower()
        kind = {'list': 'string[]'}.get(spec.kind.__name__, spec.kind.__name__)
        kind = {'float': 'double', 'str': 'string'}.get(kind, kind)
        lines.append(f'| `{spec.name}` | {kind} | `{default}` | {spec.unit} | {allowed} | '
                     f'{spec.description} |')
    return lines


if __name__ == '__main__':
    print('\n'.join(rows()))
