"""
Every command line of README.md and docs/, replayed against what `make run` runs.

Every `ros2 topic pub`, `ros2 service call` and `ros2 param set` line is taken as written and
sent through rclpy, with the same YAML payloads, to a node running config/sim.yaml; each must be
taken: a service answers success, a parameter is set, a command's goal reaches the servo's
register. Every `python examples/...` line is run as written against the installed node on
config/sim.yaml (what `make run` starts), and every sample of `make run`'s log is compared with
what that node prints.
"""

import importlib.util
import os
import pathlib
import re
import shlex
import subprocess
import sys
import tempfile
import time
from typing import Any, Dict, Iterator, List, Tuple

from dxl_servo_driver.models import modes
from dxl_servo_driver.ros.node import NODE_NAME
from node_harness import NodeHarness
from processes import fresh_domain_id, NodeProcess, START_TIMEOUT_S
import pytest
import yaml

ROOT = pathlib.Path(__file__).resolve().parents[2]
# README.md and every page of docs/: the commands are wherever the reference put them.
PAGES = [ROOT / 'README.md', *sorted((ROOT / 'docs').glob('*.md'))]
PREFIX = f'/{NODE_NAME}/'
GOAL_REGISTERS = modes.GOAL_REGISTERS
EXAMPLE = ROOT / 'examples' / 'move_and_echo.py'


def code_blocks() -> List[str]:
    """Return the code blocks of README.md and docs/, each from its tag line (```bash ...)."""
    return [block for page in PAGES for block in page.read_text().split('```')[1::2]]


def make_run_blocks() -> List[str]:
    """
    Return the code blocks about make run's node (config/sim.yaml, the root namespace).

    Code blocks that run the node on another file (a scanned robot.yaml, a namespace) are about
    that file's joints, not make run's: they are left out.
    """
    return [block for block in code_blocks() if 'robot.yaml' not in block and '__ns' not in block]


def readme_lines() -> List[List[str]]:
    """Return the ros2 pub / call / param set lines of the docs that address the default node."""
    lines = []
    for line in (line for block in make_run_blocks() for line in block.splitlines()):
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
    assert len(readme_lines()) >= 19   # fewer: lines went missing from the pages


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
    # The same goals with examples/move_and_echo.py, for ROS 2 from PyPI (no ros2 command):
    # the joint, value and kind of each ros2 line, streamed where it streams, in the node's
    # namespace (the harness's own).
    examples = h.node.what_to_try_without_ros2()
    assert len(examples) == 2
    for ros2, example in zip(lines[1:], examples):
        words = shlex.split(example)
        assert words[:2] == ['python', 'examples/move_and_echo.py'], example
        assert words[-3:] == ['--ros-args', '-r', f'__ns:={h.namespace}'], example
        args = example_module().parse_args(['move_and_echo', *words[2:]])
        payload = yaml.safe_load(shlex.split(ros2)[-1])
        assert ([args.joint], [args.value]) == (payload['name'], payload['value']), example
        assert f'/commands/{args.kind} ' in ros2, (ros2, example)
        assert (args.rate == 10.0) == (' -r 10 ' in ros2), (ros2, example)


# make run's node, as a process: its log and the example scripts. -----------------------------

LOG_STAMP = re.compile(r'^\[(?P<level>[A-Z]+)\] \[\d+\.\d+\] ')
# What varies from run to run in make run's log: the measured rate and the read counters. The
# rest (the servos, the bus limit and its bytes, the suggestions) is what the code decides.
VARYING = ((re.compile(r'measured loop rate \d+(\.\d+)? Hz'), 'measured loop rate <rate> Hz'),
           (re.compile(r'\d+ read failures, \d+ retries'), '<n> read failures, <n> retries'))
MEASURED = 'measured loop rate'
EXAMPLE_TIMEOUT_S = 60.0


def normalised(line: str) -> str:
    """Return a log line without its time stamp and with what varies between runs masked."""
    line = LOG_STAMP.sub(r'[\g<level>] ', line)
    for pattern, replacement in VARYING:
        line = pattern.sub(replacement, line)
    return line


def log_samples() -> List[List[str]]:
    """Return the samples of make run's log in the docs: blocks of [INFO] lines, `...` kept."""
    samples = []
    for block in code_blocks():
        lines = block.split('\n')[1:]   # after the tag line
        if lines and lines[0].startswith(f'[INFO] [{NODE_NAME}]: '):
            samples.append([line for line in lines if line.strip()])
    return samples


def example_lines(script: str = 'move_and_echo.py') -> List[List[str]]:
    """Return make run's blocks' `python examples/<script>` lines, as words, each once."""
    found: List[List[str]] = []
    for line in (line for block in make_run_blocks() for line in block.splitlines()):
        at = line.find(f'python examples/{script}')
        if at >= 0:
            words = shlex.split(line[at:], comments=True)
            if words not in found:
                found.append(words)
    return found


