"""
The reply deadline's slack: raised by replies that came late, never by a servo that is silent.

A read that gives up at its deadline and then finds its replies waiting before the next request
was too hasty, and so was one whose late replies the cycle took for the next read's answers
(their Realtime Tick dates them before that request): the slack doubles (up to a cap), so later
reads take their own replies. A servo that never answers leaves nothing behind, and the slack
stays small: a silent servo costs each cycle as little as before.

Everything runs on the test's own clock (fake_clock): the simulator's wire-timed port brings
every reply a set latency after its last byte crossed the wire, and the bus looks exactly when
it means to. On the machine's clock a busy machine decides when the bus looks: a block taken on
time is seen in the last half of the slack (and raises it) by a reader that woke late.
"""

from dxl_servo_driver.bus import Bus, DEADLINE_SLACK_S, MAX_DEADLINE_SLACK_S
from dxl_servo_driver.bus import wire
from dxl_servo_driver.sim.virtual_bus import configure_servos
from fake_clock import FakeClock, LatePort
import pytest

BAUD = 1_000_000
IDS = (1, 2, 3)
ADDRESS, LENGTH = 132, 4   # present_position


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> FakeClock:
    return FakeClock().install(monkeypatch)


def late_bus(clock: FakeClock, late_ms: float, ids: tuple = IDS) -> Bus:
    """Return a bus whose every reply comes late_ms after the wire brought it, in order."""
    sim = clock.sim(ids)
    configure_servos(sim, BAUD, 0)   # Return Delay Time 0: the wire and the lateness alone
    port = clock.port(sim, BAUD, late_ms / 1000.0)
    return Bus(port, BAUD, latency_timer_s=0.0, return_delay_s=0.0)


def answered(bus: Bus, clock: FakeClock) -> int:
    """Sync read, then pause as a slow loop does (a late reply is waiting by the next one)."""
    result = bus.sync_read(ADDRESS, LENGTH, IDS)
    clock.sleep(0.03)   # longer than any lateness here
    return sum(isinstance(data, bytes) for data in result.data.values())


def test_replies_later_than_the_slack_raise_it_until_they_are_taken(clock: FakeClock) -> None:
    # Every reply 3 ms late: beyond the first slack (2 ms) but within its double.
    bus = late_bus(clock, 3.0)
    assert bus.slack_s == DEADLINE_SLACK_S
    for _ in range(10):   # a read gives up at its deadline; its replies wait by the next one
        answered(bus, clock)
        if bus.counters.slack_raised:
            break
    assert bus.slack_s >= 2 * DEADLINE_SLACK_S
    # Now the replies are taken (3 ms is in the last half of 4 ms: raised once more, to 8).
    assert sum(answered(bus, clock) == len(IDS) for _ in range(20)) >= 15
    assert bus.slack_s <= 8 * DEADLINE_SLACK_S


def test_a_block_that_comes_in_the_last_half_of_the_slack_raises_it_before_one_is_lost(
        clock: FakeClock) -> None:
    # 1.5 ms late: within the first slack (2 ms beyond the wire time), in its last half: taken,
    # and the slack raised with no read given up on.
    bus = late_bus(clock, 1.5)
    assert answered(bus, clock) == len(IDS) and bus.counters.deadline_waits == 0
    assert bus.slack_s == 2 * DEADLINE_SLACK_S and bus.counters.slack_raised == 1
    # Early in 4 ms now: no more.
    assert sum(answered(bus, clock) == len(IDS) for _ in range(10)) == 10
    assert bus.counters.slack_raised == 1


def test_the_slack_never_passes_its_cap(clock: FakeClock) -> None:
    bus = late_bus(clock, 1000.0 * MAX_DEADLINE_SLACK_S + 4.0)   # later than any slack allows
    for _ in range(12):
        answered(bus, clock)
    assert bus.slack_s == MAX_DEADLINE_SLACK_S


def test_a_silent_servo_leaves_the_slack_as_it_is(clock: FakeClock) -> None:
    bus = late_bus(clock, 0.0, ids=(1, 2))
    for _ in range(10):
        result = bus.sync_read(ADDRESS, LENGTH, (1, 2, 7))   # id 7 is not there
        assert isinstance(result.data[1], bytes) and not isinstance(result.data[7], bytes)
        clock.sleep(0.01)
    assert bus.counters.deadline_waits >= 10
    assert bus.slack_s == DEADLINE_SLACK_S and bus.counters.slack_raised == 0


def test_a_raised_slack_comes_back_down_after_requests_with_nothing_late(
        clock: FakeClock, monkeypatch: pytest.MonkeyPatch) -> None:
    # The wire layer reads it (dxl_servo_driver/bus/wire.py).
    monkeypatch.setattr(wire, 'SLACK_DECAY_REQUESTS', 5)
    bus = late_bus(clock, 0.0)
    bus.raise_slack()
    assert bus.slack_s == 2 * DEADLINE_SLACK_S
    for _ in range(4):
        assert answered(bus, clock) == len(IDS)
    assert bus.slack_s == 2 * DEADLINE_SLACK_S
    answered(bus, clock)
    assert bus.slack_s == DEADLINE_SLACK_S


def test_a_cycle_behind_late_replies_gets_the_slack_they_need_and_reads_well_again(
        clock: FakeClock) -> None:
    # Back to back, as the node at full speed: the late replies of one read arrive during the
    # next, are taken for its answers and refused by their tick; the cycle raises the slack.
    from dxl_servo_driver.config import validate
    from dxl_servo_driver.driver.manager import Manager
    from dxl_servo_driver.driver.transports import SimTransport
    from node_harness import sim_params
    sim = clock.sim(IDS)
    configure_servos(sim, BAUD, 0)
    port = LatePort(clock, sim, BAUD)
    joints = {f'j{i}': {'id': i, 'operating_mode': 'position'} for i in IDS}
    manager = Manager(validate(sim_params(joints, latency_timer=0.0)), info=lambda _: None,
                      warn=lambda _: None, port_factory=lambda _: SimTransport(sim, lambda: port),
                      clock=clock.monotonic)
    manager.configure()
    manager.activate()
    try:
        bus = manager._ctx.link.io()
        assert bus.slack_s == DEADLINE_SLACK_S
        port.late(0.005)   # later than the first slack and the tick's tolerance
        fresh_run = 0
        for _ in range(200):
            assert manager.cycle_begin(full=False)
            manager.cycle_end()
            fresh_run = fresh_run + 1 if all(s.fresh for s in manager.joints) else 0
            if fresh_run >= 20:
                break
        assert fresh_run >= 20, 'the cycle never read well again'
        assert bus.slack_s > DEADLINE_SLACK_S and bus.counters.slack_raised >= 1
    finally:
        manager.deactivate()
        manager.close()
