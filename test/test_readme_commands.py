"""
Every `ros2 topic pub`, `ros2 service call` and `ros2 param set` line of the README, replayed.

The lines are taken from the README as written and sent through rclpy, with the same YAML
payloads, to a node running what `make run` runs (config/sim.yaml); each must be taken: a service
answers success, a parameter is set, a command's goal reaches the servo's register.
"""

import pathlib
import shlex
from typing import Any, Dict, List, Tuple

from dxl_servo_driver.models import modes
from dxl_servo_driver.ros.node import NODE_NAME
from node_harness import NodeHarness
import pytest
import yaml

ROOT = pathlib.Path(__file__).resolve().parent.parent
README = (ROOT / 'README.md').read_text()
PREFIX = f'/{NODE_NAME}/'
GOAL_REGISTERS = modes.GOAL_REGISTERS


def readme_lines() -> List[List[str]]:
    """
    Return the README's ros2 pub / call / param set lines that address the default node.

    Code blocks that run the node on another file (a scanned robot.yaml, a namespace) are about
    that file's joints, not make run's: they are left out.
    """
    lines = []
    blocks = README.split('```')[1::2]
    for line in (line for block in blocks if 'robot.yaml' not in block and '__ns' not in block
                 for line in block.splitlines()):
        text = line.strip()
        if not text.startswith(('ros2 topic pub', 'ros2 service call', 'ros2 param set')):
            continue
        words = shlex.split(text, comments=True)
        target = words[4] if words[2] == 'pub' and words[3].startswith('-') else words[3]
        if words[2] == 'pub' and words[3] == '-r':
            target = words[5]
        if target.startswith(PREFIX) or target == f'/{NODE_NAME}':
            lines.append(words)
    return lines


def flat_params() -> Dict[str, Any]:
    tree = yaml.safe_load((ROOT / 'config' / 'sim.yaml').read_text())['/**']['ros__parameters']
    flat: Dict[str, Any] = {}

    def walk(node: Dict[str, Any], prefix: str) -> None:
        for key, value in node.items():
            if isinstance(value, dict):
                walk(value, f'{prefix}{key}.')
            else:
                flat[f'{prefix}{key}'] = value
    walk(tree, '')
    return flat


def message_type(name: str) -> Any:
    package, kind, type_name = name.split('/')
    module = __import__(f'{package}.{kind}', fromlist=[type_name])
    return getattr(module, type_name)


def fill(msg: Any, values: Dict[str, Any]) -> Any:
    """Set a message's fields from a YAML mapping, as `ros2 topic pub` does."""
    types = msg.get_fields_and_field_types()
    for key, value in values.items():
        assert key in types, f'{type(msg).__name__} has no field {key!r}'
        kind = types[key]
        if isinstance(value, dict):
            fill(getattr(msg, key), value)
        elif kind in ('double', 'float'):
            setattr(msg, key, float(value))
        elif 'double' in kind and isinstance(value, list):
            setattr(msg, key, [float(v) for v in value])
        else:
            setattr(msg, key, value)
    return msg


@pytest.fixture(scope='module')
def h() -> Any:
    with NodeHarness(flat_params()) as harness:
        harness.joint_states.wait(lambda m: len(m.name) == 4)
        yield harness


def test_the_readme_has_the_lines_to_replay() -> None:
    kinds = {tuple(words[1:3]) for words in readme_lines()}
    assert kinds == {('topic', 'pub'), ('service', 'call'), ('param', 'set')}
    assert len(readme_lines()) >= 15


def replay(h: NodeHarness, words: List[str]) -> Tuple[str, Any]:
    assert h.node is not None and h.client is not None
    if words[1] == 'param':
        value = yaml.safe_load(words[5])
        result = h.set_parameter(words[4], value)
        assert result.successful, (words, result.reason)
        assert h.node.get_parameter(words[4]).value == value
        return 'param', value
    if words[1] == 'service':
        service, kind, payload = words[3], words[4], yaml.safe_load(words[5])
        name = service[len(PREFIX):]
        request = fill(message_type(kind).Request(), payload)
        response = h.call(name, **{k: getattr(request, k) for k in payload})
        assert response.success, (words, response.message)
        return 'service', response
    options = 2 if words[3] in ('-r', '--rate') else (1 if words[3].startswith('-') else 0)
    topic, kind = words[3 + options], words[4 + options]
    payload = yaml.safe_load(words[5 + options])
    msg = fill(message_type(kind)(), payload)
    name = topic[len(PREFIX):]
    if name.startswith('commands/'):
        command = name.split('/')[1]
        h.publish(command, msg.name, msg.value)
        servo = h.node.manager.servos[msg.name[0]]
        kind_ = servo.units.kinds[command]
        raw = kind_.to_raw(msg.value[0]) - (servo.turn_offset if command == 'position' else 0)
        h.wait_reg(servo.servo_id, GOAL_REGISTERS[command], lambda v: v == raw, timeout_s=5.0)
        return 'topic', raw
    # The arm topics: the node's handler of the topic answers success when it takes it.
    arm = h.node.arm
    handler = {'gripper': arm.gripper_command, 'joint_command': arm.joint_command,
               'joint_trajectory': arm.submit_trajectory}[name]
    result = handler(msg)
    assert result.success, (words, result.message)
    return 'topic', msg


@pytest.mark.parametrize('index', range(len(readme_lines())))
def test_each_readme_line_is_taken(h: NodeHarness, index: int) -> None:
    replay(h, readme_lines()[index])


def test_the_lines_make_run_suggests_are_taken() -> None:
    # A node of its own: the README's lines above change modes (set_operating_mode).
    with NodeHarness(flat_params()) as h:
        h.joint_states.wait(lambda m: len(m.name) == 4)
        check_suggestions(h)


def check_suggestions(h: NodeHarness) -> None:
    assert h.node is not None
    lines = h.node.what_to_try()
    assert len(lines) == 3
    assert lines[0] == f'ros2 topic echo {h.namespace}/joint_states'   # what the test reads
    kinds = []
    for line in lines[1:]:
        # The harness runs the node in a namespace of its own; the README's lines have none.
        words = [word[len(h.namespace):] if word.startswith(f'{h.namespace}/') else word
                 for word in shlex.split(line)]
        kinds.append(words[3])
        assert replay(h, words)[0] == 'topic'
    assert kinds == ['--once', '-r']
