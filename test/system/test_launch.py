"""The launch file (compiled, inspected, run against stand-ins for launch) and the udev rule."""

import ast
import importlib.util
import pathlib
import py_compile
import re
import sys
import types
from typing import Any, Dict, List, Tuple

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
LAUNCH_FILE = ROOT / 'launch' / 'dxl_servo_driver.launch.py'
UDEV_FILE = ROOT / 'udev' / '99-dxl-servo-driver.rules'


def _call_name(call: ast.Call) -> str:
    func = call.func
    if isinstance(func, ast.Attribute):
        return func.attr
    return func.id if isinstance(func, ast.Name) else ''


def _calls(tree: ast.AST, name: str) -> List[ast.Call]:
    return [node for node in ast.walk(tree)
            if isinstance(node, ast.Call) and _call_name(node) == name]


def test_the_launch_file_compiles(tmp_path: pathlib.Path) -> None:
    py_compile.compile(str(LAUNCH_FILE), cfile=str(tmp_path / 'launch.pyc'), doraise=True)


def test_the_launch_file_declares_both_arguments_and_the_node() -> None:
    tree = ast.parse(LAUNCH_FILE.read_text(), filename=str(LAUNCH_FILE))
    functions = [node.name for node in tree.body if isinstance(node, ast.FunctionDef)]
    assert 'generate_launch_description' in functions
    declared = [call.args[0].value for call in _calls(tree, 'DeclareLaunchArgument')
                if call.args and isinstance(call.args[0], ast.Constant)]
    assert sorted(declared) == ['namespace', 'params_file']
    nodes = _calls(tree, 'Node')
    assert len(nodes) == 1
    keywords = {kw.arg: kw.value for kw in nodes[0].keywords}
    assert {k: v.value for k, v in keywords.items() if isinstance(v, ast.Constant)} == {
        'package': 'dxl_servo_driver', 'executable': 'node', 'output': 'screen',
        'emulate_tty': True}
    assert {'namespace', 'parameters'} <= set(keywords)


class _Recorded:
    """A stand-in for a launch class: remembers how it was built."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args = args
        self.kwargs = kwargs


def _stand_ins() -> Tuple[Dict[str, types.ModuleType], Dict[str, type]]:
    classes = {name: type(name, (_Recorded,), {}) for name in (
        'LaunchDescription', 'DeclareLaunchArgument', 'LaunchConfiguration', 'Node')}
    modules = {
        'launch': {'LaunchDescription'}, 'launch.actions': {'DeclareLaunchArgument'},
        'launch.substitutions': {'LaunchConfiguration'}, 'launch_ros': set(),
        'launch_ros.actions': {'Node'},
    }
    built = {}
    for module_name, names in modules.items():
        module = types.ModuleType(module_name)
        for name in names:
            setattr(module, name, classes[name])
        built[module_name] = module
    return built, classes


def test_the_launch_description_wires_the_arguments_into_the_node(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # launch and launch_ros are not installable here: stand-ins record what the file builds.
    pytest.importorskip('ament_index_python')
    modules, classes = _stand_ins()
    for name, module in modules.items():
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location('dxl_launch_under_test', LAUNCH_FILE)
    assert spec is not None and spec.loader is not None
    launch_module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(launch_module)
    description = launch_module.generate_launch_description()
    assert isinstance(description, classes['LaunchDescription'])
    entities = description.args[0]
    arguments = {e.args[0]: e.kwargs for e in entities
                 if isinstance(e, classes['DeclareLaunchArgument'])}
    assert arguments['namespace']['default_value'] == ''
    default_params = pathlib.Path(arguments['params_file']['default_value'])
    assert default_params.parts[-3:] == ('dxl_servo_driver', 'config', 'sim.yaml')
    assert default_params.is_file(), 'the default parameter file is not installed'
    assert all(kwargs.get('description') for kwargs in arguments.values())
    (node,) = [e for e in entities if isinstance(e, classes['Node'])]
    assert node.kwargs['namespace'].args == ('namespace',)
    assert [p.args for p in node.kwargs['parameters']] == [('params_file',)]


def _rules() -> List[str]:
    return [line.strip() for line in UDEV_FILE.read_text().splitlines()
            if line.strip() and not line.lstrip().startswith('#')]


def test_the_udev_rule_names_the_u2d2_and_sets_the_latency_timer() -> None:
    rules = _rules()
    assert rules, 'no rule lines'
    for rule in rules:
        assert 'ATTRS{idVendor}=="0403"' in rule and 'ATTRS{idProduct}=="6014"' in rule
        # Every key is KEY{attr}op"value" (udev syntax), separated by commas.
        for key in rule.split(', '):
            assert re.fullmatch(r'[A-Z_]+(\{[a-z_/A-Z]+\})?(==|!=|\+=|=)"[^"]*"', key), key
    naming = [rule for rule in rules if 'SYMLINK+="ttyDXL"' in rule]
    assert len(naming) == 1
    assert 'MODE="0666"' in naming[0] or 'GROUP="dialout"' in naming[0]
    assert any('ATTR{device/latency_timer}="1"' in rule for rule in rules)


def test_the_udev_rule_says_how_to_install_and_check_it() -> None:
    text = UDEV_FILE.read_text()
    assert 'sudo cp udev/99-dxl-servo-driver.rules /etc/udev/rules.d/' in text
    assert 'sudo udevadm control --reload && sudo udevadm trigger' in text
    assert 'cat /sys/bus/usb-serial/devices/ttyUSB0/latency_timer' in text


def test_setup_installs_the_launch_file_and_the_rule() -> None:
    setup = (ROOT / 'setup.py').read_text()
    assert "glob('launch/*.launch.py')" in setup and "glob('udev/*.rules')" in setup
