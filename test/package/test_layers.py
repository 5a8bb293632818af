"""
The package's layering (ARCHITECTURE.md): the layers are folders, each importing only below it.

ros, tool -> driver, arm -> bus -> config, port -> protocol, models -> errors, timerslack.

Nothing but the transport registry reaches the simulator; only the node imports rclpy, only
the serial transport the serial library; no module imports itself through others (a circle).
"""

import ast
import pathlib

PACKAGE = pathlib.Path(__file__).resolve().parents[2] / 'dxl_servo_driver'
ROS_MODULES = ('rclpy', 'sensor_msgs', 'std_msgs', 'diagnostic_msgs', 'lifecycle_msgs',
               'rcl_interfaces', 'dxl_servo_driver_msgs', 'builtin_interfaces', 'std_srvs')
HARDWARE_MODULES = ('dynamixel_sdk', 'serial')
# Modules allowed to import each group (paths relative to the package).
ROS_ALLOWED: set = set()   # modules outside ros/ allowed to import ROS: none
ROS_PACKAGE = 'ros/'   # the node's parts
HARDWARE_ALLOWED = {'port/serial_device.py'}


def imported_modules(path: pathlib.Path) -> set:
    tree = ast.parse(path.read_text(), filename=str(path))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split('.')[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split('.')[0])
    return names


def test_only_the_node_imports_ros_and_only_the_transport_imports_serial() -> None:
    checked = 0
    for path in sorted(PACKAGE.rglob('*.py')):
        relative = path.relative_to(PACKAGE).as_posix()
        modules = imported_modules(path)
        if relative not in ROS_ALLOWED and not relative.startswith(ROS_PACKAGE):
            assert not modules & set(ROS_MODULES), f'{relative} imports ROS: {modules}'
        if relative not in HARDWARE_ALLOWED:
            assert not modules & set(HARDWARE_MODULES), f'{relative} imports the SDK/serial'
        checked += 1
    assert checked >= 10


def test_the_simulator_and_model_import_neither() -> None:
    for path in list((PACKAGE / 'sim').glob('*.py')) + [PACKAGE / 'driver' / 'state_block.py',
                                                        *(PACKAGE / 'protocol').glob('*.py')]:
        modules = imported_modules(path)
        assert not modules & (set(ROS_MODULES) | set(HARDWARE_MODULES)), path.name


# Each folder's layer (and the few modules every layer shares, at the package root): a module may
# import its own folder, or a folder of a lower layer; two folders of one layer never import each
# other (the arm's logic and the driver are side by side, as are the node and the tool).
LAYERS = {
    'ros': 5, 'tool': 5,
    'driver': 4, 'arm': 4,
    'bus': 3,
    'config': 2, 'port': 2,
    'protocol': 1, 'models': 1,
    'errors.py': 0, 'timerslack.py': 0,
}
# What the simulator may build on: it is a peer of the serial port, below the bus.
SIM_MAY_IMPORT = {'protocol', 'models', 'errors.py', 'timerslack.py', 'port'}
# Layers whose face (the folder's __init__) is all another folder may import.
FACES = ('protocol', 'port', 'bus', 'config')


def folder_of(module: str) -> str:
    """Return the folder (or root module file) of a dxl_servo_driver module name."""
    parts = module.split('.')
    if parts[0] != 'dxl_servo_driver' or len(parts) < 2:
        raise ValueError(module)
    return parts[1] if parts[1] in LAYERS or parts[1] == 'sim' else parts[1] + '.py'


def face_modules(folder: str) -> set:
    """Return what another folder may import of a folder with a face: it, and what it exports."""
    tree = ast.parse((PACKAGE / folder / '__init__.py').read_text())
    exported = next((ast.literal_eval(node.value) for node in tree.body
                     if isinstance(node, ast.Assign) and node.targets[0].id == '__all__'), [])
    face = f'dxl_servo_driver.{folder}'
    return {face} | {f'{face}.{name}' for name in exported
                     if (PACKAGE / folder / f'{name}.py').exists()}


def layer_of(module: str) -> int:
    """Return the layer of a dxl_servo_driver module name (sim: -1, outside the order)."""
    folder = folder_of(module)
    return -1 if folder == 'sim' else LAYERS[folder]


def package_imports(path: pathlib.Path) -> set:
    tree = ast.parse(path.read_text(), filename=str(path))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module == 'dxl_servo_driver':
                names.update(f'dxl_servo_driver.{alias.name}' for alias in node.names)
            else:
                names.add(node.module)
    return {name for name in names if name.startswith('dxl_servo_driver.')}


def test_every_module_imports_only_its_folder_or_a_lower_layer() -> None:
    checked = 0
    for path in sorted(PACKAGE.rglob('*.py')):
        relative = path.relative_to(PACKAGE).as_posix()
        own = folder_of('dxl_servo_driver.' + relative[:-3].replace('/', '.'))
        if own == 'sim' or relative == '__init__.py':
            continue
        assert own in LAYERS, f'{relative} is in no layer: give its folder one'
        for module in package_imports(path):
            folder = folder_of(module)
            assert folder != 'sim', f'{relative} imports the simulator ({module})'
            if folder == own:
                continue
            assert LAYERS[folder] < LAYERS[own], (
                f'{relative} ({own}, layer {LAYERS[own]}) imports {module} '
                f'({folder}, layer {LAYERS[folder]})')
            if folder in FACES:
                assert module in face_modules(folder), (
                    f'{relative} imports {module}: import {folder}/ by its face')
        checked += 1
    assert checked >= 12


