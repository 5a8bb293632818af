"""
Samples dated by the servos' Realtime Tick: across its wrap, across cleanup, across restarts.

The driver refuses a reply older than its request by the servo's tick (driver/clock.py). Its
offset between tick and host clock is only true while the servo runs on: a configure after a
cleanup may find a servo that restarted, or (port: sim) a new simulator whose ticks start at 0,
and a tick wraps every 32.768 s. Each configure, activation and service read here happens
with the ticks just before their wrap, or far from where the last activation left them.
"""

import time
from typing import List

from dxl_servo_driver.config import validate
from dxl_servo_driver.driver.clock import TICK_PERIOD_MS, TickClock
from lifecycle_msgs.msg import Transition
from manager_rig import cycle_read, params, Rig
from node_harness import NodeHarness, sim_params
import pytest

IDS = (1, 2, 3)
WRAP_IN_S = 1.0
# Ticks to put every servo at before a configure: just before the wrap (the configure's dated
# reads straddle it), at it, and far ahead or behind where the last activation left them.
TICKS_MS = (TICK_PERIOD_MS - 1, TICK_PERIOD_MS - 4, TICK_PERIOD_MS - 25, 0, 20_000, 5)


def set_ticks(rig: Rig, tick_ms: int) -> None:
    for servo_id in IDS:
        rig.sim.set_tick(servo_id, tick_ms)


def test_configure_activate_and_reads_hold_across_the_wrap_and_after_a_cleanup() -> None:
    rig = Rig(IDS)
    config = validate(params())
    manager = rig.manager(config)
    for tick_ms in TICKS_MS:
        set_ticks(rig, tick_ms)
        manager.configure()
        set_ticks(rig, TICK_PERIOD_MS - 3)
        manager.activate()
        # The cycle's reads carry the tick while the bus is suspicious: make it read them.
        manager.bus.mark_dirty()
        fresh = []
        deadline = time.monotonic() + 0.1
        while time.monotonic() < deadline:
            cycle_read(manager, retry_until=time.monotonic() + 0.01)
            fresh.append(all(servo.fresh for servo in manager.order))
        assert fresh and all(fresh), f'tick {tick_ms}: a fresh sample was refused'
        assert manager.stats.stale_refused == 0
        assert manager.deactivate() == []
        manager.close()   # cleanup: the servos keep running, their ticks with them


def test_service_reads_hold_while_the_tick_wraps() -> None:
    rig = Rig(IDS)
    manager = rig.manager(validate(params()))
    # The ticks wrap WRAP_IN_S after this: during the reads below, whatever configure took.
    set_ticks(rig, TICK_PERIOD_MS - int(WRAP_IN_S * 1000))
    manager.configure()
    manager.activate()
    servo = manager.order[0]
    ticks: List[int] = []
    deadline = time.monotonic() + WRAP_IN_S + 10.0
    while not any(b < a for a, b in zip(ticks, ticks[1:])) or len(ticks) < 10:
        assert time.monotonic() < deadline, f'no wrap seen in {ticks[-5:]}'
        tick = manager.read_register(servo.name, 'realtime_tick')
        assert tick.success, tick.message
        ticks.append(tick.value)
        position = manager.read_register(servo.name, 'present_position')
        assert position.success, position.message
        cycle_read(manager, retry_until=time.monotonic() + 0.01)
        assert servo.fresh
        if ticks[-1] < TICK_PERIOD_MS - 50 and len(ticks) > 10 and ticks[-1] > 50:
            time.sleep(0.01)   # far from the wrap: no need to hurry
    wrapped = next(i for i, (a, b) in enumerate(zip(ticks, ticks[1:])) if b < a)
    ticks = ticks[wrapped:wrapped + 2]
    assert ticks[0] > TICK_PERIOD_MS - 100 and ticks[1] < 100, ticks
    assert manager.stats.stale_refused == 0


def test_a_servo_restarted_while_unconfigured_is_configured_again() -> None:
    rig = Rig(IDS)
    manager = rig.manager(validate(params()))
    manager.configure()
    manager.activate()
    manager.deactivate()
    manager.close()
    for servo_id in IDS:
        rig.sim.powercycle(servo_id)   # its tick starts again from 0
        rig.wait_booted(servo_id)
    manager.configure()
    manager.activate()
    assert all(rig.reg(servo_id, 'torque_enable') == 1 for servo_id in IDS)


def test_a_long_unconfirmed_offset_is_forgotten_not_wrapped() -> None:
    clock = TickClock(forget_after_s=60.0)
    assert clock.check(1000, 10.0, 10.001)
    # Twenty hours later the same servo (its tick went round many times): relaxed by drift the
    # old bound would have wrapped into nonsense; it is forgotten and learned again.
    later_s = 10.0 + 20 * 3600.0
    assert clock.check(12_345, later_s, later_s + 0.001)
    assert clock.check(12_345 + 50, later_s + 0.05, later_s + 0.051)
    # A reply older than its request is still refused once the offset is known again.
    assert not clock.check(12_345 + 50, later_s + 0.2, later_s + 0.201)


@pytest.mark.parametrize('tick_ms', [TICK_PERIOD_MS - 3, 100])
def test_the_wrap_itself_is_no_age(tick_ms: int) -> None:
    clock = TickClock()
    sent_s = 5.0
    ticks: List[int] = []
    for step in range(10):
        now_s = sent_s + step * 0.001
        tick = (tick_ms + step) % TICK_PERIOD_MS
        ticks.append(tick)
        assert clock.check(tick, now_s, now_s + 0.0005), ticks


def test_configure_straight_after_cleanup_on_the_simulated_bus() -> None:
    """The path of make run: port sim builds a new simulator (ticks from 0) at each configure."""
    joints = {f'j{i}': {'id': i, 'operating_mode': 'position'} for i in IDS}
    with NodeHarness(sim_params(joints)) as h:
        h.joint_states.wait(lambda m: len(m.name) == len(IDS))
        for round_ in range(4):
            for transition in (Transition.TRANSITION_DEACTIVATE, Transition.TRANSITION_CLEANUP,
                               Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE):
                response = h.call('change_state', transition=Transition(id=transition))
                assert response.success, f'round {round_}: transition {transition} failed'
            h.joint_states.wait(lambda m: len(m.name) == len(IDS))
            response = h.call('read_register', name='j1', register_name='present_position')
            assert response.success, response.message
        assert h.node.manager.stats.stale_refused == 0
