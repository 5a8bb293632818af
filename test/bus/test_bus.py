"""The bus layer's sync read over the simulator: fast path, alerts, corruption, stuffing."""

import struct
import time
from typing import Tuple

from dxl_servo_driver.bus import Bus
from dxl_servo_driver.driver import state_block
from dxl_servo_driver.errors import CommTimeout, CorruptReply
from dxl_servo_driver.models import model_for
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.port import SimPortHandler
from dxl_servo_driver.sim.virtual_bus import configure_servos
import pytest

BAUD = 1_000_000
BLOCK = state_block.state_block(model_for(1030), 'present_current')
IDS = (1, 2, 3)


@pytest.fixture
def rig() -> Tuple[SimBus, Bus]:
    sim = SimBus(IDS)
    configure_servos(sim, BAUD, 0)
    bus = Bus(SimPortHandler(sim, 'sim', BAUD), BAUD, latency_timer_s=0.001, return_delay_s=0.0)
    for servo_id in IDS:
        bus.write(servo_id, BLOCK.indirect_map_address(), BLOCK.indirect_map_bytes())
    return sim, bus


def motion(sim: SimBus, servo_id: int) -> Tuple[int, ...]:
    regs = sim.registers(servo_id)
    return (regs['present_position'], regs['present_velocity'], regs['present_current'])


def test_a_clean_block_is_read_and_decoded(rig: Tuple[SimBus, Bus]) -> None:
    sim, bus = rig
    result = bus.sync_read(BLOCK.read_address, BLOCK.motion_size, IDS)
    assert result.clean
    for servo_id in IDS:
        assert BLOCK.decode_motion(result.data[servo_id]) == motion(sim, servo_id)
        assert result.alerts[servo_id] is False
    assert bus.counters.timeouts == bus.counters.corrupt == 0


def test_an_alert_bit_is_no_error_and_is_reported(rig: Tuple[SimBus, Bus]) -> None:
    sim, bus = rig
    sim.inject_error(2, 'encoder')
    result = bus.sync_read(BLOCK.read_address, BLOCK.motion_size, IDS)
    assert all(isinstance(result.data[i], bytes) for i in IDS)
    assert result.alerts == {1: False, 2: True, 3: False}
    assert BLOCK.decode_motion(result.data[2]) == motion(sim, 2)


def test_a_corrupted_reply_is_refused_alone(rig: Tuple[SimBus, Bus]) -> None:
    sim, bus = rig
    sim.set_corrupt(3, 1.0)
    results = bus.sync_read(BLOCK.read_address, BLOCK.motion_size, IDS).data
    assert isinstance(results[3], CorruptReply)
    assert isinstance(results[1], bytes) and isinstance(results[2], bytes)
    assert bus.counters.corrupt == 1


def test_a_silent_servo_times_out_alone(rig: Tuple[SimBus, Bus]) -> None:
    sim, bus = rig
    sim.set_drop(1, 1.0)
    results = bus.sync_read(BLOCK.read_address, BLOCK.motion_size, IDS).data
    assert isinstance(results[1], CommTimeout)
    assert isinstance(results[2], bytes) and isinstance(results[3], bytes)


def test_a_stuffed_reply_is_unstuffed(rig: Tuple[SimBus, Bus]) -> None:
    sim, bus = rig
    # Present position -131073 is FF FF FD FF on the wire: the servo stuffs an FD after it.
    target = struct.unpack('<i', b'\xff\xff\xfd\xff')[0]
    dynamics = sim.servo(2).dynamics
    dynamics.horn_position_pulse += target - sim.read_register(2, 'present_position')
    deadline = time.monotonic() + 2.0
    while sim.read_register(2, 'present_position') != target and time.monotonic() < deadline:
        time.sleep(0.002)
        sim.feed(b'', BAUD)
        bus.ping(2)     # lets the simulated servo advance its physics
    assert sim.read_register(2, 'present_position') == target
    results = bus.sync_read(BLOCK.read_address, BLOCK.motion_size, IDS).data
    assert BLOCK.decode_motion(results[2])[0] == target
    assert isinstance(results[1], bytes) and isinstance(results[3], bytes)


def test_begin_and_end_hold_the_bus_in_between(rig: Tuple[SimBus, Bus]) -> None:
    sim, bus = rig
    pending = bus.begin_sync_read(BLOCK.read_address, BLOCK.motion_size, IDS)
    assert bus.lock._is_owned()   # noqa: SLF001 - RLock: held by this thread until the end
    result = pending.collect()
    assert not bus.lock._is_owned()
    assert len(result.data) == 3
    with pytest.raises(RuntimeError):
        pending.collect()
    # An abandoned read releases the bus once, however often it is abandoned.
    pending = bus.begin_sync_read(BLOCK.read_address, BLOCK.motion_size, IDS)
    pending.abort()
    pending.abort()
    assert not bus.lock._is_owned()
    assert bus.dirty   # its replies are in flight: the next requests are careful
