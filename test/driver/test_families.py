"""
One servo of every family beyond the X series, each driven with its own table and units.

In process (`port: sim`, `<joint>.model`): configure, every mode the model has driven with a
goal in SI and checked in the register's own unit, the state published in SI, and torque off
at exit. The X series has the same in test_mixed_models.py.
"""

import math
import struct
from typing import Any, Dict

from dxl_servo_driver.config import validate
from dxl_servo_driver.driver.manager import Manager
from dxl_servo_driver.driver.transports import SimTransport
from dxl_servo_driver.models import model_for
from dxl_servo_driver.models.base import TORQUE_MODE
from dxl_servo_driver.models.units import units_for
from dxl_servo_driver.protocol import Instruction
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.port import SimPortHandler
from dxl_servo_driver.sim.virtual_bus import configure_servos
from manager_rig import TapPort
from node_harness import NodeHarness, sim_params
import pytest

# joint name -> model number: one of each family (and both MX(2.0) tables: with and without
# current sensing; the L42-10-S300-R beside the H54: its own units and modes).
MODELS: Dict[str, int] = {'mx28': 30, 'mx64': 311, 'mx106': 321, 'ph54': 2020, 'h42a': 51201,
                          'gripper': 35074, 'h54': 54024, 'l42': 35072, 'ym070': 4000,
                          'xl320': 350, 'ax12': 12, 'rx28': 28, 'ex106': 107, 'dx117': 117,
                          'mx28_1': 29, 'mx64_1': 310, 'x_on_1': 1020}
# Joints whose servo speaks Protocol 1.0: an X servo switched by its Protocol Version says so;
# a 1.0-only model (AX, RX, EX, DX, MX on 1.0 firmware) is on 1.0 by its `model`.
PROTOCOLS = {'x_on_1': 1.0}
# Each joint rests in velocity mode, or current, or position mode: the first its model has.
HOME = {name: next(mode for mode in ('velocity', 'current', 'position')
                   if mode in model_for(number).modes)
        for name, number in MODELS.items()}
JOINTS = {name: {'id': index, 'model': number, 'operating_mode': HOME[name],
                 **({'protocol': PROTOCOLS[name]} if name in PROTOCOLS else {})}
          for index, (name, number) in enumerate(MODELS.items(), start=1)}
IDS = {name: keys['id'] for name, keys in JOINTS.items()}
# A goal per mode in SI, modest for every model.
GOALS = {'position': ('position', 0.4), 'extended_position': ('position', 7.0),
         'current_based_position': ('position', -0.3), 'velocity': ('velocity', 1.2),
         'current': ('current', 0.15), 'pwm': ('pwm', -0.2)}
# The gripper's finger drive travels 0 (open) .. 1,150 pulses of 4,096 a turn: 0..1.76 rad.
GRIPPER_GOALS = {'current_based_position': ('position', 0.5)}


@pytest.fixture(scope='module')
def h() -> Any:
    with NodeHarness(sim_params(JOINTS)) as harness:
        harness.joint_states.wait(lambda m: len(m.name) == len(JOINTS))
        yield harness


def test_each_servo_is_configured_with_its_own_model(h: NodeHarness) -> None:
    assert h.node is not None
    for name, number in MODELS.items():
        assert h.node.manager.servos[name].model.number == number
        assert h.sim.model(IDS[name]).number == number
    states = h.servo_states.wait(lambda m: all(s.model for s in m.servos))
    assert {s.name: s.model for s in states.servos} == {
        name: model_for(number).name for name, number in MODELS.items()}


@pytest.mark.parametrize('name', sorted(MODELS))
def test_every_mode_takes_goals_in_si_written_in_the_model_s_unit(
        h: NodeHarness, name: str) -> None:
    table = model_for(MODELS[name])
    units = units_for(table)
    for mode in table.modes:
        response = h.call('set_operating_mode', name=[name], mode=mode)
        assert response.success, (name, mode, response.message)
        if table.mode_register:
            assert h.reg(IDS[name], table.mode_register) == table.modes[mode]
        else:   # a Protocol 1.0 table: its angle limits (and torque control) say the mode
            torque = h.reg(IDS[name], TORQUE_MODE) if table.has(TORQUE_MODE) else 0
            assert table.angle_limit_mode(h.reg(IDS[name], 'min_position_limit'),
                                          h.reg(IDS[name], 'max_position_limit'),
                                          torque) == mode
        kind, value = (GRIPPER_GOALS if name == 'gripper' else GOALS).get(mode, GOALS[mode])
        response = h.call(f'set_{kind}', name=[name], value=[value])
        assert response.success, (name, mode, response.message)
        assert h.node is not None
        servo = h.node.manager.servos[name]
        offset = servo.turn_offset if kind == 'position' else 0
        register = units.kinds[kind].register
        assert h.reg(IDS[name], register) == units.kinds[kind].to_raw(value) - offset, \
            (name, mode)
    if 'current' not in table.modes:
        response = h.call('set_operating_mode', name=[name], mode='current')
        assert not response.success and 'has no current mode' in response.message
    assert h.call('set_operating_mode', name=[name], mode=HOME[name]).success


