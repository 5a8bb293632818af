"""The README stays true to the code: its parameter table, its commands and interface names."""

import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent
README = (ROOT / 'README.md').read_text()


def test_parameter_table_matches_the_code() -> None:
    sys.path.insert(0, str(ROOT / 'tools'))
    try:
        from param_table import rows
    finally:
        sys.path.pop(0)
    missing = [row for row in rows() if row not in README]
    assert not missing, 'README parameter table is out of date (tools/param_table.py):\n' + \
        '\n'.join(missing)


def test_supported_servo_table_matches_the_models() -> None:
    sys.path.insert(0, str(ROOT / 'tools'))
    try:
        from model_table import rows
    finally:
        sys.path.pop(0)
    missing = [row for row in rows() if row not in README]
    assert not missing, 'README servo table is out of date (tools/model_table.py):\n' + \
        '\n'.join(missing)


def test_readme_shows_every_topic_service_and_executable() -> None:
    for name in ('make run', 'make test', 'make bench', 'commands/position', 'commands/velocity',
                 'commands/current', 'commands/pwm', 'set_position', 'set_velocity', 'set_current',
                 'set_pwm', 'set_operating_mode', 'set_torque', 'reboot', 'read_register',
                 'write_register', 'servo_states', '/diagnostics', 'ros2 topic echo /joint_states',
                 'colcon build --base-paths', 'scan --port', 'virtual_bus --ids',
                 '99-dxl-servo-driver.rules', 'dxl_servo_driver.launch.py'):
        assert name in README, name
