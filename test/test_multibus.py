"""
Two buses, two nodes: the README's form, with the installed executables in namespaces.

Two `virtual_bus` processes on two pseudo-terminals (different ids and baud rates) and two `node`
processes (`--ros-args -r __ns:=/left` and `/right`, each with its params file). A client in this
process checks that each namespace publishes its own joints and that a command to one namespace
reaches only that bus (seen through virtual_bus's `get ID NAME` control line). Every process is
stopped with SIGINT and waited for; every file is removed.
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
from typing import Any, Dict, Iterator, List, Optional

from ament_index_python.packages import get_package_prefix
from node_harness import Client, new_context
import pytest
import rclpy

ROOT = pathlib.Path(__file__).resolve().parent.parent
START_TIMEOUT_S = 30.0   # two Python + ROS processes start side by side on 2 busy cores
EXIT_TIMEOUT_S = 10.0
RAD_PER_PULSE = 2.0 * math.pi / 4096.0


def node_executable() -> str:
    """Return the node's path the way `ros2 run` finds it: <prefix>/lib/<package>/<exe>."""
    path = os.path.join(get_package_prefix('dxl_servo_driver'), 'lib', 'dxl_servo_driver',
                        'node')
    assert os.access(path, os.X_OK), f'{path} is not an executable (colcon build first)'
    return path


def stop(proc: 'subprocess.Popen[Any]', timeout_s: float = EXIT_TIMEOUT_S) -> Optional[int]:
    """SIGINT and wait; SIGKILL if it does not exit. Return the exit code of the SIGINT."""
    if proc.poll() is not None:
        return proc.returncode
    proc.send_signal(signal.SIGINT)
    try:
        return proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        return None


class Bus:
    """A virtual_bus process: its device and its control lines."""

    def __init__(self, ids: List[int], baud: int, link: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, '-m', 'dxl_servo_driver.sim.virtual_bus', '--ids',
             *[str(i) for i in ids], '--baud', str(baud), '--link', link],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
            text=True, cwd=str(ROOT))
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

    def get(self, servo_id: int, register: str) -> int:
        assert self.proc.stdin is not None
        self.proc.stdin.write(f'get {servo_id} {register}\n')
        self.proc.stdin.flush()
        answer = self.line()
        match = re.fullmatch(rf'ok get {servo_id} {register}=(-?\d+)', answer)
        assert match, answer
        return int(match.group(1))

    def close(self) -> None:
        stop(self.proc)
        for stream in (self.proc.stdin, self.proc.stdout):
            if stream is not None:
                try:
                    stream.close()
                except OSError:
                    pass
        self._reader.join(timeout=5.0)


class Node:
    """The installed node executable in a namespace, with its own params file and output."""

    def __init__(self, workdir: pathlib.Path, namespace: str, params_yaml: str) -> None:
        tag = namespace.strip('/')
        params = workdir / f'{tag}.yaml'
        params.write_text(params_yaml)
        self.output_path = workdir / f'{tag}_output.txt'
        env = dict(os.environ)
        env['ROS_LOG_DIR'] = str(workdir / f'{tag}_ros_log')
        env['PYTHONUNBUFFERED'] = '1'
        with open(self.output_path, 'w') as output:
            self.proc = subprocess.Popen(
                [node_executable(), '--ros-args', '-r', f'__ns:={namespace}', '--params-file',
                 str(params)],
                stdin=subprocess.DEVNULL, stdout=output, stderr=subprocess.STDOUT, env=env,
                cwd=str(workdir))

    def output(self) -> str:
        return self.output_path.read_text(errors='replace')

    def alive(self) -> None:
        assert self.proc.poll() is None, (
            f'the node exited with {self.proc.returncode}:\n{self.output()}')


def params_yaml(port: str, baud: int, joints: Dict[str, int]) -> str:
    lines = ['/**:', '  ros__parameters:', f'    port: "{port}"', f'    baud_rate: {baud}',
             '    loop_rate: 50.0', f'    joints: [{", ".join(joints)}]']
    for name, servo_id in joints.items():
        lines += [f'    {name}:', f'      id: {servo_id}', '      operating_mode: position']
    return '\n'.join(lines) + '\n'


