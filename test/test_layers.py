"""The layering of STYLE.md: only the node imports rclpy, only the bus imports the SDK/serial."""

import ast
import pathlib

PACKAGE = pathlib.Path(__file__).resolve().parent.parent / 'dxl_servo_driver'
ROS_MODULES = ('rclpy', 'sensor_msgs', 'std_msgs', 'diagnostic_msgs', 'lifecycle_msgs',
               'rcl_interfaces', 'dxl_servo_driver_msgs', 'builtin_interfaces')
HARDWARE_MODULES = ('dynamixel_sdk', 'serial')
# Modules allowed to import each group (paths relative to the package).
ROS_ALLOWED = {'node.py', 'scan.py'}
HARDWARE_ALLOWED = {'bus.py'}


def imported_modules(path: pathlib.Path) -> set:
    tree = ast.parse(path.read_text(), filename=str(path))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split('.')[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split('.')[0])
    return names


def test_only_the_node_imports_ros_and_only_the_bus_imports_the_sdk() -> None:
    checked = 0
    for path in sorted(PACKAGE.rglob('*.py')):
        relative = path.relative_to(PACKAGE).as_posix()
        modules = imported_modules(path)
        if relative not in ROS_ALLOWED:
            assert not modules & set(ROS_MODULES), f'{relative} imports ROS: {modules}'
        if relative not in HARDWARE_ALLOWED:
            assert not modules & set(HARDWARE_MODULES), f'{relative} imports the SDK/serial'
        checked += 1
    assert checked >= 10


def test_the_simulator_and_model_import_neither() -> None:
    for path in list((PACKAGE / 'sim').glob('*.py')) + [PACKAGE / 'model.py',
                                                        PACKAGE / 'control_table.py',
                                                        PACKAGE / 'protocol.py']:
        modules = imported_modules(path)
        assert not modules & (set(ROS_MODULES) | set(HARDWARE_MODULES)), path.name
