"""
Goals through the indirect goal slot: one sync write per cycle whatever the mix of modes.

The slot's layout is checked for every model and mode by replaying its map the way the servo
does (each data byte written to the address its entry names); the driver's writes are checked
on the simulator, by the packets it sent and the registers the servos hold.
"""

import io
import struct
from typing import Any, Dict, List, Tuple

from dxl_servo_driver import protocol
from dxl_servo_driver.config import validate
from dxl_servo_driver.driver import state_block
from dxl_servo_driver.driver.manager import Manager
from dxl_servo_driver.models import ALL_MODELS, model_for, modes, X_MODELS
from dxl_servo_driver.models.units import units_for
from dxl_servo_driver.protocol import Instruction, Packet
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.port import SimPortHandler
from dxl_servo_driver.sim.virtual_bus import configure_servos, GoalTracer
from manager_rig import BAUD, no_tasks, params, read_states, Rig, run_cycles, TapPort
import pytest

XM430_UNITS = units_for(model_for(1030))
SLOT_ADDRESS = 246   # indirect data 23: after the 22-byte state block on every X table
_GOALS = {'goal_position': -123456, 'goal_velocity': -321, 'goal_current': -77, 'goal_pwm': 555}


def _effort(table: state_block.Model) -> str:
    return 'present_current' if table.has('present_current') else 'present_load'


def _replay(table: state_block.Model, slot: state_block.GoalSlot, data: bytes) -> Dict[str, int]:
    """Write data through the slot's map as the servo does; return the registers it set whole."""
    memory: Dict[int, int] = {}
    for offset, byte in enumerate(data):
        assert memory.get(slot.targets[offset], byte) == byte, 'one byte, two values'
        memory[slot.targets[offset]] = byte
    values = {}
    owned = set()
    for name in slot.registers:
        item = table.item(name)
        span = range(item.address, item.address + item.size)
        owned.update(span)
        if all(address in memory for address in span):
            raw = bytes(memory[address] for address in span)
            values[name] = int.from_bytes(raw, 'little', signed=True)
        else:
            assert not any(address in memory for address in span), f'{name} written in part'
    assert set(memory) <= owned, 'the slot wrote outside its own goal registers'
    return values


@pytest.mark.parametrize('table', ALL_MODELS, ids=lambda t: t.label)
def test_every_write_length_sets_the_slot_registers_whole(table: state_block.Model) -> None:
    block = state_block.state_block(table, _effort(table))
    for mode in table.modes:
        slot = state_block.goal_slot(table, block, mode)
        if block.direct or len(table.indirect) < block.size + state_block.GOAL_SLOT_SIZE:
            assert slot is None   # the X330 before firmware 53: no room after its block
            continue
        # Right after the block: at 246 on every X table, the P's after its own bank.
        assert slot is not None and slot.data_address == block.read_address + block.size
        if table in X_MODELS:
            assert slot.data_address == SLOT_ADDRESS
        assert slot.registers == modes.BY_NAME[mode].slot
        goals = {name: _GOALS[name] for name in slot.registers}
        for name in slot.registers:
            length = slot.needs[name]
            # A write as long as a goal needs sets that goal whole (and those before it).
            replayed = _replay(table, slot, slot.pack(goals, length))
            assert replayed[name] == goals[name]
        assert _replay(table, slot, slot.pack(goals, state_block.GOAL_SLOT_SIZE)) == goals
        assert len(slot.map_bytes()) == 2 * state_block.GOAL_SLOT_SIZE


@pytest.fixture
def rig() -> Rig:
    return Rig()


def _sync_writes(rig: Rig) -> List[Packet]:
    return [p for p in rig.tap.packets if p.instruction == Instruction.SYNC_WRITE]


def _address_length(packet: Packet) -> Tuple[int, int]:
    return packet.params[0] | (packet.params[1] << 8), packet.params[2] | (packet.params[3] << 8)


def _manager(rig: Rig, **extra: Any) -> Manager:
    manager = rig.manager(validate(params(**extra)))
    manager.configure()
    manager.activate()
    return manager


def _command_three_modes(rig: Rig, manager: Manager) -> None:
    """Queue a goal for each of arm (position), wheel (velocity), grip (current); write."""
    assert manager.command('position', ['arm'], [0.5]).success
    assert manager.command('velocity', ['wheel'], [1.0]).success
    assert manager.command('current', ['grip'], [0.2]).success
    rig.tap.packets.clear()
    assert manager.write_pending() == 3


def _assert_three_goals(rig: Rig) -> None:
    assert rig.reg(1, 'goal_position') == XM430_UNITS.position_from_rad(0.5)
    assert rig.reg(2, 'goal_velocity') == XM430_UNITS.velocity_from_rad_s(1.0)
    assert rig.reg(3, 'goal_current') == XM430_UNITS.current_from_a(0.2)