@pytest.fixture
def workdir() -> Iterator[pathlib.Path]:
    with tempfile.TemporaryDirectory(prefix='dxl_multibus_') as path:
        yield pathlib.Path(path)


LEFT = {'l_shoulder': 1, 'l_elbow': 2}
RIGHT = {'r_shoulder': 11}


def test_two_buses_two_namespaces(workdir: pathlib.Path) -> None:
    buses: List[Bus] = []
    nodes: List[Node] = []
    clients: List[Client] = []
    context = new_context()
    try:
        left_bus = Bus(list(LEFT.values()), 1000000, str(workdir / 'ttyLEFT'))
        buses.append(left_bus)
        right_bus = Bus(list(RIGHT.values()), 115200, str(workdir / 'ttyRIGHT'))
        buses.append(right_bus)
        left = Node(workdir, '/left', params_yaml(str(workdir / 'ttyLEFT'), 1000000, LEFT))
        nodes.append(left)
        right = Node(workdir, '/right',
                     params_yaml(str(workdir / 'ttyRIGHT'), 115200, RIGHT))
        nodes.append(right)
        left_client = Client(context, namespace='/left')
        clients.append(left_client)
        right_client = Client(context, namespace='/right')
        clients.append(right_client)

        deadline = time.monotonic() + START_TIMEOUT_S
        for client, joints, node in ((left_client, LEFT, left), (right_client, RIGHT, right)):
            while True:
                node.alive()
                try:
                    msg = client.joint_states.wait(
                        lambda m: len(m.name) == len(joints), timeout_s=0.5, fresh=False)
                    break
                except AssertionError:
                    assert time.monotonic() < deadline, f'no joint_states:\n{node.output()}'
            assert list(msg.name) == list(joints)
        # Each namespace publishes only its own joints.
        for client, joints in ((left_client, LEFT), (right_client, RIGHT)):
            for msg in [client.joint_states.wait(timeout_s=5.0) for _ in range(5)]:
                assert set(msg.name) <= set(joints), msg.name

        right_goal = right_bus.get(11, 'goal_position')
        left_client.publish('position', ['l_elbow'], [0.6])
        left_client.joint_states.wait(
            lambda m: abs(m.position[m.name.index('l_elbow')] - 0.6) < 0.03
            if 'l_elbow' in m.name else False, timeout_s=10.0)
        assert left_bus.get(2, 'goal_position') == 2048 + round(0.6 / RAD_PER_PULSE)
        # A right joint named on the left is unknown there: refused, nothing moves.
        left_client.publish('position', ['r_shoulder'], [1.0])
        response = left_client.call('set_position', name=['r_shoulder'], value=[1.0])
        assert not response.success and 'r_shoulder' in response.message
        right_client.joint_states.wait(timeout_s=5.0)
        assert right_bus.get(11, 'goal_position') == right_goal
        # And the right node obeys its own namespace.
        response = right_client.call('set_position', name=['r_shoulder'], value=[-0.4])
        assert response.success, response.message
        assert right_bus.get(11, 'goal_position') == 2048 + round(-0.4 / RAD_PER_PULSE)
        assert left_bus.get(2, 'goal_position') == 2048 + round(0.6 / RAD_PER_PULSE)

        for node in nodes:
            node.alive()
            node.proc.send_signal(signal.SIGINT)
        for node in nodes:
            try:
                code = node.proc.wait(EXIT_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                raise AssertionError(f'no exit after SIGINT:\n{node.output()}') from None
            assert code == 0, node.output()
            assert 'Traceback' not in node.output(), node.output()
        assert left_bus.get(1, 'torque_enable') == 0 and right_bus.get(11, 'torque_enable') == 0
    finally:
        for client in clients:
            client.close()
        rclpy.try_shutdown(context=context)
        for node in nodes:
            stop(node.proc)
        for bus in buses:
            bus.close()
    assert not os.path.lexists(workdir / 'ttyLEFT')
    assert not os.path.lexists(workdir / 'ttyRIGHT')
