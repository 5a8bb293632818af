"""
Every stop leaves torque off: the node executable stopped by signals at awkward moments.

A virtual_bus process holds the servos; the installed node runs against it; signals land during
activation, during service transactions and during the shutdown itself. After each exit every
servo's torque is read back over virtual_bus's control lines, and the node's log must not claim
what did not happen. Bad parameter files end with one line naming what was wrong.
"""

import pathlib
import re
import signal
import subprocess
import threading
import time
from typing import Any, Callable, Dict, List, Tuple

from node_harness import Client
from processes import (
    EXIT_TIMEOUT_S, fresh_domain_id, node_executable, NodeProcess, params_yaml,
    START_TIMEOUT_S, StartVirtualBus)
import pytest

MANY = 20   # servos on the bus: activation takes long enough to be hit by a signal
POLL_S = 0.002


def many_joints(count: int) -> Dict[str, Dict[str, Any]]:
    return {f'j{i}': {'id': i, 'operating_mode': 'position' if i % 2 else 'velocity'}
            for i in range(1, count + 1)}


def wait_output(node: NodeProcess, pattern: str, timeout_s: float = START_TIMEOUT_S) -> None:
    """Poll the node's output until pattern appears (AssertionError if it exits or times out)."""
    deadline = time.monotonic() + timeout_s
    while not re.search(pattern, node.output()):
        node.alive()
        assert time.monotonic() < deadline, f'no {pattern!r} within {timeout_s} s:\n' + (
            node.output())
        time.sleep(POLL_S)


def torqued(bus: Any, ids: List[int], timeout_s: float = 5.0) -> List[int]:
    """
    Return the servos still torqued once the bus has taken what the node wrote (at most timeout_s).

    The node's last writes may still be in the pty's buffer when it has exited: the console,
    served by a thread of its own, is asked again until every servo is free or time is up.
    """
    deadline = time.monotonic() + timeout_s
    while True:
        on = [sid for sid in ids if bus.get(sid, 'torque_enable') != 0]
        if not on or time.monotonic() > deadline:
            return on
        time.sleep(POLL_S)


def check_stopped(node: NodeProcess, bus: Any, ids: List[int]) -> str:
    """Check the node exits 0, without a traceback, every servo free, its log true."""
    code = node.wait(EXIT_TIMEOUT_S)
    output = node.output()
    assert code == 0, output
    assert 'Traceback' not in output, output
    assert torqued(bus, ids) == [], output
    assert 'FAILED' not in output, output
    return output


@pytest.mark.parametrize('delay_s', [0.0, 0.004, 0.015, 0.04])
def test_sigint_during_activation_leaves_every_servo_free(
        virtual_bus: StartVirtualBus, workdir: pathlib.Path, delay_s: float) -> None:
    ids = list(range(1, MANY + 1))
    bus = virtual_bus(ids, 1000000, extra_args=['--timing', 'wire'])
    node = NodeProcess(workdir, params_yaml(bus.device, many_joints(MANY)),
                       domain_id=fresh_domain_id())
    try:
        # The bus limit line is logged between configure (EEPROM) and activate (torque on).
        wait_output(node, r'bus limit for')
        time.sleep(delay_s)
        node.proc.send_signal(signal.SIGINT)
        output = check_stopped(node, bus, ids)
        # Either it stopped before anything was switched on, or it says it switched off.
        assert 'torque off' in output or 'active:' not in output, output
    finally:
        node.stop()


@pytest.mark.parametrize('delay_s', [0.0, 0.05, 0.13])
def test_sigint_while_services_use_the_bus(virtual_bus: StartVirtualBus, workdir: pathlib.Path,
                                           client: Client, domain_id: int,
                                           delay_s: float) -> None:
    ids = [1, 2, 3, 4]
    bus = virtual_bus(ids, 1000000, extra_args=['--timing', 'wire'])
    joints = many_joints(len(ids))
    node = NodeProcess(workdir, params_yaml(bus.device, joints), domain_id=domain_id)
    stop = threading.Event()
    answers: List[bool] = []

    def hammer(call: Callable[[], Any]) -> None:
        while not stop.is_set():
            try:
                answers.append(bool(call().success))
            except AssertionError:
                return   # no answer: the node is gone

    try:
        node.wait_message(client.joint_states, lambda m: len(m.name) == len(ids),
                          START_TIMEOUT_S)
        threads = [
            threading.Thread(target=hammer, daemon=True, args=(lambda: client.call(
                'read_register', timeout_s=2.0, name='j1', register_name='present_position'),)),
            threading.Thread(target=hammer, daemon=True, args=(lambda: client.call(
                'reboot', timeout_s=2.0, name=['j3']),)),
        ]
        for thread in threads:
            thread.start()
        deadline = time.monotonic() + 20.0
        while len(answers) < 5:
            assert time.monotonic() < deadline, node.output()
            time.sleep(0.01)
        time.sleep(delay_s)
        node.proc.send_signal(signal.SIGINT)
        check_stopped(node, bus, ids)
    finally:
        stop.set()
        node.stop()


