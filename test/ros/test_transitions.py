"""
Lifecycle transitions in a row: one cycle, at its rate, nothing from before answered as new.

Twenty deactivate/activate pairs (and seeded runs of every transition) land at random moments
of the cycle, with every reply delayed a few milliseconds by the adapter, so most deactivates
find a read in flight. Afterwards there is exactly one cycle thread (counted three ways: the
threads named dxl_bus_cycle, the runner's own count, /diagnostics' cycle_threads), no lock is
left held by a read of an earlier activation, the node cycles again and never faster than its
loop rate (counted by the node in windows of known length), no read fails, and no sample is
refused as older than its request. How much slower than its rate it runs is not judged: a busy
machine decides that. What slows it whatever the machine is checked here: a second cycle
thread, and reads given the replies of an aborted one.
"""

import random
import struct
import threading
import time
from typing import Any, Dict, List

from dxl_servo_driver.bus import Bus
from dxl_servo_driver.driver.clock import TICK_PERIOD_MS
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.fault_engine import Faults
from dxl_servo_driver.sim.faulty_port import FaultyPort
from dxl_servo_driver.sim.port import SimPortHandler
from dxl_servo_driver.sim.virtual_bus import configure_servos
from lifecycle_msgs.msg import Transition
from node_harness import faulty_harness, NodeHarness, sim_params
import pytest

IDS = (1, 2, 3)
JOINTS: Dict[str, Dict[str, Any]] = {
    f'j{servo_id}': {'id': servo_id, 'operating_mode': 'position',
                     'registers': {'return_delay_time': 0}} for servo_id in IDS}
LOOP_HZ = 100.0
# The adapter holds every reply 1-4 ms: a read is on the wire for a good part of each cycle.
DELAYED = Faults(delay_ms=(1.0, 4.0))
WINDOW_S = 1.5
# Cycles a loop at LOOP_HZ may run in a window beyond its length * LOOP_HZ: one behind its
# schedule catches up back to back (a period's backlog at most), and the window's two ends
# each cut a cycle. A busy machine only makes them fewer.
CATCH_UP = 3
DEACTIVATE = Transition.TRANSITION_DEACTIVATE
ACTIVATE = Transition.TRANSITION_ACTIVATE
CLEANUP = Transition.TRANSITION_CLEANUP
CONFIGURE = Transition.TRANSITION_CONFIGURE


def cycle_threads() -> int:
    return sum(thread.name == 'dxl_bus_cycle' and thread.is_alive()
               for thread in threading.enumerate())


def cycles_in(h: NodeHarness, seconds: float) -> int:
    """Return the node's cycles in a window at least `seconds` long (measured, not assumed)."""
    assert h.node is not None
    first = h.node.manager.stats.cycles
    began = time.monotonic()
    time.sleep(seconds)
    # The window runs to the count: a thread woken late has a longer one.
    count = h.node.manager.stats.cycles - first
    assert count <= (time.monotonic() - began) * LOOP_HZ + CATCH_UP, \
        f'{count} cycles in {seconds} s at {LOOP_HZ:g} Hz: more than one cycle running'
    return count


def wait_cycles(h: NodeHarness, count: int, timeout_s: float = 10.0) -> None:
    """Wait until the node has run `count` more cycles."""
    assert h.node is not None
    manager = h.node.manager
    target = manager.stats.cycles + count
    deadline = time.monotonic() + timeout_s
    while manager.stats.cycles < target:
        assert time.monotonic() < deadline, f'not {count} cycles within {timeout_s} s'
        time.sleep(0.005)


def transition(h: NodeHarness, transition_id: int) -> None:
    response = h.call('change_state', transition=Transition(id=transition_id))
    assert response.success, f'transition {transition_id} failed'


def check_settled(h: NodeHarness, before: int) -> None:
    """One cycle thread, never beyond its rate, reading every servo, refusing nothing."""
    assert h.node is not None
    manager = h.node.manager
    h.joint_states.wait(lambda m: len(m.name) == len(IDS))
    wait_cycles(h, 30)   # the first full reads after the activation
    failures = manager.stats.read_failures
    refused = manager.stats.stale_refused
    after = cycles_in(h, WINDOW_S)
    print(f'{before} cycles in {WINDOW_S} s before the transitions, {after} after')
    # It cycles (waited for: a busy machine may run few in the window), in one thread, never
    # beyond its rate (cycles_in).
    wait_cycles(h, 10)
    assert cycle_threads() == 1 and h.node._runner.cycle_threads == 1
    assert manager.stats.read_failures == failures, manager.stats.read_failures - failures
    assert manager.stats.stale_refused == refused
    diagnostics = h.diagnostics.wait(
        lambda array: any(value.key == 'cycle_threads' and value.value == '1'
                          for status in array.status for value in status.values),
        timeout_s=5.0)
    assert diagnostics is not None


