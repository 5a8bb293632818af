"""
The cycle's loop below ROS (driver/loop.CycleLoop) on the simulated bus, without rclpy.

The loop runs the manager of `port: sim` (transports.open_transport) with a publish callback
that records, in the loop's own thread, what each cycle did: whether its samples were fresh,
whether the next read was already on the wire when it was published (pipelined or chained),
and how many cycles had prepared goals by then (a chained cycle prepares none). The tests wait
on those records (a condition), never on the clock.
"""

import math
import threading
from typing import Any, Callable, Dict, Iterator, List, Optional, Tuple

from dxl_servo_driver.config import DriverConfig, validate
from dxl_servo_driver.driver.loop import CycleLoop, THREAD_NAME
from dxl_servo_driver.driver.manager import Manager
from dxl_servo_driver.driver.transports import open_transport, Transport
import pytest

JOINTS = {'arm': 1, 'elbow': 2}
WAIT_S = 20.0   # a bound on every wait (a busy machine), never how long one takes
GOAL_RAD = 0.3
GOAL_RAW = int(round(GOAL_RAD / (2.0 * math.pi / 4096.0))) + 2048   # the XM430 of `port: sim`


def config(**top: Any) -> DriverConfig:
    params: Dict[str, Any] = {'port': 'sim', 'baud_rate': 1_000_000, 'latency_timer': 1.0,
                              'loop_rate': 100.0, 'joints': list(JOINTS)}
    for name, servo_id in JOINTS.items():
        params[f'{name}.id'] = servo_id
        params[f'{name}.operating_mode'] = 'position'
    params.update(top)
    return validate(params)


class Rig:
    """An active manager on `port: sim`, its simulator, and what its log said."""

    def __init__(self, **top: Any) -> None:
        self.transports: List[Transport] = []
        self.lines: List[str] = []

        def keep(cfg: DriverConfig) -> Transport:
            self.transports.append(open_transport(cfg))
            return self.transports[-1]

        self.manager = Manager(config(**top), info=self.lines.append, warn=self.lines.append,
                               error=self.lines.append, port_factory=keep)
        self.manager.configure()
        self.manager.activate()

    def goal_raw(self, servo_id: int) -> int:
        return int(self.transports[-1].simulator.read_register(servo_id, 'goal_position'))

    def close(self) -> None:
        self.manager.deactivate()
        self.manager.close()


class Log:
    """A Logger keeping its lines."""

    def __init__(self) -> None:
        self.lines: List[Tuple[str, str]] = []

    def info(self, message: str, **kwargs: Any) -> None:
        self.lines.append(('info', message))

    def warning(self, message: str, **kwargs: Any) -> None:
        self.lines.append(('warning', message))

    def error(self, message: str, **kwargs: Any) -> None:
        self.lines.append(('error', message))

    def fatal(self, message: str, **kwargs: Any) -> None:
        self.lines.append(('fatal', message))


class Step:
    """A CycleStep: idle or queuing a goal every cycle (as a trajectory does)."""

    def __init__(self, manager: Manager, goal: Optional[float] = None) -> None:
        self._manager = manager
        self._goal = goal
        self.prepared = 0
        self.watched = 0
        self.refused: List[str] = []

    def idle(self) -> bool:
        return self._goal is None

    def prepare_goals(self, now_s: float) -> None:
        self.prepared += 1
        if self._goal is not None:
            result = self._manager.command('position', ['arm'], [self._goal])
            if not result.success:
                self.refused.append(result.message)

    def watch_samples(self, read_ok: bool) -> None:
        self.watched += 1