@pytest.mark.parametrize('gaps_s', [(0.0,), (0.001, 0.001), (0.01, 0.02, 0.05)])
def test_repeated_signals_do_not_cut_the_torque_off(
        virtual_bus: StartVirtualBus, workdir: pathlib.Path, client: Client, domain_id: int,
        gaps_s: Tuple[float, ...]) -> None:
    ids = list(range(1, 9))
    bus = virtual_bus(ids, 1000000, extra_args=['--timing', 'wire'])
    node = NodeProcess(workdir, params_yaml(bus.device, many_joints(len(ids))),
                       domain_id=domain_id)
    try:
        node.wait_message(client.joint_states, lambda m: len(m.name) == len(ids),
                          START_TIMEOUT_S)
        node.proc.send_signal(signal.SIGINT)
        for number, gap_s in enumerate(gaps_s):
            time.sleep(gap_s)
            if node.proc.poll() is not None:
                break
            node.proc.send_signal(signal.SIGTERM if number % 2 else signal.SIGINT)
        output = check_stopped(node, bus, ids)
        assert re.search(r'stopped: torque off', output), output
    finally:
        node.stop()


@pytest.mark.parametrize('noticed', [True, False], ids=['after the node noticed', 'at once'])
def test_sigint_with_the_adapter_unplugged_exits_zero_and_says_so(
        virtual_bus: StartVirtualBus, workdir: pathlib.Path, noticed: bool) -> None:
    """The servos cannot be reached: one true line says so, and the exit is still clean."""
    ids = [1, 2, 3]
    link = workdir / 'ttyDXL'
    bus = virtual_bus(ids, 1000000, link=link)
    node = NodeProcess(workdir, params_yaml(str(link), many_joints(len(ids))),
                       domain_id=fresh_domain_id())
    try:
        wait_output(node, r'active:')
        bus.stop()   # the adapter is unplugged: its pty is gone
        if noticed:
            wait_output(node, r'reconnects when the device returns')
        node.proc.send_signal(signal.SIGINT)
        code = node.wait(EXIT_TIMEOUT_S)
        output = node.output()
        assert code == 0, output
        assert 'Traceback' not in output, output
        failed = [line for line in output.splitlines() if 'torque off FAILED' in line]
        assert len(failed) == 1, output
        assert re.search(r"stopped: torque off FAILED for 'j1', 'j2', 'j3': the port is lost",
                         failed[0]), output
    finally:
        node.stop()


# bad parameter files ---------------------------------------------------------------------

GOOD_TOP = '/**:\n  ros__parameters:\n    port: sim\n'
BAD_FILES = {
    'empty joint list': (GOOD_TOP + '    joints: []\n', r'joints'),
    'empty list elsewhere': (GOOD_TOP + '    joints: [a]\n    a:\n      id: 1\n'
                             '    extra_list: []\n', r'extra_list'),
    'syntax error': (GOOD_TOP + '    joints: [a\n', r'line \d+'),
    'tab indentation': ('/**:\n\tros__parameters:\n\t\tport: sim\n', r'tab'),
    'list at top level': ('- port: sim\n', r'top level|mapping'),
    'mixed-type list': (GOOD_TOP + '    joints: [a, 1]\n', r'joints'),
    'no ros__parameters': ('/**:\n  port: sim\n', r'ros__parameters'),
}


def one_line_exit(args: List[str], workdir: pathlib.Path) -> str:
    """Run the node with args; it must exit non-zero with exactly one error line, no trace."""
    proc = subprocess.run([node_executable(), *args], cwd=str(workdir), capture_output=True,
                          text=True, timeout=EXIT_TIMEOUT_S + START_TIMEOUT_S)
    output = proc.stdout + proc.stderr
    assert proc.returncode != 0, output
    assert 'Traceback' not in output, output
    lines = [line for line in output.splitlines() if line.strip()]
    assert len(lines) == 1, output
    return lines[0]


@pytest.mark.parametrize('case', sorted(BAD_FILES))
def test_bad_parameter_file_one_line(workdir: pathlib.Path, case: str) -> None:
    text, naming = BAD_FILES[case]
    path = workdir / 'params.yaml'
    path.write_text(text)
    line = one_line_exit(['--ros-args', '--params-file', str(path)], workdir)
    assert str(path) in line or re.search(naming, line), line
    assert re.search(naming, line, re.IGNORECASE), line


def test_missing_parameter_file_one_line(workdir: pathlib.Path) -> None:
    path = workdir / 'nowhere.yaml'
    line = one_line_exit(['--ros-args', '--params-file', str(path)], workdir)
    assert str(path) in line, line
