"""
The bus cycle's loop: read, take the samples, step, write goals, publish, pace; until stopped.

One loop below ROS owns the whole cycle (ARCHITECTURE.md, Life of one cycle): it puts the
manager's state read on the wire (Manager.cycle_begin, stamped right before the request goes
out), collects it (cycle_end), has the cycle's steps queue their goals (CycleStep: the arm's
trajectories and gripper goals), writes the goals and steps recovery (cycle_write), has the
steps judge the fresh samples and hands them to `publish`, paces itself to loop_rate and
measures the rate it keeps. What it is given: the manager (of each activation: the node's is
replaced at a reconfigure), a publish callback, a stamp source (the node's ROS clock; else the
system clock) and a logger (the node's, or PrintLog).

It runs in its own thread (`thread`: named dxl_bus_cycle, its sleeps ended on time by a 1 ns
timer slack) or from an executor timer (`timer`: Timers, one unpipelined cycle a tick), so it
never waits on the executor. Any exception is logged, counted and survived; a BaseException
ends the cycle and is kept in `failure` for the node to go to its error state.

Flat out (the next cycle due by the time this read ends) the next read goes on the wire before
this cycle is published (pipelined), so publishing overlaps the bus transaction; and when no
step has anything to prepare, the loop offers cycle_end to chain it (to put it on the wire as
soon as the last block came back clean, before its samples are taken). Whether the bus allows
it (nothing queued, nobody waiting for the lock, every servo's sample taken without a
transaction) is the read's to say (driver/cycle.Cycle.end_read); the loop says only whether it
wants it. A chained cycle writes nothing; its command timeouts are checked, and what they
queue goes out at the next.

There is never more than one cycle thread: start() refuses while the thread of an earlier
start is alive (a stop that timed out keeps it on record, it is never forgotten), and each
thread runs only while its generation is the loop's latest, so one left behind ends at its
next cycle instead of reading beside the new one. `cycle_threads` counts the live ones.
"""

import sys
import threading
import time
import traceback
from typing import Any, Callable, List, Optional, Protocol, Sequence, TextIO, Tuple

from dxl_servo_driver.driver.rates import RateMeter, Shortfall
from dxl_servo_driver.driver.roles import ManagerForLoop
from dxl_servo_driver.timerslack import fine_timer_slack

__all__ = ['CycleLoop', 'CycleStep', 'Logger', 'PrintLog', 'Publish', 'RATE_LOG_INTERVAL_S',
           'THREAD_NAME', 'Timers']

RATE_LOG_INTERVAL_S = 60.0
THREAD_NAME = 'dxl_bus_cycle'
Publish = Callable[[int, bool], None]   # (stamp of the samples in ns, whether the read went well)


class CycleStep(Protocol):
    """Work the cycle does beside the bus's (the arm's trajectories and gripper goals)."""

    def idle(self) -> bool:
        """Return True when prepare_goals has nothing to do: the next read may be chained."""

    def prepare_goals(self, now_s: float) -> None:
        """Queue this cycle's goals (called right before its goal write; monotonic now)."""

    def watch_samples(self, read_ok: bool) -> None:
        """Judge this cycle's samples (called right before they are published)."""


class Timers(Protocol):
    """Where the `timer` driver gets its timer (the node's executor)."""

    def create_timer(self, period_s: float, callback: Callable[[], None]) -> Any:
        """Create a timer calling callback every period_s."""

    def destroy_timer(self, timer: Any) -> Any:
        """Destroy a timer."""


class Logger(Protocol):
    """What the loop says things with (rclpy's node logger has these)."""

    def info(self, message: str, **kwargs: Any) -> Any:
        """Log an information."""

    def warning(self, message: str, **kwargs: Any) -> Any:
        """Log a warning."""

    def error(self, message: str, **kwargs: Any) -> Any:
        """Log an error; throttle_duration_sec: at most one that often."""

    def fatal(self, message: str, **kwargs: Any) -> Any:
        """Log the end of the cycle."""