def test_goals_of_three_modes_go_out_in_one_sync_write(rig: Rig) -> None:
    manager = _manager(rig)
    assert all(servo.goal_slot is not None for servo in manager.order)
    assert manager.goal_slots_in_use == '3 of 3'
    profile_before = rig.reg(1, 'profile_velocity')
    _command_three_modes(rig, manager)
    sync = _sync_writes(rig)
    assert len(rig.tap.packets) == len(sync) == 1
    assert _address_length(sync[0]) == (SLOT_ADDRESS, 4)   # the longest: position, velocity
    _assert_three_goals(rig)
    assert rig.reg(1, 'profile_velocity') == profile_before
    # A current goal alone needs 2 bytes.
    assert manager.command('current', ['grip'], [-0.1]).success
    rig.tap.packets.clear()
    manager.write_pending()
    assert [_address_length(p) for p in rig.tap.packets] == [(SLOT_ADDRESS, 2)]
    assert rig.reg(3, 'goal_current') == XM430_UNITS.current_from_a(-0.1)


def test_per_register_writes_one_sync_write_per_goal_register(rig: Rig) -> None:
    manager = _manager(rig, write_mode='per_register')
    assert all(servo.goal_slot is None for servo in manager.order)
    _command_three_modes(rig, manager)
    sync = _sync_writes(rig)
    assert len(sync) == len(rig.tap.packets) == 3
    assert sorted(_address_length(p) for p in sync) == [(102, 2), (104, 4), (116, 4)]
    _assert_three_goals(rig)


def test_current_based_position_carries_both_goals(rig: Rig) -> None:
    manager = _manager(rig, **{'grip.operating_mode': 'current_based_position'})
    grip_current = rig.reg(3, 'goal_current')
    # Position alone: 4 bytes; the goal current stays what it was.
    assert manager.command('position', ['arm', 'grip'], [0.2, 0.4]).success
    rig.tap.packets.clear()
    manager.write_pending()
    assert [_address_length(p) for p in rig.tap.packets] == [(SLOT_ADDRESS, 4)]
    assert rig.reg(3, 'goal_position') == XM430_UNITS.position_from_rad(0.4)
    assert rig.reg(3, 'goal_current') == grip_current
    # A current goal with a position goal of another joint: one write of the whole slot, the
    # position joint repeating its own goal in the bytes it does not need.
    assert manager.command('current', ['grip'], [0.15]).success
    assert manager.command('position', ['arm'], [-0.3]).success
    rig.tap.packets.clear()
    manager.write_pending()
    assert [_address_length(p) for p in rig.tap.packets] == [(SLOT_ADDRESS, 6)]
    assert rig.reg(3, 'goal_current') == XM430_UNITS.current_from_a(0.15)
    assert rig.reg(3, 'goal_position') == XM430_UNITS.position_from_rad(0.4)
    assert rig.reg(1, 'goal_position') == XM430_UNITS.position_from_rad(-0.3)
    # write_register of the goal current: the slot's next write carries that value, not an
    # older one.
    assert manager.write_register('grip', 'goal_current', 100).success
    assert manager.command('position', ['grip'], [0.1]).success
    manager.write_pending()
    assert rig.reg(3, 'goal_current') == 100


def test_a_mode_switch_maps_the_slot_to_the_new_mode(rig: Rig) -> None:
    manager = _manager(rig)
    assert manager.set_operating_mode(['arm'], 'velocity').success
    assert manager.servos['arm'].goal_slot.registers == ('goal_velocity',)  # type: ignore
    position_goal = rig.reg(1, 'goal_position')
    assert manager.command('velocity', ['arm', 'wheel'], [0.5, -0.5]).success
    rig.tap.packets.clear()
    manager.write_pending()
    assert [_address_length(p) for p in rig.tap.packets] == [(SLOT_ADDRESS, 4)]
    assert rig.reg(1, 'goal_velocity') == XM430_UNITS.velocity_from_rad_s(0.5)
    assert rig.reg(1, 'goal_position') == position_goal
    assert rig.reg(2, 'goal_velocity') == XM430_UNITS.velocity_from_rad_s(-0.5)


def test_a_restarted_servo_gets_its_slot_back(rig: Rig) -> None:
    manager = _manager(rig)
    rig.sim.powercycle(3)
    rig.wait_booted(3)
    read_states(manager)
    assert manager.servos['grip'].restarts == 1
    run_cycles(manager, no_tasks(manager))
    assert manager.servos['grip'].goal_slot is not None
    assert manager.command('current', ['grip'], [0.1]).success
    rig.tap.packets.clear()
    manager.write_pending()
    assert [_address_length(p) for p in rig.tap.packets] == [(SLOT_ADDRESS, 2)]
    assert rig.reg(3, 'goal_current') == XM430_UNITS.current_from_a(0.1)


