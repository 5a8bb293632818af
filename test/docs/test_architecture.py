"""
ARCHITECTURE.md is true in every claim a program can check.

Every path it names exists; every `folder/module.Name` it names is there to import; its map of
the layers is the one test/package/test_layers.py enforces; every folder of the package is on
the map; every test module it names exists.
"""

import importlib
import pathlib
import re
import sys
from typing import List, Tuple

ROOT = pathlib.Path(__file__).resolve().parents[2]
PACKAGE = ROOT / 'dxl_servo_driver'
TEXT = (ROOT / 'ARCHITECTURE.md').read_text()
sys.path.insert(0, str(ROOT / 'test' / 'package'))
import test_layers  # noqa: E402, I100 - the layer test's own map, from its folder

CODE = re.compile(r'`([^`\s]+)`')
# A reference into the package: a path, then optionally .Name.attr (`driver/loop.CycleLoop`).
REFERENCE = re.compile(
    r'^(?P<path>[a-z_0-9]+(?:/[a-z_0-9]+)*)(?:\.py|/)?(?P<attrs>(?:\.[A-Za-z_]\w*)*)$')


def _where(path: str) -> List[pathlib.Path]:
    return [base / path for base in (PACKAGE, ROOT, ROOT / 'test') if (base / path).exists()]


def references() -> List[Tuple[str, str, str]]:
    """Return (text, path, attributes) of every backticked name with a slash or a .py in it."""
    found = []
    for token in CODE.findall(TEXT):
        token = token.rstrip('.,:;')
        if '/' not in token and not token.endswith('.py'):
            continue
        if token.startswith(('/', '~', '<')) or '*' in token or '…' in token:
            continue
        match = REFERENCE.match(token.replace('.py.', '.'))
        if match is None:
            continue
        path = match.group('path') + ('/' if token.endswith('/') else '')
        found.append((token, path, match.group('attrs')))
    return found


def _resolve(path: str, attrs: str) -> str:
    """Return '' when path (and its attributes) are there, else what is missing."""
    if path.endswith('/'):
        return '' if any(place.is_dir() for place in _where(path)) else f'no folder {path}'
    bare = path.split('/')[-1]
    if '/' not in path:
        # A bare file name: a test module, or a module of the package, anywhere.
        hits = list(ROOT.glob(f'test/**/{bare}.py')) + list(PACKAGE.glob(f'**/{bare}.py'))
        hits += [ROOT / f'{bare}.py'] if (ROOT / f'{bare}.py').exists() else []
        if not hits:
            return f'no file {bare}.py'
        return ''
    if not (_where(path + '.py') or _where(path)):
        return f'no {path}(.py) in the package, the repository or test/'
    if not attrs:
        return ''
    if not (PACKAGE / (path + '.py')).exists():
        return f'{path}{attrs}: attributes of a file outside the package'
    module = importlib.import_module('dxl_servo_driver.' + path.replace('/', '.'))
    target = module
    for name in attrs.strip('.').split('.'):
        if not hasattr(target, name):
            return f'{path}{attrs}: no {name}'
        target = getattr(target, name)
    return ''


def test_every_path_and_name_it_gives_is_there() -> None:
    found = references()
    assert len(found) > 60, found
    missing = [f'`{token}`: {problem}' for token, path, attrs in found
               for problem in [_resolve(path, attrs)] if problem]
    assert not missing, '\n'.join(missing)


def test_the_check_finds_what_is_not_there() -> None:
    assert _resolve('driver/loop', '.CycleLoop') == ''
    assert _resolve('driver/loop', '.NoSuchThing') != ''
    assert _resolve('driver/no_such_module', '') != ''
    assert _resolve('test_no_such_test', '') != ''
    assert _resolve('driver/', '') == '' and _resolve('no_such_folder/', '') != ''


def map_of_layers() -> dict:
    """Return {folder or root module: layer} from the map in the Layers section."""
    block = TEXT.split('## Layers', 1)[1].split('```', 2)[1]
    layers = {}
    layer = None
    for line in block.splitlines():
        head = re.match(r'^(\d)?\s+([a-z_0-9]+(?:/|\.py))\s', line + ' ')
        if not head:
            continue
        if head.group(1) is not None:
            layer = int(head.group(1))
        layers[head.group(2).rstrip('/')] = layer
    return layers