def test_state_is_published_in_si(h: NodeHarness) -> None:
    names = [name for name in MODELS if HOME[name] == 'velocity']
    everyone = list(MODELS)
    for name in names:
        assert h.call('set_operating_mode', name=[name], mode='velocity').success
    assert h.call('set_velocity', name=names, value=[1.0] * len(names)).success
    msg = h.joint_states.wait(
        lambda m: m.name == everyone
        and all(abs(m.velocity[everyone.index(n)] - 1.0) < 0.1 for n in names),
        timeout_s=15.0)
    assert h.node is not None
    assert msg is not None
    for name in names:
        servo = h.node.manager.servos[name]
        table = model_for(MODELS[name])
        rad_s_per_raw = table.velocity_unit_rpm * 2 * math.pi / 60
        # The goal went out in the model's own unit (a register that does not wander, unlike
        # Present Velocity: comparing that with a message of another moment was a race), and
        # the published value, in SI, is that velocity (waited for above).
        item = table.item('goal_velocity')   # the AX's Moving Speed: a direction bit
        stored = h.reg(IDS[name], item.name) & ((1 << 8 * item.size) - 1)
        raw = item.decode(stored.to_bytes(item.size, 'little'))
        assert abs(raw * rad_s_per_raw - 1.0) <= rad_s_per_raw / 2 + 1e-9, (name, raw)
        assert servo.units.rad_s_per_velocity_raw == pytest.approx(rad_s_per_raw)
    assert h.call('set_velocity', name=names, value=[0.0] * len(names)).success


def test_torque_is_off_at_exit() -> None:
    harness = NodeHarness(sim_params(JOINTS))
    try:
        harness.joint_states.wait(lambda m: len(m.name) == len(JOINTS))
        assert all(harness.reg(servo_id, 'torque_enable') == 1 for servo_id in IDS.values())
    finally:
        harness.close()
    assert all(harness.sim.servo(servo_id).memory.get('torque_enable') == 0
               for servo_id in IDS.values())


@pytest.mark.parametrize('name', sorted(MODELS))
def test_a_servo_that_lost_its_power_is_found_and_restored(h: NodeHarness, name: str) -> None:
    # The X's indirect map is gone after a power cut (its canary reads 0); the P, PRO(A) and
    # Y keep theirs in EEPROM and the XL-320 and Protocol 1.0 tables have none: their torque
    # went off with no error to say why.
    assert h.node is not None
    servo = h.node.manager.servos[name]
    before = servo.restarts
    h.wait_reg(IDS[name], 'torque_enable', lambda value: value == 1)
    h.sim.powercycle(IDS[name])
    h.wait_reg(IDS[name], 'torque_enable', lambda value: value == 1, timeout_s=15.0)
    assert servo.restarts == before + 1
    h.joint_states.wait(lambda m: name in m.name, timeout_s=10.0)


@pytest.mark.parametrize('name, register, reason', [
    ('mx64', 'protocol_version', 'would stop answering'),
    ('ym070', 'protocol_type', 'would stop answering'),    # the Y's name for it
    ('ax12', 'cw_angle_limit', 'is the mode of the AX-12A'),
    ('xl320', 'control_mode', 'managed by the driver'),
])
def test_what_would_take_a_servo_off_the_bus_or_its_mode_is_refused(
        h: NodeHarness, name: str, register: str, reason: str) -> None:
    before = h.reg(IDS[name], register)
    response = h.call('write_register', name=name, register_name=register, value=1)
    assert not response.success and reason in response.message, response.message
    assert h.reg(IDS[name], register) == before


@pytest.mark.parametrize('read_mode, instruction', [('sync', Instruction.BULK_READ),
                                                    ('fast_sync', Instruction.FAST_BULK_READ)])
def test_a_bus_of_several_layouts_is_read_with_one_bulk_read(
        read_mode: str, instruction: Instruction) -> None:
    # An XM430 (block at 224, 12 bytes with the tick), an XL430 at firmware 45 and an X330 at
    # firmware 52 (its block at 208): one request for all, each at its own address and length.
    models = {1: model_for(1020), 2: model_for(1060), 3: model_for(1200, 52)}
    sim = SimBus(list(models), boot_time_s=0.0, models=models, firmware={3: 52})
    configure_servos(sim, 1_000_000, None)
    tap = TapPort(SimPortHandler(sim, 'sim', 1_000_000))
    joints = {f'j{i}': {'id': i, 'operating_mode': 'velocity'} for i in models}
    manager = Manager(validate(sim_params(joints, read_mode=read_mode)), info=lambda _: None,
                      warn=lambda _: None, port_factory=lambda _: SimTransport(sim, lambda: tap))
    manager.configure()
    manager.activate()
    try:
        tap.packets.clear()
        assert manager.cycle_begin(full=False)
        manager.cycle_end()
        reads = [p for p in tap.packets if p.instruction in (
            Instruction.SYNC_READ, Instruction.FAST_SYNC_READ, Instruction.BULK_READ,
            Instruction.FAST_BULK_READ, Instruction.READ)]
        assert [p.instruction for p in reads] == [instruction]
        records = [struct.unpack_from('<BHH', reads[0].params, 5 * k) for k in range(3)]
        assert records == [(1, 224, 12), (2, 224, 12), (3, 208, 12)]
        assert all(servo.fresh for servo in manager.active_servos())
        assert [each.what for each in manager.bus_budget().transactions][0] == (
            'fast bulk read' if read_mode == 'fast_sync' else 'bulk read')
    finally:
        manager.deactivate()
        manager.close()
