"""
The pairs from the box: their parameter files, the two launch files, and a pair run on `sim`.

config/koch_*.yaml and omx_*.yaml are read as ROS reads them (check_parameter_file, the nested
keys joined with dots) and validated; the launch files are built against stand-ins for launch
and launch_ros (neither is installable here), as test_launch.py does for the one-bus file; and
each pair's two files run as the installed node, in the namespaces teleop.launch.py gives them,
on `port: sim`, until the follower says it follows its leader.
"""

import importlib.util
import pathlib
import sys
import time
import types
from typing import Any, Dict, Iterator, List, Mapping, Tuple

from diagnostic_msgs.msg import DiagnosticArray
from dxl_servo_driver import config as cfg
from node_harness import Client, new_context
from processes import NodeProcess
import pytest
import rclpy
import yaml  # type: ignore[import-untyped]

ROOT = pathlib.Path(__file__).resolve().parents[2]
PAIRS = (('koch_leader.yaml', 'koch_follower.yaml'), ('omx_leader.yaml', 'omx_follower.yaml'))
WAIT_S = 60.0   # two nodes starting side by side on a busy machine


def flat(tree: Mapping[str, Any], prefix: str = '') -> Dict[str, Any]:
    """Return a ros__parameters mapping with nested keys joined by dots, as ROS does."""
    out: Dict[str, Any] = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(flat(value, f'{prefix}{key}.'))
        else:
            out[f'{prefix}{key}'] = value
    return out


def read(name: str) -> cfg.DriverConfig:
    path = ROOT / 'config' / name
    cfg.check_parameter_file(str(path))
    return cfg.validate(flat(yaml.safe_load(path.read_text())['/**']['ros__parameters']))


@pytest.mark.parametrize('leader_file, follower_file', PAIRS)
def test_each_pair_is_a_leader_without_torque_and_a_follower_of_it(
        leader_file: str, follower_file: str) -> None:
    leader, follower = read(leader_file), read(follower_file)
    assert leader.follow_topic == ''
    # A leader's joints are passive, but for its gripper: a trigger, a spring at its rest.
    assert all(not joint.torque for joint in leader.joints if not joint.trigger)
    assert [joint.name for joint in leader.joints if joint.trigger] == ['gripper']
    assert follower.follow_topic == '/leader/joint_states'
    assert leader.port == follower.port == 'sim'
    leader_joints = {joint.name: joint for joint in leader.joints}
    for joint in follower.joints:
        # Every follower joint copies a leader joint of the same name; the grippers map the
        # leader's travel.
        assert joint.follow in leader_joints
        if joint.gripper:
            source = leader_joints[joint.follow]
            assert source.gripper
            travel = (source.gripper_open, source.gripper_closed)
            assert (joint.follow_open, joint.follow_closed) == travel
            assert joint.operating_mode == 'current_based_position'


def test_the_koch_pair_has_the_koch_servos() -> None:
    leader, follower = read('koch_leader.yaml'), read('koch_follower.yaml')
    assert [j.model.name for j in leader.joints if j.model] == ['XL330-M077'] * 6
    assert [j.model.name for j in follower.joints if j.model] == (
        ['XL430-W250'] * 2 + ['XL330-M288'] * 4)
    assert read('omx_follower.yaml').joints[0].model.name == 'XM430-W350'   # type: ignore


class _Recorded:
    """A stand-in for a launch class: remembers how it was built."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args = args
        self.kwargs = kwargs


@pytest.fixture
def launch_classes(monkeypatch: pytest.MonkeyPatch) -> Iterator[Dict[str, type]]:
    pytest.importorskip('ament_index_python')
    classes = {name: type(name, (_Recorded,), {}) for name in (
        'LaunchDescription', 'DeclareLaunchArgument', 'LaunchConfiguration', 'Node')}
    for module_name, names in (('launch', ['LaunchDescription']),
                               ('launch.actions', ['DeclareLaunchArgument']),
                               ('launch.substitutions', ['LaunchConfiguration']),
                               ('launch_ros', []), ('launch_ros.actions', ['Node'])):
        module = types.ModuleType(module_name)
        for name in names:
            setattr(module, name, classes[name])
        monkeypatch.setitem(sys.modules, module_name, module)
    yield classes


def describe(name: str, classes: Dict[str, type]) -> Tuple[Dict[str, Any], List[Any]]:
    """Return a launch file's arguments (name: kwargs) and nodes, built on the stand-ins."""
    spec = importlib.util.spec_from_file_location(f'dxl_launch_{name}',
                                                  ROOT / 'launch' / name)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    entities = description.args[0]
    arguments = {e.args[0]: e.kwargs for e in entities
                 if isinstance(e, classes['DeclareLaunchArgument'])}
    assert all(kwargs.get('description') for kwargs in arguments.values())
    return arguments, [e for e in entities if isinstance(e, classes['Node'])]


