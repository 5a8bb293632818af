"""
End to end: the installed `node` executable against a `virtual_bus` process on a pty.

The executable is resolved as `ros2 run dxl_servo_driver node` resolves it. A client node in
this process watches joint_states and sends commands; virtual_bus's control lines (`get ID
NAME`) show what reached the servo. Every process is stopped and waited for, every file removed.
"""

import math
import os
import pathlib
import queue
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from typing import Any, Callable, Dict, Iterator, List, Optional, TypeVar

from ament_index_python.packages import get_package_prefix
from node_harness import Client, Collector, new_context
import pytest
import rclpy

ROOT = pathlib.Path(__file__).resolve().parent.parent
START_TIMEOUT_S = 20.0   # a Python + ROS process on a busy 2-core machine may start slowly
EXIT_TIMEOUT_S = 10.0
RAD_PER_PULSE = 2.0 * math.pi / 4096.0
M = TypeVar('M')


def node_executable() -> str:
    """Return the node's path the way `ros2 run` finds it: <prefix>/lib/<package>/<exe>."""
    path = os.path.join(get_package_prefix('dxl_servo_driver'), 'lib', 'dxl_servo_driver',
                        'node')
    assert os.access(path, os.X_OK), f'{path} is not an executable (colcon build first)'
    return path


def stop(proc: subprocess.Popen, timeout_s: float = 5.0) -> None:
    """SIGINT, then SIGKILL if it does not exit; always waited for."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


class VirtualBus:
    """A virtual_bus subprocess: its device, and its control lines."""

    def __init__(self, ids: List[int], link: str, baud: int = 1000000) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, '-m', 'dxl_servo_driver.sim.virtual_bus',
             '--ids', *[str(i) for i in ids], '--baud', str(baud), '--link', link],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            cwd=str(ROOT))
        self._lines: 'queue.Queue[Optional[str]]' = queue.Queue()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        try:
            self.device = self.line(START_TIMEOUT_S)
        except BaseException:
            self.close()
            raise

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self._lines.put(line.rstrip('\n'))
        self._lines.put(None)

    def line(self, timeout_s: float = 5.0) -> str:
        try:
            line = self._lines.get(timeout=timeout_s)
        except queue.Empty:
            raise AssertionError(f'virtual_bus said nothing within {timeout_s} s') from None
        assert line is not None, 'virtual_bus ended'
        return line

    def control(self, command: str) -> str:
        """Send one control line; return its one-line answer."""
        assert self.proc.stdin is not None
        self.proc.stdin.write(command + '\n')
        self.proc.stdin.flush()
        return self.line()

    def get(self, servo_id: int, register: str) -> int:
        answer = self.control(f'get {servo_id} {register}')
        match = re.fullmatch(rf'ok get {servo_id} {register}=(-?\d+)', answer)
        assert match, answer
        return int(match.group(1))

    def close(self) -> None:
        stop(self.proc)
        for stream in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            if stream is not None:
                try:
                    stream.close()
                except OSError:
                    pass
        self._reader.join(timeout=5.0)


class NodeProcess:
    """The installed node executable with a params file; its output goes to a file."""

    def __init__(self, workdir: pathlib.Path, params_yaml: str) -> None:
        self.params = workdir / 'params.yaml'
        self.params.write_text(params_yaml)
        self.output_path = workdir / 'node_output.txt'
        env = dict(os.environ)
        env['ROS_LOG_DIR'] = str(workdir / 'ros_log')   # its log files stay in workdir
        env['PYTHONUNBUFFERED'] = '1'
        with open(self.output_path, 'w') as output:
            self.proc = subprocess.Popen(
                [node_executable(), '--ros-args', '--params-file', str(self.params)],
                stdin=subprocess.DEVNULL, stdout=output, stderr=subprocess.STDOUT, env=env,
                cwd=str(workdir))

    def wait(self, timeout_s: float = START_TIMEOUT_S) -> int:
        try:
            return self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            raise AssertionError(f'the node did not exit within {timeout_s} s:\n'
                                 + self.output()) from None

    def output(self) -> str:
        return self.output_path.read_text(errors='replace')

    def wait_message(self, collector: Collector[M], predicate: Callable[[M], bool],
                     timeout_s: float) -> M:
        """Wait for a matching message while the node runs; its output if it exits."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                return collector.wait(predicate, timeout_s=0.25, fresh=False)
            except AssertionError:
                if self.proc.poll() is not None:
                    raise AssertionError(f'the node exited with {self.proc.returncode}:\n'
                                         + self.output()) from None
                if time.monotonic() > deadline:
                    raise AssertionError(f'no matching message within {timeout_s} s; node '
                                         f'output:\n{self.output()}') from None

    def close(self) -> None:
        stop(self.proc)


