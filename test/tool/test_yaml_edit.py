"""The parameter-file editor of `dxl calibrate`: other lines kept, keys placed, refusals."""

import pathlib
from typing import Any, Dict, List

from dxl_servo_driver import config
from dxl_servo_driver.tool import yaml_edit
import pytest
import yaml

ROOT = pathlib.Path(__file__).resolve().parents[2]
ARM = (ROOT / 'config' / 'arm_sim.yaml').read_text()


def flat(text: str) -> Dict[str, Any]:
    """Return the file's parameters as ROS flattens them."""
    return yaml_edit.parameters_of(text)


def changed_lines(old: str, new: str) -> List[str]:
    """Return the lines new has in place of, or beside, old's (a unified diff's '+' lines)."""
    diff = yaml_edit.unified_diff(old, new, 'f').splitlines(keepends=True)[2:]
    return [line[1:] for line in diff if line.startswith('+')]


def test_change_keeps_every_other_line_byte_identical() -> None:
    new = yaml_edit.apply(ARM, {'elbow': {'offset': 0.2513}, 'wrist_roll': {'reverse': True},
                                'shoulder_pan': {'min_position': -2.5}})
    old_lines, new_lines = ARM.splitlines(keepends=True), new.splitlines(keepends=True)
    assert len(new_lines) == len(old_lines) + 1     # reverse inserted, two changed in place
    differing = [(a, b) for a, b in zip(old_lines, new_lines) if a != b]
    # Up to the insertion every line but the two changed is byte-identical.
    assert differing[0] == ('      min_position: -2.6            # rad, joint units: written to '
                            "the servo's position limits\n",
                            '      min_position: -2.5            # rad, joint units: written to '
                            "the servo's position limits\n")
    assert ('      offset: 0.2                   # the URDF zero is 0.2 rad round the horn\n',
            '      offset: 0.2513                # the URDF zero is 0.2 rad round the horn\n') \
        in differing
    assert changed_lines(ARM, new) == [
        "      min_position: -2.5            # rad, joint units: written to the servo's "
        'position limits\n',
        '      offset: 0.2513                # the URDF zero is 0.2 rad round the horn\n',
        '      reverse: true\n']
    params = flat(new)
    assert params['elbow.offset'] == 0.2513 and params['wrist_roll.reverse'] is True
    assert params['shoulder_pan.min_position'] == -2.5
    config.validate(params)


def test_a_missing_key_goes_at_the_end_of_its_own_joint() -> None:
    new = yaml_edit.apply(ARM, {'wrist_pitch': {'offset': -0.1}})
    lines = new.splitlines()
    at = lines.index('      offset: -0.1')
    assert lines[at - 1] == '      max_position: 1.9'     # wrist_pitch's last key
    assert lines[at + 1] == '    wrist_roll:'
    assert flat(new)['wrist_pitch.offset'] == -0.1
    assert 'offset' not in yaml.safe_load(ARM)['/**']['ros__parameters']['wrist_pitch']


def test_the_last_joint_of_the_file_and_a_file_without_a_final_line_break() -> None:
    text = ARM.rstrip('\n')
    new = yaml_edit.apply(text, {'gripper': {'gripper_open': 0.05, 'offset': 1.0}})
    assert new.startswith(text.rsplit('\n', 2)[0])
    # The last line gets its line break, the inserted one one too.
    assert new.endswith('      gripper_open: 0.05\n      gripper_closed: 1.2\n      offset: 1.0\n')
    assert flat(new)['gripper.offset'] == 1.0


def test_values_are_written_with_the_type_ros_reads() -> None:
    assert yaml_edit.format_value(1.0) == '1.0'
    assert yaml_edit.format_value(-0.0) == '0.0'
    assert yaml_edit.format_value(0.123456) == '0.1235'
    assert yaml_edit.format_value(False) == 'false'
    new = yaml_edit.apply(ARM, {'elbow': {'offset': 2.0, 'min_position': -2.0}})
    assert isinstance(flat(new)['elbow.offset'], float)   # not the integer 2: ROS would refuse


def test_crlf_comments_and_blank_lines_kept() -> None:
    text = ('# header\r\n/**:\r\n  ros__parameters:\r\n    joints: [a, b]\r\n    a:\r\n'
            '      id: 1\r\n\r\n      # the elbow\r\n      offset: 0.5  # by eye\r\n\r\n'
            '    b:\r\n      id: 2\r\n')
    new = yaml_edit.apply(text, {'a': {'offset': -1.25, 'reverse': True}})
    assert new == ('# header\r\n/**:\r\n  ros__parameters:\r\n    joints: [a, b]\r\n    a:\r\n'
                   '      id: 1\r\n\r\n      # the elbow\r\n      offset: -1.25 # by eye\r\n'
                   '      reverse: true\r\n\r\n    b:\r\n      id: 2\r\n')


def test_flat_keys_are_changed_in_place_and_added_beside() -> None:
    text = '/**:\n  ros__parameters:\n    joints: [a]\n    a.id: 1\n    a.offset: 0.5\n' \
           '    loop_rate: 50.0\n'
    new = yaml_edit.apply(text, {'a': {'offset': 0.25, 'reverse': True}})
    assert new == ('/**:\n  ros__parameters:\n    joints: [a]\n    a.id: 1\n    a.offset: 0.25\n'
                   '    a.reverse: true\n    loop_rate: 50.0\n')


def test_the_section_listing_joints_is_the_one_changed() -> None:
    text = ('other_node:\n  ros__parameters:\n    a:\n      id: 9\n'
            '/arm/driver:\n  ros__parameters:\n    joints: [a]\n    a:\n      id: 1\n')
    new = yaml_edit.apply(text, {'a': {'offset': 0.5}})
    assert new == text + '      offset: 0.5\n'