def check_nothing_in_flight(h: NodeHarness) -> None:
    """After a deactivate no read is left holding the manager's or the bus's lock."""
    assert h.node is not None
    manager = h.node.manager
    assert cycle_threads() == 0 and h.node._runner.cycle_threads == 0
    for lock in (manager.lock, manager.bus.lock if manager.bus is not None else None):
        if lock is None:
            continue
        taken: List[bool] = []

        def take(lock: Any = lock) -> None:
            # From another thread: the test's own thread could take an RLock it already held.
            taken.append(lock.acquire(timeout=1.0))
            if taken[-1]:
                lock.release()
        thread = threading.Thread(target=take)
        thread.start()
        thread.join()
        assert taken == [True], 'a lock is still held by a read of the last activation'


def test_twenty_deactivate_activate_pairs_leave_one_cycle_at_its_rate() -> None:
    params = sim_params(JOINTS, loop_rate=LOOP_HZ, latency_timer=8.0)
    with faulty_harness(params, DELAYED) as h:
        h.joint_states.wait(lambda m: len(m.name) == len(IDS))
        before = cycles_in(h, WINDOW_S)
        rng = random.Random(20)
        for _ in range(20):
            transition(h, DEACTIVATE)
            time.sleep(rng.uniform(0.0, 0.02))
            transition(h, ACTIVATE)
            time.sleep(rng.uniform(0.0, 0.02))
        check_settled(h, before)


@pytest.mark.parametrize('seed', range(3))
def test_any_sequence_of_transitions_ends_in_one_cycle(seed: int) -> None:
    params = sim_params(JOINTS, loop_rate=LOOP_HZ, latency_timer=8.0)
    with faulty_harness(params, DELAYED, seed=seed) as h:
        h.joint_states.wait(lambda m: len(m.name) == len(IDS))
        before = cycles_in(h, WINDOW_S)
        rng = random.Random(seed)
        state = 'active'
        # The legal moves of the lifecycle from each primary state.
        moves = {'active': [(DEACTIVATE, 'inactive')],
                 'inactive': [(ACTIVATE, 'active'), (CLEANUP, 'unconfigured')],
                 'unconfigured': [(CONFIGURE, 'inactive')]}
        for _ in range(30):
            transition_id, state = rng.choice(moves[state])
            transition(h, transition_id)
            if state == 'inactive' and transition_id == DEACTIVATE:
                check_nothing_in_flight(h)
            time.sleep(rng.uniform(0.0, 0.02))
        while state != 'active':
            transition_id, state = moves[state][0]
            transition(h, transition_id)
        check_settled(h, before)


def test_an_aborted_read_is_waited_out_not_answered_later() -> None:
    """Its replies, still on their way, never pass for the answer of the next request."""
    sim = SimBus(IDS)
    configure_servos(sim, 1_000_000, 0)
    port = FaultyPort(SimPortHandler(sim, 'sim', 1_000_000), Faults(delay_ms=(3.0, 3.0)))
    bus = Bus(port, 1_000_000, latency_timer_s=0.005, return_delay_s=0.0)
    tick = sim.servo(1).model.item('realtime_tick')
    ticks: List[int] = []
    for _ in range(5):
        bus.begin_sync_read(tick.address, tick.size, IDS).abort()   # given up at once
        time.sleep(0.002)   # the next request goes out while those replies are on their way
        asked_tick = sim.read_register(1, 'realtime_tick')
        result = bus.sync_read(tick.address, tick.size, IDS)
        data = result.data[1]
        assert isinstance(data, bytes), data
        ticks.append(struct.unpack('<H', data)[0])
        # The aborted read's answer is 2 ms older than this request: -2 ms, folded. This
        # request's is taken between the tick read before it and the one read after it.
        taken_tick = sim.read_register(1, 'realtime_tick')
        age_ms = (ticks[-1] - asked_tick) % TICK_PERIOD_MS
        assert age_ms <= (taken_tick - asked_tick) % TICK_PERIOD_MS, (asked_tick, ticks)
        time.sleep(0.01)
    assert port.in_waiting == 0
