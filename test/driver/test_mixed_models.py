"""
A mixed bus of X-series models, each driven with its own table and units.

XM430-W350 (1020), XM430-W210 (1030), XL430-W250 (1060), XM540-W270 (1120), XL330-M288 (1200).

In process (`port: sim`, `<joint>.model`): every joint goes through every mode its model has,
with a goal in SI units checked against the register in the model's unit. As a user would:
the installed node configured from a file on `virtual_bus --models`, moving and reporting in SI.
"""

import math
import pathlib
from types import SimpleNamespace
from typing import Any, Dict, Optional

from dxl_servo_driver.models import model_for
from dxl_servo_driver.models.units import units_for
from dxl_servo_driver.ros.messages import JointTable
from node_harness import Client, NodeHarness, sim_params
from processes import NodeProcess, params_yaml, START_TIMEOUT_S
from processes import VirtualBusProcess
import pytest

MODELS = {'w350': 1020, 'w210': 1030, 'xl430': 1060, 'xm540': 1120, 'xl330': 1200}
JOINTS = {name: {'id': index, 'model': number, 'operating_mode': 'velocity'}
          for index, (name, number) in enumerate(MODELS.items(), start=1)}
IDS = {name: keys['id'] for name, keys in JOINTS.items()}
# A goal per mode, in SI, modest for every model (the XL330's 1 mA unit and the others').
GOALS = {'position': ('position', 0.4), 'extended_position': ('position', 7.0),
         'current_based_position': ('position', -0.3), 'velocity': ('velocity', 1.2),
         'current': ('current', 0.15), 'pwm': ('pwm', -0.2)}
REGISTERS = {'position': 'goal_position', 'velocity': 'goal_velocity', 'current': 'goal_current',
             'pwm': 'goal_pwm'}


@pytest.fixture(scope='module')
def h() -> Any:
    with NodeHarness(sim_params(JOINTS)) as harness:
        harness.joint_states.wait(lambda m: len(m.name) == len(JOINTS))
        yield harness


def test_each_servo_is_driven_with_its_own_model(h: NodeHarness) -> None:
    assert h.node is not None
    for name, number in MODELS.items():
        servo = h.node.manager.servos[name]
        assert servo.model.number == number
        assert h.sim.model(IDS[name]).number == number
    states = h.servo_states.wait(lambda m: all(s.model for s in m.servos))
    assert {s.name: s.model for s in states.servos} == {
        'w350': 'XM430-W350', 'w210': 'XM430-W210', 'xl430': 'XL430-W250',
        'xm540': 'XM540-W270', 'xl330': 'XL330-M288'}


@pytest.mark.parametrize('name', sorted(MODELS))
def test_every_mode_of_every_model_takes_goals_in_si(h: NodeHarness, name: str) -> None:
    table = model_for(MODELS[name])
    units = units_for(table)
    modes = list(table.modes)
    for mode in modes:
        response = h.call('set_operating_mode', name=[name], mode=mode)
        assert response.success, (name, mode, response.message)
        assert h.reg(IDS[name], 'operating_mode') == table.modes[mode]
        kind, value = GOALS[mode]
        response = h.call(f'set_{kind}', name=[name], value=[value])
        assert response.success, (name, mode, response.message)
        servo = h.node.manager.servos[name] if h.node else None
        assert servo is not None
        offset = servo.turn_offset if kind == 'position' else 0
        raw = units.kinds[kind].to_raw(value) - offset
        assert h.reg(IDS[name], REGISTERS[kind]) == raw, (name, mode)
    # A model without current sensing refuses the current modes and goals by name.
    if 'current' not in table.modes:
        response = h.call('set_operating_mode', name=[name], mode='current')
        assert not response.success and 'has no current mode' in response.message
        response = h.call('set_current', name=[name], value=[0.1])
        assert not response.success and 'no goal_current register' in response.message
    # Back to velocity for the next tests.
    assert h.call('set_operating_mode', name=[name], mode='velocity').success