class PrintLog:
    """A Logger without ROS: each line on a stream (stderr), throttling ignored."""

    def __init__(self, stream: Optional[TextIO] = None, verbose: bool = True) -> None:
        self._stream = stream
        self._verbose = verbose   # False: errors only (a benchmark's rate reports are noise)

    def _say(self, level: str, message: str) -> None:
        print(f'[{level}] {message}', file=self._stream or sys.stderr, flush=True)

    def info(self, message: str, **kwargs: Any) -> None:
        """Log an information."""
        if self._verbose:
            self._say('INFO', message)

    def warning(self, message: str, **kwargs: Any) -> None:
        """Log a warning."""
        if self._verbose:
            self._say('WARN', message)

    def error(self, message: str, **kwargs: Any) -> None:
        """Log an error."""
        self._say('ERROR', message)

    def fatal(self, message: str, **kwargs: Any) -> None:
        """Log the end of the cycle."""
        self._say('FATAL', message)


class CycleLoop:
    """Drives the manager's cycle at the loop rate and measures it (the module docstring)."""

    def __init__(self, manager: Callable[[], ManagerForLoop], loop_rate_hz: float,
                 publish: Publish, log: Logger, stamp: Callable[[], int] = time.time_ns,
                 steps: Sequence[CycleStep] = (), timers: Optional[Timers] = None) -> None:
        self._manager_of = manager   # asked at each start: a reconfigure makes a new one
        self._publish = publish
        self._log = log
        self._stamp_source = stamp   # ns, the time the samples are published with
        self._steps = tuple(steps)
        self._timers = timers
        self._stop = threading.Event()
        self._wake = threading.Event()     # cuts the cycle's sleep short (stop, new loop_rate)
        self.thread: Optional[threading.Thread] = None
        self._generation = 0
        self._started: List[threading.Thread] = []   # every cycle thread not known ended
        self._timer: Any = None
        self._timer_manager: Optional[ManagerForLoop] = None
        self.rate = RateMeter()
        self._shortfall = Shortfall()
        self.period_s = 1.0 / loop_rate_hz
        self._period_changed = False
        self.bus_cycle_s = 0.0
        self._read_stamp = 0   # stamp of the read in flight, ns
        self._read_began_s = 0.0
        self._next_rate_log_s = 0.0
        self.last_cycle_s = 0.0
        self.cycle_errors = 0
        self.failure: Optional[BaseException] = None

    # control --------------------------------------------------------------------------------
    @property
    def cycle_threads(self) -> int:
        """Return how many cycle threads are alive (0 stopped, 1 running; never more)."""
        self._started = [thread for thread in self._started if thread.is_alive()]
        return len(self._started)

    @property
    def running(self) -> bool:
        """Return whether a cycle runs, or the thread of a stopped one has not ended yet."""
        return self._timer is not None or self.cycle_threads > 0

    def start(self, driver: str, bus_cycle_s: float) -> None:
        """Start cycling: in a thread (`thread`) or from a timer of `timers` (`timer`)."""
        if self.running:
            raise RuntimeError('the bus cycle of the last activation has not ended yet')
        if driver == 'timer' and self._timers is None:
            raise ValueError('cycle_driver timer: this loop was given no timers')
        manager = self._manager_of()
        self._generation += 1
        self.bus_cycle_s = bus_cycle_s
        self._stop.clear()
        self._wake.clear()
        self.rate.reset()
        self._shortfall.reset()
        self._next_rate_log_s = 0.0
        self.last_cycle_s = time.monotonic()
        self.failure = None
        if driver == 'timer':
            assert self._timers is not None
            self._timer_manager = manager
            self._timer = self._timers.create_timer(self.period_s, self._timer_cycle)
        else:
            self.thread = threading.Thread(target=self._run, args=(self._generation, manager),
                                           name=THREAD_NAME, daemon=True)
            self._started.append(self.thread)
            self.thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop cycling and wait for the thread (never from the thread itself)."""
        self._generation += 1   # a thread that misses the stop event ends at its next cycle
        self._stop.set()
        self._wake.set()
        if self._timer is not None:
            assert self._timers is not None
            self._timers.destroy_timer(self._timer)
            self._timer = None
        if self.thread is not None:
            if self.thread is not threading.current_thread():
                self.thread.join(timeout=timeout_s)
                if self.thread.is_alive():
                    # Kept in _started: no activation starts another beside it.
                    self._log.error(f'the bus cycle did not stop within {timeout_s:g} s')
            self.thread = None

    def set_rate(self, hz: float) -> None:
        """Take a new loop_rate at once (the sleep under way is cut short)."""
        self.period_s = 1.0 / hz
        self._period_changed = True
        self._shortfall.reset()
        self._wake.set()
        if self._timer is not None:
            assert self._timers is not None
            self._timers.destroy_timer(self._timer)
            self._timer = self._timers.create_timer(self.period_s, self._timer_cycle)

    # the thread -----------------------------------------------------------------------------
    def _run(self, generation: int, manager: ManagerForLoop) -> None:
        """Run the bus cycle in its thread; if it ever fails for good, say so and keep why."""
        # Its sleeps (until the replies are due, until the next cycle) end on time, not up to
        # 50 us later.
        fine_timer_slack()
        try:
            self._loop(generation, manager)
        except BaseException as exc:  # noqa: B902 - never a silent death of the cycle
            self.failure = exc
            manager.abort_read()
            self._log.fatal(
                f'the bus cycle stopped: {exc!r}; going to the error state (torque off)\n'
                + ''.join(traceback.format_exception(exc)))

    def _loop(self, generation: int, manager: ManagerForLoop) -> None:
        """
        Read, write goals, step recovery, publish, pace; until stopped.

        reading: a read is in flight; pipelined: the next cycle's read went out before this
        one was published (or was chained), so the next turn starts by collecting it, with no
        sleep between. Any exception is logged, counted and survived.
        """
        next_s = time.monotonic()
        reading = False
        pipelined = False
        while not self._stop.is_set() and generation == self._generation:
            try:
                if not pipelined:
                    reading = self._begin(manager)
                stamp, began_s = self._read_stamp, self._read_began_s
                # Chained only while the loop runs flat out (the next cycle due by the time this
                # read ends, as for pipelining) and no step has anything to prepare.
                chain = (pipelined and next_s + self.period_s - time.monotonic()
                         <= self.bus_cycle_s and self._idle())
                ok = reading and self._end(manager, began_s, chain)
                chained = chain and manager.read_in_flight
                reading = chained
                next_s, now = self._next_due(next_s)
                if chained:
                    manager.check_command_timeout()   # queues only: written next cycle
                else:
                    self._prepare(now)
                    manager.cycle_write(tasks_until=next_s - self.bus_cycle_s)
                self._shortfall.add_cycle(time.monotonic() - began_s)
                pipelined = chained or next_s - time.monotonic() <= self.bus_cycle_s
                if pipelined and not chained:
                    reading = self._begin(manager)
                self._deliver(stamp, ok)
            except Exception as exc:  # noqa: B902 - the cycle must survive anything
                reading = pipelined = False
                self._survive(manager, exc)
                self._stop.wait(0.05)
                next_s = time.monotonic()
            self.last_cycle_s = time.monotonic()
            self._tick_rate(manager)
            if not pipelined:
                next_s = self._sleep_until(next_s)
        manager.abort_read()   # never leave the bus held

    def _next_due(self, next_s: float) -> Tuple[float, float]:
        """Return when the next cycle is due, and now."""
        period = self.period_s
        next_s += period
        now = time.monotonic()
        if next_s < now - period:
            next_s = now   # behind: run as fast as the bus allows, without a backlog
        return next_s, now

    def _sleep_until(self, next_s: float) -> float:
        """Sleep until next_s (a stop or a new loop_rate wakes it); return when it is due."""
        delay = next_s - time.monotonic()
        if delay > 0.0 and self._wake.wait(delay):
            self._wake.clear()
        if self._period_changed:
            self._period_changed = False
            next_s = time.monotonic()
        return next_s

    # the timer ------------------------------------------------------------------------------
    def _timer_cycle(self) -> None:
        """Run one whole cycle, unpipelined (the `timer` driver's tick)."""
        manager = self._timer_manager
        assert manager is not None
        try:
            began = self._begin(manager)
            ok = began and self._end(manager, self._read_began_s)
            now = time.monotonic()
            self._prepare(now)
            manager.cycle_write(tasks_until=now + 0.5 * self.period_s)
            self._shortfall.add_cycle(time.monotonic() - self._read_began_s)
            self._deliver(self._read_stamp, ok)
        except Exception as exc:  # noqa: B902 - the cycle must survive anything
            self._survive(manager, exc)
        self.last_cycle_s = time.monotonic()
        self._tick_rate(manager)

    # one cycle's parts ----------------------------------------------------------------------
    def _begin(self, manager: ManagerForLoop) -> bool:
        """Stamp and start a read; False when nothing is in flight (port lost, no servo)."""
        # Stamped with the lock held, right before the request: a service's transaction may
        # hold the bus for tens of milliseconds first.
        if manager.cycle_begin(stamp=self._stamp):
            return True
        self._stamp()
        return False

    def _stamp(self) -> None:
        """Take the time of the read about to go on the wire."""
        # In nanoseconds: the joint_states bytes take it as it is (ros/messages.JointTable).
        self._read_stamp = self._stamp_source()
        self._read_began_s = time.monotonic()

    def _end(self, manager: ManagerForLoop, began_s: float, chain: bool = False) -> bool:
        # Lost or corrupted replies are read again while the cycle has time (or twice the bus
        # time when the loop runs as fast as the bus allows).
        retry_until = began_s + max(0.9 * self.period_s, 2.0 * self.bus_cycle_s)
        return manager.cycle_end(retry_until, self._stamp if chain else None)

    def _idle(self) -> bool:
        return all(step.idle() for step in self._steps)

    def _prepare(self, now_s: float) -> None:
        for step in self._steps:
            step.prepare_goals(now_s)

    def _deliver(self, stamp_ns: int, read_ok: bool) -> None:
        """Have the steps judge the samples, then publish them."""
        for step in self._steps:
            step.watch_samples(read_ok)
        self._publish(stamp_ns, read_ok)

    def _survive(self, manager: ManagerForLoop, exc: Exception) -> None:
        """Count a failed cycle, let its read go, say why (throttled)."""
        self.cycle_errors += 1
        manager.abort_read()
        self._log.error(f'cycle failed: {exc!r}', throttle_duration_sec=2.0)

    # the rate -------------------------------------------------------------------------------
    def _tick_rate(self, manager: ManagerForLoop) -> None:
        windows = self.rate.windows
        self.rate.tick()
        if self.rate.windows != windows:
            requested = 1.0 / self.period_s
            blame = self._shortfall.window(self.rate.rate_hz, requested)
            budget = manager.bus_budget()
            if blame == 'bus':
                self._log.warning(
                    f'the bus cannot keep loop_rate {requested:g} Hz: measured '
                    f'{self.rate.rate_hz:.1f} Hz (bus limit {budget.rate_limit_hz:.0f} Hz); '
                    'running as fast as it allows')
            elif blame == 'machine':
                self._log.warning(
                    f'loop_rate {requested:g} Hz not reached: measured '
                    f'{self.rate.rate_hz:.1f} Hz while the bus had time to spare (the '
                    'machine is busy)')
        if time.monotonic() >= self._next_rate_log_s:
            self._log_rate(manager)

    def _log_rate(self, manager: ManagerForLoop) -> None:
        # A first report once the rate has settled, then one a minute.
        first = self._next_rate_log_s == 0.0
        self._next_rate_log_s = time.monotonic() + (3.0 if first else RATE_LOG_INTERVAL_S)
        if first:
            return
        budget = manager.bus_budget()
        self._log.info(
            f'measured loop rate {self.rate.rate_hz:.1f} Hz (requested '
            f'{1.0 / self.period_s:g} Hz, bus limit {budget.rate_limit_hz:.0f} Hz); '
            f'{manager.stats.read_failures} read failures, {manager.stats.retries} retries')