class Cycles:
    """The publish callback: what each cycle did, recorded in the loop's thread."""

    def __init__(self, manager: Manager, step: Step,
                 also: Callable[[], None] = lambda: None) -> None:
        self._manager = manager
        self._step = step
        self._also = also
        self._changed = threading.Condition()
        self.published = 0
        self.fresh = 0           # every servo read well in that cycle
        self.in_flight = 0       # the next read already on the wire when it was published
        self.chained = 0         # cycles that prepared no goal (their read was chained)
        self.unwatched = 0       # published before the step watched its samples
        self.threads: List[str] = []
        self._raise_next: Optional[BaseException] = None

    def __call__(self, stamp_ns: int, read_ok: bool) -> None:
        with self._changed:
            self.published += 1
            self.fresh += read_ok and all(servo.fresh for servo in self._manager.order)
            self.in_flight += self._manager.read_in_flight
            self.chained = self.published - self._step.prepared
            self.unwatched += self._step.watched != self.published
            self.threads.append(threading.current_thread().name)
            self._also()
            self._changed.notify_all()
            error, self._raise_next = self._raise_next, None
        if error is not None:
            raise error

    def fail_next(self, error: BaseException) -> int:
        """Have the next publish raise error; return the cycles published until then."""
        with self._changed:
            self._raise_next = error
            return self.published

    def wait(self, condition: Callable[['Cycles'], bool]) -> None:
        with self._changed:
            assert self._changed.wait_for(lambda: condition(self), WAIT_S), vars(self)


class Timers:
    """Timers calling back every period, one callback at a time (a single-threaded executor)."""

    def __init__(self) -> None:
        self.created: List[float] = []
        self.live: List[threading.Event] = []
        self._executor = threading.Lock()

    def create_timer(self, period_s: float, callback: Callable[[], None]) -> threading.Event:
        stopped = threading.Event()

        def run() -> None:
            while not stopped.wait(period_s):
                with self._executor:
                    if not stopped.is_set():
                        callback()

        self.created.append(period_s)
        self.live.append(stopped)
        threading.Thread(target=run, name='fake_executor', daemon=True).start()
        return stopped

    def destroy_timer(self, timer: threading.Event) -> None:
        timer.set()
        self.live.remove(timer)


@pytest.fixture
def rig() -> Iterator[Rig]:
    made = Rig()
    try:
        yield made
    finally:
        made.close()


def lock_is_free(manager: Manager) -> bool:
    """Return whether another thread can take the manager's lock (re-entrant: not this one)."""
    taken: List[bool] = []

    def take() -> None:
        taken.append(manager.lock.acquire(timeout=5.0))
        if taken[-1]:
            manager.lock.release()

    other = threading.Thread(target=take)
    other.start()
    other.join()
    return taken == [True]


def loop_of(rig: Rig, cycles: Cycles, step: Step, rate_hz: float,
            timers: Optional[Timers] = None, log: Optional[Log] = None) -> CycleLoop:
    return CycleLoop(lambda: rig.manager, rate_hz, cycles, log or Log(), steps=[step],
                     timers=timers)


def test_flat_out_the_loop_pipelines_and_chains_with_fresh_samples(rig: Rig) -> None:
    step = Step(rig.manager)
    cycles = Cycles(rig.manager, step)
    loop = loop_of(rig, cycles, step, 10000.0)   # far above what the bus carries
    loop.start('thread', rig.manager.bus_budget().cycle_time_s)
    try:
        cycles.wait(lambda c: c.fresh >= 200 and c.in_flight >= 50 and c.chained >= 50)
    finally:
        loop.stop()
    assert set(cycles.threads) == {THREAD_NAME}
    assert cycles.unwatched == 0
    assert loop.cycle_errors == 0 and loop.failure is None and loop.cycle_threads == 0
    assert not rig.manager.read_in_flight


def test_a_step_with_goals_stops_chaining_but_not_pipelining(rig: Rig) -> None:
    # A step that queues a goal every cycle (a trajectory): every cycle writes, so no read is
    # chained, but the next read still goes out before the cycle is published.
    step = Step(rig.manager, GOAL_RAD)
    seen: List[bool] = []
    cycles = Cycles(rig.manager, step, also=lambda: seen.append(rig.goal_raw(1) == GOAL_RAW))
    loop = loop_of(rig, cycles, step, 10000.0)
    loop.start('thread', rig.manager.bus_budget().cycle_time_s)
    try:
        cycles.wait(lambda c: c.fresh >= 100 and c.in_flight >= 50 and any(seen))
    finally:
        loop.stop()
    assert cycles.chained == 0 and step.refused == []
    assert loop.cycle_errors == 0