def test_the_package_root_holds_only_what_every_layer_shares() -> None:
    root = sorted(path.name for path in PACKAGE.glob('*.py'))
    assert root == ['__init__.py', 'errors.py', 'timerslack.py'], root
    folders = sorted(path.name for path in PACKAGE.iterdir()
                     if path.is_dir() and (path / '__init__.py').exists())
    assert folders == sorted([name for name in LAYERS if not name.endswith('.py')] + ['sim'])


def test_only_the_transport_registry_reaches_the_simulator() -> None:
    for path in sorted(PACKAGE.rglob('*.py')):
        relative = path.relative_to(PACKAGE).as_posix()
        if relative.startswith('sim/') or relative == 'driver/transports.py':
            continue
        assert 'dxl_servo_driver.sim' not in path.read_text(), relative
    # The simulator itself builds on the bottom layer and the port (tables, models, packets).
    for path in (PACKAGE / 'sim').glob('*.py'):
        for module in package_imports(path):
            folder = folder_of(module)
            assert folder in SIM_MAY_IMPORT | {'sim'}, f'sim/{path.name} imports {module}'
            if folder in FACES:
                assert module in face_modules(folder), (
                    f'sim/{path.name} imports {module}: import {folder}/ by its face')


def _module_name(path: pathlib.Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix('').parts)
    if parts[-1] == '__init__':
        parts.pop()
    return '.'.join(parts)


def _module_graph() -> dict:
    """Return {module: modules of the package it imports}, submodules named by `from` resolved."""
    files = {_module_name(path): path for path in PACKAGE.rglob('*.py')}
    graph = {}
    for name, path in files.items():
        edges = set()
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                edges.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                for alias in node.names:
                    sub = f'{node.module}.{alias.name}'
                    edges.add(sub if sub in files else node.module)
        graph[name] = {edge for edge in edges if edge in files and edge != name}
    return graph


def _circle(graph: dict) -> list:
    """Return one import circle as a list of modules, or [] when there is none."""
    state = {}   # module -> 1 on the path being explored, 2 done

    def visit(module: str, path: list) -> list:
        state[module] = 1
        for imported in sorted(graph[module]):
            if state.get(imported) == 1:
                return path[path.index(imported):] + [imported]
            if imported not in state:
                found = visit(imported, path + [imported])
                if found:
                    return found
        state[module] = 2
        return []

    for module in sorted(graph):
        if module not in state:
            found = visit(module, [module])
            if found:
                return found
    return []


def test_no_import_circle() -> None:
    graph = _module_graph()
    assert len(graph) > 40 and 'dxl_servo_driver.ros.node' in graph
    assert _circle(graph) == [], ' -> '.join(_circle(graph))
    # The check finds one where there is one.
    assert _circle({'a': {'b'}, 'b': {'c'}, 'c': {'a'}, 'd': set()}) == ['a', 'b', 'c', 'a']


# The module at the top of a folder: it builds the folder's parts (driver/: the manager) or is an
# executable's entry (ros/, tool/); only the layers above import it.
FOLDER_TOPS = {'driver': 'manager', 'ros': 'main', 'tool': 'main'}


def test_no_part_of_a_folder_imports_its_top_or_its_face() -> None:
    """
    No module imports the top (FOLDER_TOPS) or the face (FACES: the __init__) of its own folder.

    Such an import runs back up. The circle test sees only an import that comes back to its
    module, and the layer test lets a folder import itself: a part of driver/ importing the
    manager (which imports every other part) is neither. Every import counts, in a function or
    under `if TYPE_CHECKING:` too. A part that calls its top names the calls in a Protocol
    (driver/roles.py).
    """
    def upward(graph: dict, tops: set) -> list:
        found = []
        for module, imported in sorted(graph.items()):
            for top in sorted(imported & tops):
                folder = top if top.count('.') == 1 else top.rpartition('.')[0]
                if module.startswith(folder + '.') and module != top:
                    found.append(f'{module} imports {top}')
        return found

    tops = ({f'dxl_servo_driver.{folder}' for folder in FACES}
            | {f'dxl_servo_driver.{folder}.{top}' for folder, top in FOLDER_TOPS.items()})
    graph = _module_graph()
    assert set(graph) >= tops
    assert upward(graph, tops) == []
    # The check finds one where there is one: a part importing the top, a part importing the face.
    assert upward({'p.d.top': {'p.d.part'}, 'p.d.part': set(), 'p.d.loop': {'p.d.top'},
                   'p.f': {'p.f.a'}, 'p.f.a': set(), 'p.f.b': {'p.f', 'p.d.top'}},
                  {'p.d.top', 'p.f'}) == ['p.d.loop imports p.d.top', 'p.f.b imports p.f']
