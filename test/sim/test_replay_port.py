"""
The recorded-reply port of the benchmark's ceiling (sim/replay.py), in front of the simulator.

The first (fast) sync read goes to the servos and is recorded; an identical one is answered at
once from the record, every byte the same but each servo's Realtime Tick, moved on by the time
since, with CRCs that check; sync writes are dropped once replaying; anything else still reaches
the servos.
"""

import struct
import time

from dxl_servo_driver.bus import Bus
from dxl_servo_driver.driver import state_block
from dxl_servo_driver.driver.clock import TickClock
from dxl_servo_driver.models import model_for
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.port import SimPortHandler
from dxl_servo_driver.sim.replay import ReplayPort
from dxl_servo_driver.sim.virtual_bus import configure_servos
import pytest

BAUD = 4_000_000
IDS = (1, 2, 3)
BLOCK = state_block.state_block(model_for(1030), 'present_current')
TICK_OFFSET = BLOCK.tagged_size - 2
FIELDS = BLOCK.tagged_struct.format.lstrip('<')


def rig() -> tuple[SimBus, ReplayPort, Bus]:
    sim = SimBus(list(IDS), seed=1, boot_time_s=0.0)
    configure_servos(sim, BAUD, None)
    port = ReplayPort(SimPortHandler(sim, 'sim', BAUD), TICK_OFFSET)
    bus = Bus(port, BAUD, latency_timer_s=0.0, return_delay_s=0.0)
    for servo_id in IDS:
        bus.write(servo_id, BLOCK.indirect_map_address(), BLOCK.indirect_map_bytes())
    return sim, port, bus


@pytest.mark.parametrize('fast', [False, True], ids=['sync', 'fast_sync'])
def test_a_repeated_read_is_answered_from_its_record_with_the_ticks_moved_on(fast: bool) -> None:
    _, port, bus = rig()
    began_s = time.monotonic()
    first = bus.begin_sync_read(BLOCK.read_address, BLOCK.tagged_size, IDS, fast,
                                fields=FIELDS).collect()
    recorded_s = time.monotonic()
    assert first.values is not None and port.forwarded >= 1 and port.replayed == 0
    time.sleep(0.02)
    asked_s = time.monotonic()
    second = bus.begin_sync_read(BLOCK.read_address, BLOCK.tagged_size, IDS, fast,
                                 fields=FIELDS).collect()
    ended_s = time.monotonic()
    assert port.replayed == 1
    assert second.values is not None   # whole and clean: every CRC checked
    # The tick moved on by the time between the two reads (20 ms and what a busy machine
    # added), in whole milliseconds: bounded by the times taken around them.
    least_ms = (asked_s - recorded_s) * 1000.0 - 1.0
    most_ms = (ended_s - began_s) * 1000.0 + 1.0
    count = BLOCK.TAGGED_FIELDS
    for k in range(len(IDS)):
        before = first.values[k * count:(k + 1) * count]
        after = second.values[k * count:(k + 1) * count]
        assert after[:3] == before[:3]                      # the motion part as recorded
        assert least_ms <= (after[3] - before[3]) % 0x8000 <= most_ms
    # And the driver's dating takes the replayed samples as current.
    clock = TickClock()
    for _ in range(3):
        result = bus.begin_sync_read(BLOCK.read_address, BLOCK.tagged_size, IDS, fast,
                                     fields=FIELDS).collect()
        assert result.values is not None
        assert clock.check(result.values[3], result.sent_s, time.monotonic())
        time.sleep(0.003)


def test_sync_writes_are_dropped_once_replaying_and_other_requests_reach_the_servos() -> None:
    sim, port, bus = rig()
    goal = model_for(1030).item('goal_position')
    bus.sync_write(goal.address, 4, [(servo_id, struct.pack('<i', 1000)) for servo_id in IDS])
    assert port.swallowed == 0 and sim.read_register(1, 'goal_position') == 1000
    bus.sync_read(BLOCK.read_address, BLOCK.tagged_size, IDS)   # recorded: replaying from now
    bus.sync_write(goal.address, 4, [(servo_id, struct.pack('<i', 3000)) for servo_id in IDS])
    assert port.swallowed == 1 and sim.read_register(1, 'goal_position') == 1000
    bus.write(2, goal.address, struct.pack('<i', 2500))         # a one-off write: it gets there
    assert sim.read_register(2, 'goal_position') == 2500
    assert bus.read(3, goal.address, 4) == struct.pack('<i', 1000)


def test_an_incomplete_answer_is_not_recorded() -> None:
    sim, port, bus = rig()
    sim.set_drop(2, 1.0)   # servo 2 never answers
    result = bus.sync_read(BLOCK.read_address, BLOCK.tagged_size, IDS)
    assert not isinstance(result.data[2], bytes)
    bus.sync_read(BLOCK.read_address, BLOCK.tagged_size, IDS)
    assert port.replayed == 0   # asked the servos again: nothing was recorded
