"""
Rooms of one job: no class over 400 lines, no module over 700 but the model tables.

A control table is one fact per line, as long as its manual's table; anything else that grows past
these has found a second job: split it where it divides.
"""

import ast
import pathlib
from typing import Iterator, Tuple

ROOT = pathlib.Path(__file__).resolve().parents[2]
CHECKED = ('dxl_servo_driver', 'bench', 'tools')
MAX_CLASS_LINES = 400
MAX_MODULE_LINES = 700
# The model tables: rows of the e-manual's control tables, one register a line.
TABLES = {'dxl_servo_driver/models/' + name for name in (
    'catalog.py', 'xm430.py', 'mx.py', 'pro.py', 'pro_legacy.py', 'y.py', 'xl320.py',
    'protocol1.py')}


def modules() -> Iterator[Tuple[str, pathlib.Path]]:
    for folder in CHECKED:
        for path in sorted((ROOT / folder).rglob('*.py')):
            yield path.relative_to(ROOT).as_posix(), path


def long_rooms(source: str, name: str) -> list:
    """Return what is too long in one module's source: its classes, and itself unless a table."""
    found = []
    lines = len(source.splitlines())
    if lines > MAX_MODULE_LINES and name not in TABLES:
        found.append(f'{name}: {lines} lines')
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ClassDef):
            length = node.end_lineno - node.lineno + 1
            if length > MAX_CLASS_LINES:
                found.append(f'{name}: class {node.name} {length} lines')
    return found


def test_no_class_over_400_lines_and_no_module_over_700() -> None:
    found = [room for name, path in modules() for room in long_rooms(path.read_text(), name)]
    assert not found, '\n'.join(found)


def test_the_check_finds_a_long_room() -> None:
    body = '\n'.join(f'    x{i} = {i}' for i in range(MAX_CLASS_LINES))
    assert long_rooms(f'class Big:\n{body}\n', 'm.py') == ['m.py: class Big 401 lines']
    module = '\n'.join(f'x{i} = {i}' for i in range(MAX_MODULE_LINES + 1))
    assert long_rooms(module, 'm.py') == ['m.py: 701 lines']
    assert long_rooms(module, 'dxl_servo_driver/models/xm430.py') == []