def _text(value: Any) -> str:
    """Return a parameter value with LaunchConfigurations written as $(name)."""
    if isinstance(value, list):
        return ''.join(_text(part) for part in value)
    if isinstance(value, _Recorded):
        return f'$({value.args[0]})'
    return str(value)


def test_teleop_launches_a_leader_and_its_follower(
        launch_classes: Dict[str, type]) -> None:
    arguments, nodes = describe('teleop.launch.py', launch_classes)
    assert arguments['leader_port']['default_value'] == 'sim'
    assert arguments['follower_port']['default_value'] == 'sim'
    assert pathlib.Path(arguments['leader_params']['default_value']).name == 'koch_leader.yaml'
    assert pathlib.Path(arguments['follower_params']['default_value']).name == (
        'koch_follower.yaml')
    leader, follower = nodes
    assert leader.kwargs['namespace'].args == ('leader_namespace',)
    assert follower.kwargs['namespace'].args == ('follower_namespace',)
    assert [_text(p) for p in leader.kwargs['parameters'][:1]] == ['$(leader_params)']
    overrides = {k: _text(v) for k, v in follower.kwargs['parameters'][1].items()}
    assert overrides == {'port': '$(follower_port)',
                         'follow.topic': '/$(leader_namespace)/joint_states'}
    assert {k: _text(v) for k, v in leader.kwargs['parameters'][1].items()} == {
        'port': '$(leader_port)'}


def test_bimanual_launches_two_pairs_each_follower_on_its_side(
        launch_classes: Dict[str, type]) -> None:
    arguments, nodes = describe('bimanual.launch.py', launch_classes)
    ports = sorted(name for name in arguments if name.endswith('_port'))
    assert ports == ['left_follower_port', 'left_leader_port', 'right_follower_port',
                     'right_leader_port']
    assert all(arguments[name]['default_value'] == 'sim' for name in ports)
    namespaces = [node.kwargs['namespace'] for node in nodes]
    assert namespaces == ['left_leader', 'left_follower', 'right_leader', 'right_follower']
    for node in nodes:
        overrides = {k: _text(v) for k, v in node.kwargs['parameters'][1].items()}
        assert overrides['port'] == f'$({node.kwargs["namespace"]}_port)'
        side, role = node.kwargs['namespace'].split('_')
        if role == 'follower':
            assert overrides['follow.topic'] == f'/{side}_leader/joint_states'
        else:
            assert 'follow.topic' not in overrides


def follow_state(msg: DiagnosticArray) -> str:
    for status in msg.status:
        for value in status.values:
            if value.key == 'follow_state':
                return str(value.value)
    return ''


@pytest.mark.parametrize('leader_file, follower_file', PAIRS)
def test_each_pair_runs_on_the_simulator(workdir: pathlib.Path, domain_id: int,
                                         leader_file: str, follower_file: str) -> None:
    context = new_context(domain_id)
    nodes: List[NodeProcess] = []
    client = None
    try:
        for name, namespace in ((leader_file, '/leader'), (follower_file, '/follower')):
            nodes.append(NodeProcess(workdir, (ROOT / 'config' / name).read_text(), namespace,
                                     domain_id))
        client = Client(context, namespace='/follower')
        deadline = time.monotonic() + WAIT_S
        while True:
            try:
                # Following: engaged at activation, its leader heard (not holding).
                client.diagnostics.wait(lambda m: follow_state(m) == 'following', 0.5)
                break
            except AssertionError:
                for node in nodes:
                    node.alive()
                assert time.monotonic() < deadline, nodes[1].output()
        for node in nodes:
            assert 'Traceback' not in node.output(), node.output()
    finally:
        if client is not None:
            client.close()
        rclpy.try_shutdown(context=context)
        for node in nodes:
            node.stop()