def example_module() -> Any:
    """Return examples/move_and_echo.py as a module (its parse_args reads a line's words)."""
    spec = importlib.util.spec_from_file_location('move_and_echo', EXAMPLE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class MakeRun:
    """The installed node on config/sim.yaml in a DDS domain of its own: what `make run` runs."""

    def __init__(self, workdir: pathlib.Path) -> None:
        self.domain_id = fresh_domain_id()
        self.node = NodeProcess(workdir, (ROOT / 'config' / 'sim.yaml').read_text(),
                                domain_id=self.domain_id)

    def wait_for(self, text: str, timeout_s: float) -> None:
        """Wait until the node has printed text (AssertionError with its output if it exits)."""
        deadline = time.monotonic() + timeout_s
        while text not in self.node.output():
            self.node.alive()
            assert time.monotonic() < deadline, (
                f'make run did not print {text!r} within {timeout_s} s:\n{self.node.output()}')
            time.sleep(0.1)

    def env(self) -> Dict[str, str]:
        """Return the environment of a client of this node."""
        return dict(os.environ, ROS_DOMAIN_ID=str(self.domain_id), PYTHONUNBUFFERED='1')


@pytest.fixture(scope='module')
def make_run() -> Iterator[MakeRun]:
    with tempfile.TemporaryDirectory(prefix='dxl_test_') as path:
        run = MakeRun(pathlib.Path(path))
        try:
            run.wait_for(MEASURED, START_TIMEOUT_S + 10.0)
            yield run
            run.node.alive()
        finally:
            code = run.node.stop()
        assert code == 0, run.node.output()


def test_the_docs_show_what_make_run_prints() -> None:
    assert len(log_samples()) >= 1
    assert any(MEASURED in line for sample in log_samples() for line in sample)
    assert example_lines(), 'no `python examples/move_and_echo.py` line to run'
    assert example_lines(FOLLOW), f'no `python examples/{FOLLOW}` line to run'
    scripts = {word for block in make_run_blocks() for word in block.split()
               if word.startswith('examples/') and word.endswith('.py')}
    assert scripts == {'examples/move_and_echo.py', f'examples/{FOLLOW}'}, scripts


@pytest.mark.parametrize('index', range(len(log_samples())))
def test_each_log_sample_is_what_make_run_prints(make_run: MakeRun, index: int) -> None:
    """The sample's lines are printed in its order; `...` stands for lines left out."""
    printed = [normalised(line) for line in make_run.node.output().splitlines()]
    at = 0
    for line in log_samples()[index]:
        if line.strip() == '...':
            continue
        want = normalised(line)
        assert want in printed[at:], (
            f'{line!r} is not what make run prints (after the lines before it); it printed:\n'
            + '\n'.join(printed))
        at = printed.index(want, at) + 1


@pytest.mark.parametrize('index', range(len(example_lines())))
def test_each_example_line_runs(make_run: MakeRun, index: int) -> None:
    words = example_lines()[index]
    assert words[:2] == ['python', 'examples/move_and_echo.py'], words
    args = example_module().parse_args(['move_and_echo', *words[2:]])
    refused = make_run.node.output().count('refused')
    done = subprocess.run([sys.executable, *words[1:]], cwd=str(ROOT), env=make_run.env(),
                          capture_output=True, text=True, timeout=EXAMPLE_TIMEOUT_S)
    told = f'{shlex.join(words)}:\n{done.stdout}{done.stderr}\nnode:\n{make_run.node.output()}'
    assert done.returncode == 0, told
    states = [line for line in done.stdout.splitlines() if re.match(r' *\d+\.\d+ s  ', line)]
    assert len(states) == args.count, told
    assert f'{args.joint}=' in states[-1], told
    assert make_run.node.output().count('refused') == refused, told   # the command was taken
    if args.kind == 'position':   # the joint went there
        last = re.search(rf'(?:^| ){re.escape(args.joint)}=([-+]\d+\.\d+)', states[-1])
        assert last is not None and abs(float(last.group(1)) - args.value) < 0.03, told


FOLLOW = 'follow_trajectory.py'


@pytest.mark.parametrize('index', range(len(example_lines(FOLLOW))))
def test_each_follow_trajectory_line_runs(make_run: MakeRun, index: int) -> None:
    """A FollowJointTrajectory goal as the docs send it: SUCCESSFUL, the joints where asked."""
    words = example_lines(FOLLOW)[index]
    done = subprocess.run([sys.executable, *words[1:]], cwd=str(ROOT), env=make_run.env(),
                          capture_output=True, text=True, timeout=EXAMPLE_TIMEOUT_S)
    told = f'{shlex.join(words)}:\n{done.stdout}{done.stderr}\nnode:\n{make_run.node.output()}'
    assert done.returncode == 0, told
    assert re.search(r'^result: SUCCESSFUL', done.stdout, re.M), told
    arrived = re.search(r'^arrived (.*)$', done.stdout, re.M)
    assert arrived is not None, told
    at = {name: float(value) for name, value in
          (pair.split('=') for pair in arrived.group(1).split())}
    for target in words[2:]:
        if '=' in target and not target.startswith('-'):
            name, value = target.split('=')
            assert abs(at[name] - float(value)) < 0.05, told   # the default goal_tolerance