def params_yaml(port: str, joints: Dict[str, Dict[str, Any]], **top: Any) -> str:
    lines = ['/**:', '  ros__parameters:', f'    port: "{port}"', '    baud_rate: 1000000',
             '    loop_rate: 50.0', f'    joints: [{", ".join(joints)}]']
    lines += [f'    {key}: {value}' for key, value in top.items()]
    for name, keys in joints.items():
        lines.append(f'    {name}:')
        lines += [f'      {key}: {value}' for key, value in keys.items()]
    return '\n'.join(lines) + '\n'


@pytest.fixture
def workdir() -> Iterator[pathlib.Path]:
    with tempfile.TemporaryDirectory(prefix='dxl_e2e_') as path:
        yield pathlib.Path(path)


@pytest.fixture
def client() -> Iterator[Client]:
    context = new_context()
    try:
        client = Client(context)
    except BaseException:
        rclpy.try_shutdown(context=context)
        raise
    try:
        yield client
    finally:
        client.close()
        rclpy.try_shutdown(context=context)


JOINTS = {'j1': {'id': 1, 'operating_mode': 'position'},
          'j2': {'id': 2, 'operating_mode': 'velocity'}}


def test_node_runs_moves_a_joint_and_stops_on_sigint(workdir: pathlib.Path,
                                                     client: Client) -> None:
    link = str(workdir / 'ttyDXL')
    bus = VirtualBus([1, 2], link)
    node: Optional[NodeProcess] = None
    try:
        assert os.path.realpath(link) == bus.device
        node = NodeProcess(workdir, params_yaml(link, JOINTS))
        node.wait_message(client.joint_states, lambda m: list(m.name) == ['j1', 'j2'],
                          START_TIMEOUT_S)
        assert bus.get(1, 'torque_enable') == 1
        client.publish('position', ['j1'], [0.5])
        msg = node.wait_message(
            client.joint_states,
            lambda m: m.name[:1] == ['j1'] and abs(m.position[0] - 0.5) < 0.03, 10.0)
        assert msg.name[0] == 'j1'
        assert bus.get(1, 'goal_position') == 2048 + round(0.5 / RAD_PER_PULSE)
        # A service call over DDS to another process, answered after the write.
        response = client.call('set_velocity', name=['j2'], value=[1.0])
        assert response.success, response.message
        assert bus.get(2, 'goal_velocity') == round(1.0 / (0.229 * 2.0 * math.pi / 60.0))
        node.proc.send_signal(signal.SIGINT)
        code = node.wait(EXIT_TIMEOUT_S)
        output = node.output()
        assert code == 0, output
        assert 'Traceback' not in output, output
        # torque_off_on_shutdown (default true): both servos are free.
        assert bus.get(1, 'torque_enable') == 0
        assert bus.get(2, 'torque_enable') == 0
    finally:
        if node is not None:
            node.close()
        bus.close()
    assert not os.path.lexists(link)   # virtual_bus removed its symlink


def error_lines(output: str) -> List[str]:
    return [line for line in output.splitlines() if '[ERROR]' in line or '[FATAL]' in line]


def test_missing_servo_exits_non_zero_naming_the_id(workdir: pathlib.Path) -> None:
    link = str(workdir / 'ttyDXL')
    bus = VirtualBus([1], link)
    node: Optional[NodeProcess] = None
    try:
        joints = {'j1': {'id': 1}, 'j7': {'id': 7}}
        node = NodeProcess(workdir, params_yaml(link, joints, ping_retries=2))
        code = node.wait()
        output = node.output()
        assert code != 0, output
        assert 'Traceback' not in output, output
        naming = [line for line in error_lines(output) if re.search(r'\bid 7\b', line)]
        assert len(naming) == 1, output
        assert 'j7' in naming[0]
        assert bus.get(1, 'torque_enable') == 0   # nothing was switched on
    finally:
        if node is not None:
            node.close()
        bus.close()


def test_port_that_does_not_exist(workdir: pathlib.Path) -> None:
    port = str(workdir / 'no_such_tty')
    node = NodeProcess(workdir, params_yaml(port, JOINTS))
    try:
        code = node.wait()
        output = node.output()
        assert code != 0, output
        assert 'Traceback' not in output, output
        naming = [line for line in error_lines(output) if port in line]
        assert len(naming) == 1, output
    finally:
        node.close()


def test_invalid_configuration_exits_non_zero_naming_the_key(workdir: pathlib.Path) -> None:
    joints = {'j1': {'id': 1}, 'j2': {'id': 1}}   # duplicate id
    node = NodeProcess(workdir, params_yaml(str(workdir / 'unused'), joints))
    try:
        code = node.wait()
        output = node.output()
        assert code != 0, output
        assert 'Traceback' not in output, output
        naming = [line for line in error_lines(output) if 'j2.id' in line]
        assert len(naming) == 1, output
    finally:
        node.close()
