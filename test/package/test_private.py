"""
No module uses a private member of another object: each layer reaches the one below by its face.

A private member is a name with one leading underscore (`_name`, not `__dunder__`). An object
may use its own (`self._x`, `cls._x`, `super()._x`) and a module its own module-level privates
(`_helper()`); anything else (`other._x`, `module._x`, `getattr(other, '_x')`) reaches past
another object's public names, and fails here.
"""

import ast
import pathlib
from typing import Iterator, List, Tuple

PACKAGE = pathlib.Path(__file__).resolve().parents[2] / 'dxl_servo_driver'
# Uses allowed, as (module path relative to the package, the expression), and why: rclpy's
# LifecycleNode has no public hook for these, and test/ros/test_rclpy_internals.py fails the day
# an rclpy release changes them.
ALLOWED = {
    ('ros/lifecycle_guard.py', 'node._state_machine'),
    ('ros/lifecycle_guard.py', 'node._service_change_state'),
}


def _private(name: str) -> bool:
    return name.startswith('_') and not (name.startswith('__') and name.endswith('__'))


def _own(node: ast.expr) -> bool:
    """Return True for the objects whose privates are their own: self, cls, super()."""
    if isinstance(node, ast.Name):
        return node.id in ('self', 'cls')
    return (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
            and node.func.id == 'super')


def private_uses(source: str) -> Iterator[Tuple[int, str]]:
    """Yield (line, expression) of every use of another object's private member, in order."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Attribute) and _private(node.attr) and not _own(node.value):
            found.append(node)
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
              and node.func.id in ('getattr', 'setattr', 'hasattr', 'delattr')
              and len(node.args) >= 2 and isinstance(node.args[1], ast.Constant)
              and isinstance(node.args[1].value, str) and _private(node.args[1].value)
              and not _own(node.args[0])):
            found.append(node)
    for node in sorted(found, key=lambda node: (node.lineno, node.col_offset)):
        yield node.lineno, ast.unparse(node)


def test_the_check_finds_what_it_is_meant_to_find() -> None:
    source = """
import os

_TABLE = {}


def _helper(bus):
    bus._flush()                      # found
    return bus.framer._layout         # found
    return _TABLE, _helper, os.sep    # a module's own privates: fine


class Layer:
    def __init__(self, wire):
        self._wire = wire             # its own: fine
        self.__dict__                 # dunder: fine

    def run(self):
        self._wire.read()             # public of a private held object: fine
        self._wire._collect()         # found
        getattr(self._wire, '_lock')  # found
        super()._run()                # its own: fine
        return type(self)._cache, os._exit   # both found
"""
    found = [text for _, text in private_uses(source)]
    assert found == ['bus._flush', 'bus.framer._layout', 'self._wire._collect',
                     "getattr(self._wire, '_lock')", 'type(self)._cache', 'os._exit']


def test_no_module_uses_another_objects_private_member() -> None:
    uses: List[str] = []
    checked = 0
    for path in sorted(PACKAGE.rglob('*.py')):
        relative = path.relative_to(PACKAGE).as_posix()
        checked += 1
        for line, text in private_uses(path.read_text()):
            if (relative, text) not in ALLOWED:
                uses.append(f'{relative}:{line}: {text}')
    assert checked >= 50
    assert not uses, 'private members of other objects used:\n' + '\n'.join(uses)
