"""The built environment: generated interfaces import, executables sit where `ros2 run` looks."""

import os
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]


def test_messages_have_the_spec_fields() -> None:
    from dxl_servo_driver_msgs.msg import (
        GripperCommand, JointCommand, ServoState, ServoStateArray)
    assert set(JointCommand.get_fields_and_field_types()) == {'name', 'value'}
    assert JointCommand.get_fields_and_field_types()['value'] == 'sequence<double>'
    state = ServoState.get_fields_and_field_types()
    assert state == {
        'name': 'string', 'id': 'uint8', 'model_number': 'uint16', 'firmware_version': 'uint8',
        'operating_mode': 'string', 'torque_enabled': 'boolean', 'position': 'double',
        'velocity': 'double', 'current': 'double', 'pwm': 'double', 'input_voltage': 'double',
        'temperature': 'double', 'moving': 'boolean', 'moving_status': 'uint8',
        'hardware_error_status': 'uint8', 'hardware_errors': 'sequence<string>',
        'comm_errors': 'uint32',
        # beyond the fields required of it: the model's name, a gripper's grasp
        'model': 'string', 'grasping': 'boolean'}
    assert GripperCommand.get_fields_and_field_types() == {
        'name': 'string', 'position': 'double', 'ratio': 'double', 'max_effort': 'double'}
    assert ServoStateArray.get_fields_and_field_types() == {
        'header': 'std_msgs/Header', 'servos': 'sequence<dxl_servo_driver_msgs/ServoState>'}


@pytest.mark.parametrize('name, request_fields, response_fields', [
    ('SetGoals', {'name': 'sequence<string>', 'value': 'sequence<double>'}, None),
    ('SetOperatingMode', {'name': 'sequence<string>', 'mode': 'string'}, None),
    ('SetTorque', {'name': 'sequence<string>', 'enable': 'boolean'}, None),
    ('Reboot', {'name': 'sequence<string>'}, None),
    ('ReadRegister', {'name': 'string', 'register_name': 'string'},
     {'value': 'int64', 'success': 'boolean', 'message': 'string'}),
    ('WriteRegister', {'name': 'string', 'register_name': 'string', 'value': 'int64'}, None),
])
def test_services_have_the_spec_fields(name: str, request_fields: dict,
                                       response_fields: 'dict | None') -> None:
    import dxl_servo_driver_msgs.srv as srv
    service = getattr(srv, name)
    assert service.Request.get_fields_and_field_types() == request_fields
    expected = response_fields or {'success': 'boolean', 'message': 'string'}
    assert service.Response.get_fields_and_field_types() == expected


def test_console_scripts_are_where_ros2_run_looks() -> None:
    from ament_index_python.packages import get_package_prefix
    lib = pathlib.Path(get_package_prefix('dxl_servo_driver')) / 'lib' / 'dxl_servo_driver'
    for exe in ('node', 'virtual_bus', 'scan'):
        assert os.access(lib / exe, os.X_OK), f'{lib / exe} is not an executable'


def test_every_interface_field_is_commented() -> None:
    for path in sorted((ROOT / 'msg_defs').glob('*/*.*')):
        if path.suffix not in ('.msg', '.srv'):
            continue
        for line in path.read_text().splitlines():
            code = line.split('#', 1)[0].strip()
            if code and code != '---':
                assert '#' in line, f'{path.name}: field without a comment: {line!r}'


def test_package_xml_declares_what_the_code_imports() -> None:
    import xml.etree.ElementTree as ElementTree
    tree = ElementTree.parse(ROOT / 'package.xml')
    assert tree.getroot().get('format') == '3'
    keys = {element.text for element in tree.getroot()
            if element.tag in ('depend', 'exec_depend', 'test_depend')}
    for key in ('rclpy', 'rcl_interfaces', 'sensor_msgs', 'std_msgs', 'diagnostic_msgs',
                'lifecycle_msgs', 'dxl_servo_driver_msgs', 'dynamixel_sdk', 'python3-serial',
                'python3-yaml', 'launch', 'launch_ros', 'ament_index_python', 'ament_flake8',
                'ament_pep257', 'python3-pytest', 'python3-hypothesis'):
        assert key in keys, key
