"""
The package's layering (ARCHITECTURE.md): ros -> driver -> bus/transport -> protocol/models.

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
HARDWARE_ALLOWED = {'serial_port.py'}


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
    for path in list((PACKAGE / 'sim').glob('*.py')) + [PACKAGE / 'state_block.py',
                                                        PACKAGE / 'protocol.py']:
        modules = imported_modules(path)
        assert not modules & (set(ROS_MODULES) | set(HARDWARE_MODULES)), path.name


# Each module's layer: a module may import the package's modules of its own layer or below.
LAYERS = {
    'scan.py': 3, 'ros': 3, 'tool': 3,
    'manager.py': 2, 'driver': 2, 'tasks.py': 2, 'config.py': 2, 'state_block.py': 2,
    'registers.py': 2,
    'transports.py': 2, 'trajectory.py': 2, 'commands.py': 2,
    'gripper.py': 2,
    'bus.py': 1, 'wire.py': 1, 'transactions.py': 1, 'group_reads.py': 1, 'serial_port.py': 1,
    'protocol.py': 0, 'protocol1.py': 0, 'errors.py': 0, 'models': 0, 'termios2.py': 0,
    'raw_port.py': 0,
    'timerslack.py': 0,
}


def layer_of(module: str) -> int:
    """Return the layer of a dxl_servo_driver module name (sim: -1, outside the order)."""
    parts = module.split('.')
    if parts[0] != 'dxl_servo_driver' or len(parts) < 2:
        raise ValueError(module)
    if parts[1] == 'sim':
        return -1
    key = parts[1] if parts[1] in LAYERS else parts[1] + '.py'
    return LAYERS[key]


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


def test_every_module_imports_only_its_layer_or_below() -> None:
    checked = 0
    for path in sorted(PACKAGE.rglob('*.py')):
        relative = path.relative_to(PACKAGE).as_posix()
        top = relative.split('/')[0]
        if top == 'sim' or relative == '__init__.py':
            continue
        own = LAYERS[top]
        for module in package_imports(path):
            assert layer_of(module) != -1, f'{relative} imports the simulator ({module})'
            assert layer_of(module) <= own, f'{relative} (layer {own}) imports {module}'
        checked += 1
    assert checked >= 12


def test_only_the_transport_registry_reaches_the_simulator() -> None:
    for path in sorted(PACKAGE.rglob('*.py')):
        relative = path.relative_to(PACKAGE).as_posix()
        if relative.startswith('sim/') or relative == 'transports.py':
            continue
        assert 'dxl_servo_driver.sim' not in path.read_text(), relative
    # The simulator itself builds on the bottom layer only (tables, models, packets).
    for path in (PACKAGE / 'sim').glob('*.py'):
        for module in package_imports(path):
            assert layer_of(module) in (-1, 0), f'sim/{path.name} imports {module}'


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