# A dotted name without a path: `manager.cycle_begin`, `protocol.FRAMERS`, `Goals.check`.
DOTTED = re.compile(r'^(?P<head>[A-Za-z_]\w*)(?P<attrs>(?:\.[A-Za-z_]\w*)+)(?:\(.*\))?$')
SKIP_HEADS = {'self', 'ros2', 'rclpy', 'sensor_msgs', 'control_msgs', 'std_msgs', 'os', 'time',
              'threading', 'docs', 'README', 'config', 'arm_sim', 'package', 'setup'}


def _modules() -> dict:
    """Return {a module's last name, or a folder's: [its dotted names]} over the package."""
    names: dict = {}
    for path in PACKAGE.rglob('*.py'):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix('').parts)
        if parts[-1] == '__init__':
            parts.pop()
        names.setdefault(parts[-1], []).append('.'.join(parts))
    return names


def _resolve_dotted(head: str, attrs: List[str]) -> str:
    """Return '' when `head.attrs` names something there (a module's, or one of its classes')."""
    candidates = []
    for dotted in _modules().get(head, []):
        module = importlib.import_module(dotted)
        candidates.append(module)
        candidates.extend(value for value in vars(module).values()
                          if isinstance(value, type) and value.__module__ == dotted)
    if not candidates and head[:1].isupper():
        for dotted in sum(_modules().values(), []):
            module = importlib.import_module(dotted)
            if isinstance(getattr(module, head, None), type):
                candidates.append(getattr(module, head))
    if not candidates:
        return ''   # not a name of the package (a message type, a ROS name)
    for target in candidates:
        for name in attrs:
            found = getattr(target, name, None)
            if found is None and isinstance(target, type):
                found = _instance_attribute(target, name)
            if found is None:
                break
            target = found
        else:
            return ''
    return f'{head}.{".".join(attrs)}: not there'


def _instance_attribute(cls: type, name: str) -> object:
    """Return something when cls's methods assign self.<name> (an instance attribute)."""
    import inspect
    for klass in cls.__mro__:
        if name in getattr(klass, '__annotations__', {}):
            return object()   # a dataclass's field, or a declared attribute
        try:
            source = inspect.getsource(klass)
        except (OSError, TypeError):
            continue
        if re.search(rf'self\.{name}\b\s*(?::[^=]+)?=', source):
            return object()
    return None


def test_every_dotted_name_it_gives_is_there() -> None:
    missing = []
    checked = 0
    for token in CODE.findall(TEXT):
        match = DOTTED.match(token.rstrip('.,:;'))
        if not match or match.group('head') in SKIP_HEADS or '/' in token:
            continue
        head, attrs = match.group('head'), match.group('attrs').strip('.').split('.')
        if attrs[-1] in ('py', 'md', 'yaml', 'rst', 'launch'):
            continue
        problem = _resolve_dotted(head, attrs)
        checked += problem == ''
        if problem:
            missing.append(f'`{token}`: {problem}')
    assert checked > 30
    assert not missing, '\n'.join(missing)


def test_the_dotted_check_finds_what_is_not_there() -> None:
    assert _resolve_dotted('manager', ['Manager', 'cycle_begin']) == ''
    assert _resolve_dotted('manager', ['cycle_begin']) == ''
    assert _resolve_dotted('manager', ['no_such_method']) != ''
    assert _resolve_dotted('Goals', ['check']) == ''
    assert _resolve_dotted('Goals', ['no_such']) != ''


def test_the_map_of_layers_is_the_one_the_layer_test_enforces() -> None:
    drawn = map_of_layers()
    enforced = dict(test_layers.LAYERS)
    assert {name: layer for name, layer in drawn.items() if name != 'sim'} == enforced
    assert 'sim' in drawn, 'the simulator is on the map, outside the order'
    folders = {path.name for path in PACKAGE.iterdir() if (path / '__init__.py').exists()}
    roots = {path.name for path in PACKAGE.glob('*.py')} - {'__init__.py'}
    assert folders | roots == set(drawn), 'every folder and root module of the package is drawn'
