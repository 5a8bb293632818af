"""
No branch on a protocol's version outside the framers (protocol/).

What differs between Protocol 2.0 and 1.0 is a fact the framer states (`Framer.sync_read`,
`address_param`, `broadcast_ping`, ...): the rest of the package asks it. A branch is a
comparison of a protocol or version with a number (`framer.version == 1`, `protocol == 1.0`) or
with one framer (`framer is PROTOCOL_1`). Which protocol a model speaks is a fact of its table,
so `model.protocol` compared is a question about the model, not a branch on the bus's framer.
"""

import ast
import pathlib
from typing import List

PACKAGE = pathlib.Path(__file__).resolve().parents[2] / 'dxl_servo_driver'
VERSIONED = {'protocol', 'version', 'protocol_version'}
FRAMER_NAMES = {'PROTOCOL_1', 'PROTOCOL_2'}


def _names_a_version(node: ast.expr) -> bool:
    if isinstance(node, ast.Name):
        return node.id in VERSIONED
    if isinstance(node, ast.Attribute):
        owner = node.value
        is_model = isinstance(owner, ast.Name) and owner.id == 'model' or (
            isinstance(owner, ast.Attribute) and owner.attr == 'model')
        return node.attr in VERSIONED and not is_model
    return False


def _a_version_number(node: ast.expr) -> bool:
    return isinstance(node, ast.Constant) and node.value in (1, 2) and \
        not isinstance(node.value, bool)


def branches(source: str) -> List[str]:
    """Return the protocol-version comparisons of one module's source, as text."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Compare):
            continue
        sides = [node.left, *node.comparators]
        versioned = any(_names_a_version(side) for side in sides) and any(
            _a_version_number(side) for side in sides)
        framer = any(isinstance(side, ast.Name) and side.id in FRAMER_NAMES for side in sides)
        if versioned or framer:
            found.append(f'{node.lineno}: {ast.unparse(node)}')
    return found


def test_no_module_outside_the_framers_branches_on_a_protocol_version() -> None:
    found = []
    for path in sorted(PACKAGE.rglob('*.py')):
        relative = path.relative_to(PACKAGE).as_posix()
        if relative.startswith('protocol/'):
            continue
        found += [f'{relative}:{branch}' for branch in branches(path.read_text())]
    assert not found, 'ask the framer instead:\n' + '\n'.join(found)


def test_the_check_finds_a_branch() -> None:
    source = """
if framer.version == 1: pass
if servo.joint.protocol != 1.0: pass
if bus.framer is PROTOCOL_2: pass
if model.protocol == 1.0: pass        # a model's fact: not a branch
if framer.sync_read: pass             # a framer's fact: not a branch
"""
    assert [line.split(':')[0] for line in branches(source)] == ['2', '3', '4']