def test_a_slot_that_does_not_read_back_is_given_up_for_register_writes(rig: Rig) -> None:
    config = validate(params())
    manager = rig.manager(config)
    manager.configure()
    # Something else took the arm's slot entries (as a firmware that does not keep them would).
    memory = rig.sim.servo(1).memory
    memory.set('indirect_address_23', 112)
    manager.activate()
    arm = manager.servos['arm']
    assert arm.goal_slot is None and arm.slot_refused
    assert manager.goal_slots_in_use == '2 of 3'
    assert any('goal slot' in line and "'arm'" in line for line in rig.logs)
    assert manager.command('position', ['arm'], [0.25]).success
    assert manager.command('velocity', ['wheel'], [0.5]).success
    rig.tap.packets.clear()
    manager.write_pending()
    assert sorted(_address_length(p) for p in rig.tap.packets) == [(116, 4), (SLOT_ADDRESS, 4)]
    assert rig.reg(1, 'goal_position') == XM430_UNITS.position_from_rad(0.25)
    assert rig.reg(2, 'goal_velocity') == XM430_UNITS.velocity_from_rad_s(0.5)


class MixedRig(Rig):
    """The manager tests' rig on a bus of other models."""

    def __init__(self, models: Dict[int, state_block.Model], firmware: Dict[int, int]) -> None:
        self.sim = SimBus(tuple(models), boot_time_s=0.02, models=models, firmware=firmware)
        configure_servos(self.sim, BAUD, None)
        self.tap = TapPort(SimPortHandler(self.sim, 'sim', BAUD))
        self.logs: List[str] = []


def test_an_old_x330_without_room_is_written_per_register_beside_the_slot() -> None:
    rig = MixedRig({1: model_for(1020), 2: model_for(1200, 50)}, {2: 50})
    manager = rig.manager(validate({
        'port': 'sim', 'baud_rate': BAUD, 'latency_timer': 1.0, 'joints': ['arm', 'finger'],
        'arm.id': 1, 'arm.operating_mode': 'position',
        'finger.id': 2, 'finger.operating_mode': 'position'}))
    manager.configure()
    manager.activate()
    assert manager.servos['arm'].goal_slot is not None
    assert manager.servos['finger'].goal_slot is None
    finger = units_for(model_for(1200, 50))
    arm = units_for(model_for(1020))
    assert manager.command('position', ['arm', 'finger'], [0.3, -0.3]).success
    rig.tap.packets.clear()
    manager.write_pending()
    assert sorted(_address_length(p) for p in rig.tap.packets) == [(116, 4), (SLOT_ADDRESS, 4)]
    assert rig.reg(1, 'goal_position') == arm.position_from_rad(0.3)
    assert rig.reg(2, 'goal_position') == finger.position_from_rad(-0.3)


def test_the_benchmark_goal_tracer_follows_writes_through_the_slot() -> None:
    # virtual_bus --trace-goals times every goal position the host writes (the benchmark's
    # command latency): through the slot as well as at Goal Position itself.
    sim = SimBus((1, 2), boot_time_s=0.0)
    configure_servos(sim, BAUD, None)
    out = io.StringIO()
    tracer = GoalTracer(out, sim)
    table = model_for(1020)
    block = state_block.state_block(table, 'present_current')
    slot = state_block.goal_slot(table, block, 'position')
    current = state_block.goal_slot(table, block, 'current')
    assert slot is not None and current is not None
    for servo_id, mapped in ((1, slot), (2, current)):
        sim.feed(protocol.encode_instruction(servo_id, Instruction.WRITE, struct.pack(
            '<H', mapped.map_address) + mapped.map_bytes()), BAUD)
    goals = {1: {'goal_position': 3000}, 2: {'goal_current': 40}}
    params = struct.pack('<HH', SLOT_ADDRESS, 4) + b''.join(
        bytes((sid,)) + (slot if sid == 1 else current).pack(goals[sid], 4) for sid in (1, 2))
    tracer.feed(protocol.encode_instruction(0xFE, Instruction.SYNC_WRITE, params), 5.0)
    direct = struct.pack('<HH', 116, 4) + bytes((2,)) + struct.pack('<i', 1234)
    tracer.feed(protocol.encode_instruction(0xFE, Instruction.SYNC_WRITE, direct), 6.0)
    lines = [line.split() for line in out.getvalue().splitlines()]
    # The current-mode servo's slot write holds no goal position: not logged.
    assert lines == [['5.000000', '1', '3000'], ['6.000000', '2', '1234']]
