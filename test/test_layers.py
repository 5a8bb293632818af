"""
The package's layering (ARCHITECTURE.md): ros -> driver -> bus/transport -> protocol/models.

Nothing but the transport registry reaches the simulator; only the node imports rclpy, only
the serial transport the serial library.
"""

import ast
import pathlib

PACKAGE = pathlib.Path(__file__).resolve().parent.parent / 'dxl_servo_driver'
ROS_MODULES = ('rclpy', 'sensor_msgs', 'std_msgs', 'diagnostic_msgs', 'lifecycle_msgs',
               'rcl_interfaces', 'dxl_servo_driver_msgs', 'builtin_interfaces')
HARDWARE_MODULES = ('dynamixel_sdk', 'serial')
# Modules allowed to import each group (paths relative to the package).
ROS_ALLOWED = {'scan.py'}
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
    'scan.py': 3, 'ros': 3,
    'manager.py': 2, 'driver': 2, 'tasks.py': 2, 'config.py': 2, 'state_block.py': 2,
    'registers.py': 2,
    'transports.py': 2, 'trajectory.py': 2, 'commands.py': 2,
    'gripper.py': 2,
    'bus.py': 1, 'serial_port.py': 1,
    'protocol.py': 0, 'errors.py': 0, 'models': 0, 'termios2.py': 0,
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
