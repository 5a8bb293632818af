"""
End to end: the installed `node` executable against a `virtual_bus` process on a pty.

The executable is resolved as `ros2 run dxl_servo_driver node` resolves it. A client node in
this process watches joint_states and sends commands; virtual_bus's control lines (`get ID
NAME`) show what reached the servo. Every process is stopped and waited for, every file removed.
"""

import os
import pathlib
import re
import signal
from typing import List, Optional

from dxl_servo_driver.models import model_for, xm430
from dxl_servo_driver.models.units import units_for
from node_harness import Client
from processes import (
    EXIT_TIMEOUT_S, NodeProcess, params_yaml, START_TIMEOUT_S, VirtualBusProcess)

# The units of the XM430 manual's model, every joint's here (models/units.py).
UNITS = units_for(model_for(xm430.MODEL_NUMBER))
RAD_PER_PULSE = UNITS.rad_per_pulse


JOINTS = {'j1': {'id': 1, 'operating_mode': 'position'},
          'j2': {'id': 2, 'operating_mode': 'velocity'}}


def test_node_runs_moves_a_joint_and_stops_on_sigint(workdir: pathlib.Path, client: Client,
                                                     domain_id: int) -> None:
    link = str(workdir / 'ttyDXL')
    bus = VirtualBusProcess([1, 2], 1000000, link)
    node: Optional[NodeProcess] = None
    try:
        assert os.path.realpath(link) == bus.device
        node = NodeProcess(workdir, params_yaml(link, JOINTS), domain_id=domain_id)
        node.wait_message(client.joint_states, lambda m: list(m.name) == ['j1', 'j2'],
                          START_TIMEOUT_S)
        assert bus.get(1, 'torque_enable') == 1
        client.publish('position', ['j1'], [0.5])
        msg = node.wait_message(
            client.joint_states,
            lambda m: m.name[:1] == ['j1'] and abs(m.position[0] - 0.5) < 0.03, 10.0)
        assert msg.name[0] == 'j1'
        assert bus.get(1, 'goal_position') == UNITS.zero_raw + round(0.5 / RAD_PER_PULSE)
        # A service call over DDS to another process, answered after the write.
        response = client.call('set_velocity', name=['j2'], value=[1.0])
        assert response.success, response.message
        bus.wait_get(2, 'goal_velocity', round(1.0 / UNITS.rad_s_per_velocity_raw))
        node.proc.send_signal(signal.SIGINT)
        code = node.wait(EXIT_TIMEOUT_S)
        output = node.output()
        assert code == 0, output
        assert 'Traceback' not in output, output
        # torque_off_on_shutdown (default true): both servos are free.
        bus.wait_get(1, 'torque_enable', 0)
        bus.wait_get(2, 'torque_enable', 0)
    finally:
        if node is not None:
            node.stop()
        bus.stop()
    assert not bus.left_link
    assert not os.path.lexists(link)   # virtual_bus removed its symlink


def error_lines(output: str) -> List[str]:
    return [line for line in output.splitlines() if '[ERROR]' in line or '[FATAL]' in line]


def test_missing_servo_exits_non_zero_naming_the_id(workdir: pathlib.Path) -> None:
    link = str(workdir / 'ttyDXL')
    bus = VirtualBusProcess([1], 1000000, link)
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
            node.stop()
        bus.stop()


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
        node.stop()


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
        node.stop()