def test_a_paced_loop_neither_pipelines_nor_chains(rig: Rig) -> None:
    # 10 Hz: a cycle is pipelined only when the loop fell a whole period behind.
    step = Step(rig.manager)
    cycles = Cycles(rig.manager, step)
    loop = loop_of(rig, cycles, step, 10.0)
    loop.start('thread', rig.manager.bus_budget().cycle_time_s)
    try:
        cycles.wait(lambda c: c.fresh >= 3)
    finally:
        loop.stop()
    assert cycles.in_flight == 0 and cycles.chained == 0


def test_the_timer_driver_runs_whole_cycles_from_the_timer(rig: Rig) -> None:
    step = Step(rig.manager)
    cycles = Cycles(rig.manager, step)
    timers = Timers()
    loop = loop_of(rig, cycles, step, 200.0, timers)
    loop.start('timer', rig.manager.bus_budget().cycle_time_s)
    try:
        cycles.wait(lambda c: c.fresh >= 5)
        loop.set_rate(100.0)   # a new timer at the new period
        assert timers.created == pytest.approx([0.005, 0.01]) and len(timers.live) == 1
        assert loop.running and loop.cycle_threads == 0
    finally:
        loop.stop()
    assert timers.live == [] and not loop.running
    assert set(cycles.threads) == {'fake_executor'}
    assert cycles.in_flight == 0 and cycles.chained == 0


def test_the_timer_driver_needs_timers(rig: Rig) -> None:
    step = Step(rig.manager)
    loop = loop_of(rig, Cycles(rig.manager, step), step, 100.0)
    with pytest.raises(ValueError):
        loop.start('timer', 0.001)
    assert not loop.running


def test_never_two_cycle_threads(rig: Rig) -> None:
    step = Step(rig.manager)
    cycles = Cycles(rig.manager, step)
    loop = loop_of(rig, cycles, step, 1000.0)
    loop.start('thread', rig.manager.bus_budget().cycle_time_s)
    try:
        cycles.wait(lambda c: c.published >= 1)
        with pytest.raises(RuntimeError):
            loop.start('thread', 0.001)
        assert loop.cycle_threads == 1
        assert sum(t.name == THREAD_NAME for t in threading.enumerate()) == 1
    finally:
        loop.stop()
    assert loop.cycle_threads == 0 and not loop.running
    assert not any(t.name == THREAD_NAME and t.is_alive() for t in threading.enumerate())
    assert lock_is_free(rig.manager)


def test_an_exception_is_survived_and_a_base_exception_ends_the_cycle(rig: Rig) -> None:
    step = Step(rig.manager)
    cycles = Cycles(rig.manager, step)
    log = Log()
    loop = loop_of(rig, cycles, step, 10000.0, log=log)
    loop.start('thread', rig.manager.bus_budget().cycle_time_s)
    try:
        cycles.wait(lambda c: c.fresh >= 10)
        published = cycles.fail_next(RuntimeError('a publisher failed'))
        cycles.wait(lambda c: c.published >= published + 10)
        assert loop.cycle_errors == 1 and loop.failure is None
        thread = loop.thread
        assert thread is not None and thread.is_alive()
        cycles.fail_next(SystemExit('a library called exit()'))
        thread.join(WAIT_S)
        assert not thread.is_alive()
    finally:
        loop.stop()
    assert isinstance(loop.failure, SystemExit)
    assert any(level == 'error' and 'a publisher failed' in text for level, text in log.lines)
    assert any(level == 'fatal' and 'the bus cycle stopped' in text for level, text in log.lines)
    # The read the failed cycle had in flight was let go, with the manager's lock.
    assert not rig.manager.read_in_flight
    assert lock_is_free(rig.manager)
