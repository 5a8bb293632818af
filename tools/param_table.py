"""
Print the parameter tables of docs/parameters.md (top level, per joint) from the code.

The tables are dxl_servo_driver.config's PARAMS and JOINT_PARAMS; test/docs/test_readme.py
checks that PAGE holds every row printed here. After a change to a parameter, paste the output
there.
"""

import pathlib
import sys
from typing import List

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))

from dxl_servo_driver.config import (  # noqa: E402 - path set-up
    JOINT_PARAMS, PARAMS, ParamSpec, REGISTER_FAMILIES)

# The page that shows the tables, from the repository's root.
PAGE = 'docs/parameters.md'

_KINDS = {'list': 'string[]', 'float': 'double', 'str': 'string'}


def _row(spec: ParamSpec, name: str) -> str:
    if spec.choices:
        allowed = ', '.join(str(c) for c in spec.choices)
    elif spec.minimum is not None:
        allowed = f'{spec.minimum:g} .. {spec.maximum:g}'
    else:
        allowed = ''
    default = spec.shown or spec.default
    if isinstance(default, bool):
        default = str(default).lower()
    default = f'`{default}`' if not spec.shown else default
    kind = _KINDS.get(spec.kind.__name__, spec.kind.__name__)
    when = ' Changes at run time.' if spec.runtime else ''
    only = ''
    if spec.only_for:
        switch = {joint.name: joint.kind for joint in JOINT_PARAMS}[spec.only_for]
        only = (f' Only for `<joint>.{spec.only_for}: true`.' if switch is bool
                else f' Only with `<joint>.{spec.only_for}` set.')
    return (f'| `{name}` | {kind} | {default} | {spec.unit} | {allowed} | '
            f'{spec.description}{when}{only} |')


def rows() -> List[str]:
    """Return the lines of both tables."""
    header = ['| name | type | default | unit | range | description |',
              '|---|---|---|---|---|---|']
    lines = header + [_row(spec, spec.name) for spec in PARAMS]
    lines += [''] + header + [_row(spec, f'<joint>.{spec.name}') for spec in JOINT_PARAMS]
    lines += [f'| `<joint>.{family}.<name>` | int | | | | {text} |'
              for family, text in REGISTER_FAMILIES]
    return lines


if __name__ == '__main__':
    print('\n'.join(rows()))