@pytest.mark.parametrize('text, words', [
    ('/**: {ros__parameters: {joints: [a], a: {id: 1}}}\n', 'no "ros__parameters:" block'),
    ('/**:\n  ros__parameters:\n    joints: [a]\n    a: 3\n', 'written inline'),
    ('/**:\n  ros__parameters:\n    joints: [a]\n    a: {id: 1,\n        offset: 0.2}\n',
     "joint 'a' is a flow mapping continued on the next lines"),
    ('/**:\n  ros__parameters:\n    joints: [a]\n    a: {id}\n', 'cannot unfold'),
    ('/**:\n  ros__parameters:\n    joints: [a]\n    a:\n      id: 1\n      offset: 0.1\n'
     '      offset: 0.2\n', 'given 2 times'),
    ('/**:\n  ros__parameters:\n    joints: [a]\n    a:\n      id: 1\n      offset:\n'
     '        0.1\n', 'continues on the next lines'),
    ('/**:\n  ros__parameters:\n    joints: [a]\n    a:\n      id: 1\n      offset: &o 0.1\n',
     'not a plain scalar'),
    ('/**:\n  ros__parameters:\n    joints: [a]\n    a:\n      id: 1\n    a.offset: 0.3\n'
     '    a:\n      id: 2\n', 'given 2 times'),
    ('/**:\n  ros__parameters:\n    joints: [b]\n    b:\n      id: 1\n', "joint 'a' is not"),
    ('a:\n  ros__parameters:\n    joints: [a]\nb:\n  ros__parameters:\n    joints: [a]\n',
     'expected one'),
    ('/**:\n  ros__parameters:\n    joints: [a]\n    a:\n      id: 1\n---\nb: 1\n',
     'not valid YAML'),
])
def test_what_cannot_be_placed_is_refused(text: str, words: str) -> None:
    with pytest.raises(yaml_edit.EditError, match=words.replace('(', r'\(')):
        yaml_edit.apply(text, {'a': {'offset': 0.5}})


def test_a_joint_written_inline_is_unfolded_into_a_block_the_rest_byte_identical() -> None:
    # README.md's first parameter file: `shoulder: {id: 1, operating_mode: position}`.
    text = (ROOT / 'config' / 'one_joint.yaml').read_text()
    inline = '    shoulder: {id: 1, operating_mode: position}\n'
    assert inline in text
    new = yaml_edit.apply(text, {'shoulder': {'offset': 0.25, 'reverse': True}})
    head, _, tail = text.partition(inline)
    assert new == head + ('    shoulder:\n      id: 1\n      operating_mode: position\n'
                          '      offset: 0.25\n      reverse: true\n') + tail
    assert flat(new) == {**flat(text), 'shoulder.offset': 0.25, 'shoulder.reverse': True}


def test_an_inline_joint_keeps_its_comment_values_as_written_and_the_files_indent() -> None:
    text = ('/**:\r\n  ros__parameters:\r\n    joints: [a, b]\r\n'
            '    a: {id: 1, registers: {profile_velocity: 30}, note: "x, y: z", '
            'ids: [1, 2],}   # the elbow\r\n    b:\r\n        id: 2\r\n')
    new = yaml_edit.apply(text, {'a': {'offset': 0.5}})
    assert new == ('/**:\r\n  ros__parameters:\r\n    joints: [a, b]\r\n'
                   '    a:   # the elbow\r\n        id: 1\r\n        registers:\r\n'
                   '            profile_velocity: 30\r\n        note: "x, y: z"\r\n'
                   '        ids: [1, 2]\r\n        offset: 0.5\r\n    b:\r\n        id: 2\r\n')
    # Only the joints changed are unfolded.
    other = text.replace('    b:\r\n        id: 2', '    b: {id: 2}')
    assert yaml_edit.apply(other, {'a': {'offset': 0.5}}).endswith('    b: {id: 2}\r\n')


def test_a_joint_with_a_comment_after_its_colon_is_a_block() -> None:
    # config/koch_leader.yaml's gripper: `gripper:      # the trigger ...`.
    text = '/**:\n  ros__parameters:\n    joints: [a]\n    a:        # the trigger\n      id: 1\n'
    assert yaml_edit.apply(text, {'a': {'offset': 0.5}}) == text + '      offset: 0.5\n'
    leader = (ROOT / 'config' / 'koch_leader.yaml').read_text()
    new = yaml_edit.apply(leader, {'gripper': {'gripper_open': 0.1}})
    assert flat(new)['gripper.gripper_open'] == 0.1


def test_a_block_scalar_is_not_taken_for_keys() -> None:
    text = ('/**:\n  ros__parameters:\n    joints: [a]\n    note: |\n      a:\n'
            '        offset: 1.0\n    a:\n      id: 1\n')
    new = yaml_edit.apply(text, {'a': {'offset': 0.5}})
    assert new == text + '      offset: 0.5\n'
    assert flat(new)['note'] == 'a:\n  offset: 1.0\n'


def test_unified_diff() -> None:
    new = yaml_edit.apply(ARM, {'elbow': {'offset': 0.3}})
    diff = yaml_edit.unified_diff(ARM, new, 'arm.yaml')
    assert diff.startswith('--- arm.yaml\n+++ arm.yaml\n@@')
    assert '-      offset: 0.2  ' in diff and '+      offset: 0.3  ' in diff
    assert yaml_edit.unified_diff(ARM, ARM, 'arm.yaml') == ''
