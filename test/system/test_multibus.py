"""
Two buses, two nodes: the README's form, with the installed executables in namespaces.

Two `virtual_bus` processes on two pseudo-terminals (different ids and baud rates) and two `node`
processes (`--ros-args -r __ns:=/left` and `/right`, each with its params file). A client in this
process checks that each namespace publishes its own joints and that a command to one namespace
reaches only that bus (seen through virtual_bus's `get ID NAME` control line). Every node is
stopped with SIGINT, every process is waited for; every file is removed.
"""

import os
import pathlib
import signal
import time
from typing import Dict, List

from dxl_servo_driver.models import model_for, xm430
from dxl_servo_driver.models.units import units_for
from node_harness import Client, new_context
from processes import (
    EXIT_TIMEOUT_S, fresh_domain_id, NodeProcess, params_yaml, START_TIMEOUT_S,
    VirtualBusProcess)
import rclpy

# The units of the XM430 manual's model, every joint's here (models/units.py).
UNITS = units_for(model_for(xm430.MODEL_NUMBER))
RAD_PER_PULSE = UNITS.rad_per_pulse


def joint_params(joints: Dict[str, int]) -> Dict[str, Dict[str, object]]:
    """Return params_yaml's joints: each name with its id, in position mode."""
    return {name: {'id': servo_id, 'operating_mode': 'position'}
            for name, servo_id in joints.items()}


LEFT = {'l_shoulder': 1, 'l_elbow': 2}
RIGHT = {'r_shoulder': 11}


def test_two_buses_two_namespaces(workdir: pathlib.Path) -> None:
    buses: List[VirtualBusProcess] = []
    nodes: List[NodeProcess] = []
    clients: List[Client] = []
    domain_id = fresh_domain_id()
    context = new_context(domain_id)
    try:
        left_bus = VirtualBusProcess(list(LEFT.values()), 1000000, workdir / 'ttyLEFT')
        buses.append(left_bus)
        right_bus = VirtualBusProcess(list(RIGHT.values()), 115200, workdir / 'ttyRIGHT')
        buses.append(right_bus)
        left = NodeProcess(workdir, params_yaml(str(workdir / 'ttyLEFT'), joint_params(LEFT),
                                                baud_rate=1000000), '/left', domain_id)
        nodes.append(left)
        right = NodeProcess(workdir, params_yaml(str(workdir / 'ttyRIGHT'), joint_params(RIGHT),
                                                 baud_rate=115200), '/right', domain_id)
        nodes.append(right)
        left_client = Client(context, namespace='/left')
        clients.append(left_client)
        right_client = Client(context, namespace='/right')
        clients.append(right_client)

        deadline = time.monotonic() + START_TIMEOUT_S   # for both: they start side by side
        for client, joints, node in ((left_client, LEFT, left), (right_client, RIGHT, right)):
            msg = node.wait_message(client.joint_states, lambda m: len(m.name) == len(joints),
                                    deadline - time.monotonic())
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
        assert left_bus.get(2, 'goal_position') == UNITS.zero_raw + round(0.6 / RAD_PER_PULSE)
        # A right joint named on the left is unknown there: refused, nothing moves.
        left_client.publish('position', ['r_shoulder'], [1.0])
        response = left_client.call('set_position', name=['r_shoulder'], value=[1.0])
        assert not response.success and 'r_shoulder' in response.message
        right_client.joint_states.wait(timeout_s=5.0)
        assert right_bus.get(11, 'goal_position') == right_goal
        # And the right node obeys its own namespace.
        response = right_client.call('set_position', name=['r_shoulder'], value=[-0.4])
        assert response.success, response.message
        right_bus.wait_get(11, 'goal_position', UNITS.zero_raw + round(-0.4 / RAD_PER_PULSE))
        assert left_bus.get(2, 'goal_position') == UNITS.zero_raw + round(0.6 / RAD_PER_PULSE)

        for node in nodes:
            node.alive()
            node.proc.send_signal(signal.SIGINT)
        for node in nodes:
            code = node.wait(EXIT_TIMEOUT_S)
            assert code == 0, node.output()
            assert 'Traceback' not in node.output(), node.output()
        left_bus.wait_get(1, 'torque_enable', 0)
        right_bus.wait_get(11, 'torque_enable', 0)
    finally:
        for client in clients:
            client.close()
        rclpy.try_shutdown(context=context)
        for node in nodes:
            node.stop()
        for bus in buses:
            bus.stop()
    assert not any(bus.left_link for bus in buses)
    assert not os.path.lexists(workdir / 'ttyLEFT')
    assert not os.path.lexists(workdir / 'ttyRIGHT')