def test_units_follow_each_model(h: NodeHarness) -> None:
    # The same 1.0 rad/s on every joint: the same raw velocity (0.229 rpm units on all X);
    # effort from current (XM) or from Present Load (XL430); current in 1 mA on the XL330.
    for name in MODELS:
        assert h.call('set_operating_mode', name=[name], mode='velocity').success
    assert h.call('set_velocity', name=list(MODELS), value=[1.0] * len(MODELS)).success
    msg = h.joint_states.wait(
        lambda m: len(m.name) == len(MODELS) and all(abs(v - 1.0) < 0.1 for v in m.velocity),
        timeout_s=15.0)
    assert msg.name == list(MODELS)
    assert h.node is not None
    for name, number in MODELS.items():
        table = model_for(number)
        servo = h.node.manager.servos[name]
        state = servo.state   # one sample, as the cycle decoded it
        assert state is not None
        # What joint_states publishes from that sample (the node's own table).
        one = SimpleNamespace(name=name, units=servo.units, state=state, fresh=True,
                              turn_offset=servo.turn_offset)
        published = JointTable([one]).fill(None)
        if table.current_unit_a is not None:
            # Current (2.69 mA, or 1 mA on the XL330) times the datasheet torque constant.
            scale = table.current_unit_a * table.torque_constant_nm_per_a
        else:
            # Present Load: 0.1 % of the stall torque.
            scale = 0.001 * table.stall_torque_nm
        assert math.isclose(published.effort[0], state[2] * scale, rel_tol=1e-9), name
        assert math.isclose(published.velocity[0], state[1] * 0.229 * 2 * math.pi / 60)
    states = h.servo_states.wait(lambda m: all(not math.isnan(s.velocity) for s in m.servos))
    by_name = {s.name: s for s in states.servos}
    assert math.isnan(by_name['xl430'].current)          # no current sensing
    assert not math.isnan(by_name['xl330'].current)
    assert h.call('set_velocity', name=list(MODELS), value=[0.0] * len(MODELS)).success


def test_a_file_and_virtual_bus_with_models_as_a_user_would(
        workdir: pathlib.Path, client: Client, domain_id: int) -> None:
    link = str(workdir / 'ttyDXL')
    ids = [keys['id'] for keys in JOINTS.values()]
    bus = VirtualBusProcess(ids, 1000000, link,
                            extra_args=['--models', *[str(n) for n in MODELS.values()]])
    node: Optional[NodeProcess] = None
    joints: Dict[str, Dict[str, Any]] = {
        'w350': {'id': 1, 'operating_mode': 'position'},
        'w210': {'id': 2, 'operating_mode': 'current_based_position'},
        'xl430': {'id': 3, 'operating_mode': 'extended_position', 'model': 'XL430-W250'},
        'xm540': {'id': 4, 'operating_mode': 'current'},
        'xl330': {'id': 5, 'operating_mode': 'velocity', 'model': 'XL330-M288'},
    }
    try:
        node = NodeProcess(workdir, params_yaml(link, joints), domain_id=domain_id)
        node.wait_message(client.joint_states, lambda m: len(m.name) == 5, START_TIMEOUT_S)
        output = node.output()
        for name in ('XM430-W350 (model 1020)', 'XL430-W250 (model 1060)',
                     'XM540-W270 (model 1120)', 'XL330-M288 (model 1200)'):
            assert name in output, output
        client.publish('position', ['w350', 'xl430'], [0.5, 9.0])
        client.publish('current', ['xm540'], [0.2])
        client.publish('velocity', ['xl330'], [2.0])
        msg = node.wait_message(
            client.joint_states,
            lambda m: abs(m.position[0] - 0.5) < 0.05 and abs(m.position[2] - 9.0) < 0.1
            and abs(m.velocity[4] - 2.0) < 0.2, 20.0)
        assert msg.name == list(joints)
        assert bus.get(4, 'goal_current') == round(0.2 / 2.69e-3)
        assert bus.get(5, 'goal_velocity') == round(2.0 / (0.229 * 2 * math.pi / 60))
        assert node.stop() == 0, node.output()
        for servo_id in ids:
            bus.wait_get(servo_id, 'torque_enable', 0)
    finally:
        if node is not None:
            node.stop()
        bus.stop()
