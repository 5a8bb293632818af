"""
An adapter that echoes what the host sends (local echo): learned once, skipped everywhere.

A half-duplex adapter without echo suppression hands the host its own request back before the
servos' reply. The bus learns that from the first transaction and from then on expects the echo
in front of every answer: no transaction may wait for its deadline (the cost that turns a 100 Hz
cycle into 11 Hz behind a 16 ms latency timer), none may take the echo for a reply or a reply for
noise, whether the echo comes whole or in pieces across several reads. Each transaction kind is
checked on the bus (sync read, fast sync read, read, write, ping, reboot, sync write), then the
node: its cycle, its services and its torque-off at the end.
"""

import time
from typing import Any, Callable, Dict, Tuple

from dxl_servo_driver.bus import Bus
from dxl_servo_driver.bus.wire import Counters
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.fault_engine import Faults
from dxl_servo_driver.sim.faulty_port import FaultyPort
from dxl_servo_driver.sim.port import SimPortHandler
from dxl_servo_driver.sim.virtual_bus import configure_servos
from node_harness import faulty_harness, NodeHarness, sim_params
import pytest

BAUD = 1_000_000
IDS = (1, 2, 3)
LATENCY_TIMER_S = 0.016   # the Linux default: a wait for the deadline costs 18 ms
ECHOES: Dict[str, Faults] = {
    'whole': Faults(echo=True),
    'in pieces': Faults(echo=True, echo_chunk=3, echo_gap_ms=0.05),
    'byte by byte': Faults(echo=True, echo_chunk=1, echo_gap_ms=0.01),
}
TORQUE_ENABLE = 64
GOAL_POSITION = 116
PRESENT_POSITION = 132


def clean(counters: Counters) -> Tuple[int, ...]:
    """Return the counters that must not move once the echo is learned."""
    return (counters.timeouts, counters.corrupt, counters.stale, counters.flushed_bytes,
            counters.deadline_waits, counters.status_errors)


def echo_bus(faults: Faults) -> Tuple[SimBus, FaultyPort, Bus]:
    sim = SimBus(IDS, boot_time_s=0.02)
    configure_servos(sim, BAUD, 0)
    port = FaultyPort(SimPortHandler(sim, 'sim', BAUD), faults)
    return sim, port, Bus(port, BAUD, latency_timer_s=LATENCY_TIMER_S, return_delay_s=0.0)


def wait_booted(sim: SimBus, servo_id: int) -> None:
    deadline = time.monotonic() + 2.0
    while not sim.servo(servo_id).responsive(time.monotonic()):
        assert time.monotonic() < deadline
        time.sleep(0.002)


TRANSACTIONS: Dict[str, Callable[[SimBus, Bus], Any]] = {
    'ping': lambda sim, bus: bus.ping(2),
    'read': lambda sim, bus: bus.read(2, PRESENT_POSITION, 4),
    'write': lambda sim, bus: bus.write(2, GOAL_POSITION, bus.read(2, PRESENT_POSITION, 4)),
    'sync read': lambda sim, bus: bus.sync_read(PRESENT_POSITION, 4, IDS),
    'fast sync read': lambda sim, bus: bus.sync_read(PRESENT_POSITION, 4, IDS, fast=True),
    'sync write': lambda sim, bus: bus.sync_write(
        TORQUE_ENABLE, 1, [(servo_id, b'\x00') for servo_id in IDS]),
    'reboot': lambda sim, bus: (bus.reboot(3), wait_booted(sim, 3)),
}


@pytest.mark.parametrize('echo', sorted(ECHOES))
@pytest.mark.parametrize('kind', sorted(TRANSACTIONS))
def test_every_transaction_skips_the_echo_without_waiting(echo: str, kind: str) -> None:
    sim, port, bus = echo_bus(ECHOES[echo])
    bus.ping(1)   # learns the echo (this one may wait: it did not expect it)
    assert bus.echo
    before = clean(bus.counters)
    echoes = bus.counters.echoes
    for _ in range(5):
        result = TRANSACTIONS[kind](sim, bus)
        if kind in ('sync read', 'fast sync read'):
            assert all(isinstance(data, bytes) for data in result.data.values()), result.data
    bus.ping(1)   # a sync write has no answer: the next transaction shows nothing was left
    assert clean(bus.counters) == before, bus.counters
    assert bus.echo and bus.counters.echoes >= echoes + 6
    assert port.in_waiting == 0


def test_an_echo_is_not_unlearned_by_one_odd_transaction() -> None:
    sim, port, bus = echo_bus(ECHOES['whole'])
    bus.ping(1)
    assert bus.echo
    port.set(echo=False)   # one request whose echo the adapter swallowed
    bus.ping(1)
    port.set(echo=True)
    waits = bus.counters.deadline_waits
    for _ in range(5):
        bus.sync_read(PRESENT_POSITION, 4, IDS)
        bus.ping(2)
    assert bus.echo and bus.counters.deadline_waits == waits


def test_an_adapter_that_stops_echoing_is_unlearned_within_a_few_transactions() -> None:
    sim, port, bus = echo_bus(ECHOES['whole'])
    bus.ping(1)
    port.set(echo=False)   # an adapter replaced, or echo suppression switched on
    for _ in range(5):
        bus.ping(1)
    assert not bus.echo
    waits = bus.counters.deadline_waits
    for _ in range(5):
        bus.sync_read(PRESENT_POSITION, 4, IDS)
        bus.ping(2)
    assert bus.counters.deadline_waits == waits


@pytest.mark.parametrize('echo', sorted(ECHOES))
def test_the_node_behind_an_echoing_adapter(echo: str) -> None:
    """The cycle and services never wait their deadlines out; torque off is acknowledged."""
    joints = {f'j{servo_id}': {'id': servo_id, 'operating_mode': 'position',
                               'registers': {'return_delay_time': 0}} for servo_id in IDS}
    params = sim_params(joints, loop_rate=100.0, latency_timer=16.0)
    h: NodeHarness = faulty_harness(params, ECHOES[echo])
    try:
        assert h.node is not None
        h.joint_states.wait(lambda m: len(m.name) == len(IDS))
        bus = h.node.manager.bus
        assert bus is not None and bus.echo
        before = clean(bus.counters)
        cycles = h.node.manager.stats.cycles
        for step in range(20):
            h.publish('position', ['j1', 'j2'], [0.1 * (step % 3), -0.1])
            assert h.call('read_register', name='j3', register_name='present_position').success
            time.sleep(0.02)
        assert h.call('set_position', name=['j3'], value=[0.2]).success
        # The cycle ran meanwhile (waited for: a busy machine may not have run one yet).
        deadline = time.monotonic() + 10.0
        while h.node.manager.stats.cycles <= cycles:
            assert time.monotonic() < deadline, 'the cycle does not run'
            time.sleep(0.01)
        assert clean(bus.counters) == before, bus.counters
        assert h.node.manager.stats.read_failures == 0
        # A reboot: the pings of the booting servo wait for their deadlines (it is silent),
        # and nothing else does; its restore does not linger behind them.
        timeouts = bus.counters.timeouts
        assert h.call('reboot', name=['j2']).success
        pings = bus.counters.timeouts - timeouts
        assert bus.counters.deadline_waits - before[4] == pings, bus.counters
        h.joint_states.wait(lambda m: len(m.name) == len(IDS))
    finally:
        h.close()
    # torque_off_on_shutdown: every servo off, every torque-off acknowledged (the log says so).
    assert all(h.sim.read_register(servo_id, 'torque_enable') == 0 for servo_id in IDS)
