"""
The bus cycle runner: read, write goals, step recovery, publish, pace; until stopped.

It runs in its own thread at loop_rate (or, with cycle_driver timer, from an executor timer),
so it never waits on the executor. Any exception is logged, counted and survived; a
BaseException ends the cycle and is kept in `failure` for the node to go to its error state.

There is never more than one cycle thread: start() refuses while the thread of an earlier
start is alive (a stop that timed out keeps it on record, it is never forgotten), and each
thread runs only while its generation is the runner's latest, so one left behind ends at its
next cycle instead of reading beside the new one. `cycle_threads` counts the live ones.
"""

import threading
import time
import traceback
from typing import Any, Callable, List, Optional, Protocol

from dxl_servo_driver.manager import Manager
from dxl_servo_driver.ros.diagnostics import CycleFacts
from dxl_servo_driver.ros.rates import RateMeter, Shortfall
from dxl_servo_driver.timerslack import fine_timer_slack

RATE_LOG_INTERVAL_S = 60.0


class Host(Protocol):
    """What the runner needs of the node."""

    manager: Manager

    def get_logger(self) -> Any:
        """Return the node's logger."""

    def get_clock(self) -> Any:
        """Return the node's clock (stamps of the samples)."""

    def create_timer(self, period_s: float, callback: Callable[[], None]) -> Any:
        """Create an executor timer."""

    def destroy_timer(self, timer: Any) -> Any:
        """Destroy an executor timer."""


class CycleRunner:
    """Drives the manager's cycle at the loop rate and measures it."""

    def __init__(self, host: Host, loop_rate_hz: float,
                 publish: Callable[[Any, bool], None],
                 prepare: Callable[[float], None] = lambda now_s: None,
                 may_chain: Callable[[], bool] = lambda: False) -> None:
        self._host = host
        self._publish = publish
        # Called right before each cycle's goal write (trajectory sampling).
        self._prepare = prepare
        # Whether prepare has nothing to do (no trajectory, no gripper goal): the next read may
        # then go on the wire as soon as the last came back (Manager.cycle_end's chain).
        self._may_chain = may_chain
        self._stop = threading.Event()
        self._wake = threading.Event()     # cuts the cycle's sleep short (stop, new loop_rate)
        self.thread: Optional[threading.Thread] = None
        self._generation = 0
        self._started: List[threading.Thread] = []   # every cycle thread not known ended
        self._timer: Any = None
        self.rate = RateMeter()
        self._shortfall = Shortfall()
        self.period_s = 1.0 / loop_rate_hz
        self._period_changed = False
        self.bus_cycle_s = 0.0
        self._read_stamp = 0   # ROS time of the read in flight, ns
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
        """Start cycling: in a thread (`thread`) or from an executor timer (`timer`)."""
        if self.running:
            raise RuntimeError('the bus cycle of the last activation has not ended yet')
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
            self._timer = self._host.create_timer(self.period_s, self._timer_cycle)
        else:
            self.thread = threading.Thread(target=self._run, args=(self._generation,),
                                           name='dxl_bus_cycle', daemon=True)
            self._started.append(self.thread)
            self.thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop cycling and wait for the thread (never from the thread itself)."""
        self._generation += 1   # a thread that misses the stop event ends at its next cycle
        self._stop.set()
        self._wake.set()
        if self._timer is not None:
            self._host.destroy_timer(self._timer)
            self._timer = None
        if self.thread is not None:
            if self.thread is not threading.current_thread():
                self.thread.join(timeout=timeout_s)
                if self.thread.is_alive():
                    # Kept in _started: no activation starts another beside it.
                    self._host.get_logger().error(
                        f'the bus cycle did not stop within {timeout_s:g} s')
            self.thread = None

    def set_rate(self, hz: float) -> None:
        """Take a new loop_rate at once (the sleep under way is cut short)."""
        self.period_s = 1.0 / hz
        self._period_changed = True
        self._shortfall.reset()
        self._wake.set()
        if self._timer is not None:
            self._host.destroy_timer(self._timer)
            self._timer = self._host.create_timer(self.period_s, self._timer_cycle)

    def facts(self) -> CycleFacts:
        """Return what the diagnostics say of the cycle."""
        return CycleFacts(self.rate.rate_hz, 1.0 / self.period_s,
                          time.monotonic() - self.last_cycle_s, self.cycle_errors, self.failure,
                          self.cycle_threads)

    # the cycle ------------------------------------------------------------------------------
    def _run(self, generation: int) -> None:
        """Run the bus cycle in its thread; if it ever fails for good, say so and keep why."""
        # Its sleeps (until the replies are due, until the next cycle) end on time, not up to
        # 50 us later.
        fine_timer_slack()
        try:
            self._loop(generation)
        except BaseException as exc:  # noqa: B902 - never a silent death of the cycle
            self.failure = exc
            self._host.manager.abort_read()
            self._host.get_logger().fatal(
                f'the bus cycle stopped: {exc!r}; going to the error state (torque off)\n'
                + ''.join(traceback.format_exception(exc)))

    def _loop(self, generation: int) -> None:
        """
        Read, write goals, step recovery, publish, pace; until stopped.

        When the next cycle is due at once (the loop runs as fast as the bus allows), the next
        read goes on the wire before this cycle is published, so publishing overlaps the bus
        transaction instead of adding to it; and when nothing is to be written before it (no
        goal, task, trajectory), as soon as the last read's block came back clean, before its
        samples are taken (chained): the bus waits on no Python. A chained cycle writes
        nothing; its command timeouts are checked, and what they queue goes out at the next.
        Any exception is logged, counted and survived.
        """
        manager = self._host.manager
        next_s = time.monotonic()
        reading = False
        pipelined = False
        while not self._stop.is_set() and generation == self._generation:
            try:
                if not pipelined:
                    reading = self._begin()
                stamp, began_s = self._read_stamp, self._read_began_s
                # Chained only while the loop runs flat out (the next cycle due by the time this
                # read ends, as for pipelining) and nothing is to be prepared.
                chain = (pipelined and next_s + self.period_s - time.monotonic()
                         <= self.bus_cycle_s and self._may_chain())
                ok = reading and self._end(began_s, chain)
                chained = chain and manager.read_in_flight
                reading = chained
                period = self.period_s
                next_s += period
                now = time.monotonic()
                if next_s < now - period:
                    next_s = now   # behind: run as fast as the bus allows, without a backlog
                if chained:
                    manager.check_command_timeout()   # queues only: written next cycle
                else:
                    self._prepare(now)
                    manager.cycle_write(tasks_until=next_s - self.bus_cycle_s)
                self._shortfall.add_cycle(time.monotonic() - began_s)
                pipelined = chained or next_s - time.monotonic() <= self.bus_cycle_s
                if pipelined and not chained:
                    reading = self._begin()
                self._publish(stamp, ok)
            except Exception as exc:  # noqa: B902 - the cycle must survive anything
                self.cycle_errors += 1
                manager.abort_read()
                reading = pipelined = False
                self._host.get_logger().error(f'cycle failed: {exc!r}',
                                              throttle_duration_sec=2.0)
                self._stop.wait(0.05)
                next_s = time.monotonic()
            self.last_cycle_s = time.monotonic()
            self._tick_rate()
            if not pipelined:
                delay = next_s - time.monotonic()
                if delay > 0.0 and self._wake.wait(delay):
                    self._wake.clear()
                if self._period_changed:
                    self._period_changed = False
                    next_s = time.monotonic()
        manager.abort_read()   # never leave the bus held

    def _begin(self) -> bool:
        """Stamp and start a read; False when nothing is in flight (port lost, no servo)."""
        # Stamped with the lock held, right before the request: a service's transaction may
        # hold the bus for tens of milliseconds first.
        if self._host.manager.cycle_begin(stamp=self._stamp):
            return True
        self._stamp()
        return False

    def _stamp(self) -> None:
        """Take the time of the read about to go on the wire."""
        # In nanoseconds: the joint_states bytes take it as it is (messages.JointTable).
        clock = self._host.get_clock()
        # The ROS clock is the system clock (CLOCK_REALTIME, as time.time_ns) unless sim time
        # is active: read directly, it costs a tenth of building an rclpy Time every cycle.
        self._read_stamp = (clock.now().nanoseconds if clock.ros_time_is_active
                            else time.time_ns())
        self._read_began_s = time.monotonic()

    def _end(self, began_s: float, chain: bool = False) -> bool:
        # Lost or corrupted replies are read again while the cycle has time (or twice the bus
        # time when the loop runs as fast as the bus allows).
        retry_until = began_s + max(0.9 * self.period_s, 2.0 * self.bus_cycle_s)
        return self._host.manager.cycle_end(retry_until, self._stamp if chain else None)

    def _timer_cycle(self) -> None:
        manager = self._host.manager
        try:
            began = self._begin()
            ok = began and self._end(self._read_began_s)
            now = time.monotonic()
            self._prepare(now)
            manager.cycle_write(tasks_until=now + 0.5 * self.period_s)
            self._shortfall.add_cycle(time.monotonic() - self._read_began_s)
            self._publish(self._read_stamp, ok)
        except Exception as exc:  # noqa: B902 - the cycle must survive anything
            self.cycle_errors += 1
            manager.abort_read()
            self._host.get_logger().error(f'cycle failed: {exc!r}', throttle_duration_sec=2.0)
        self.last_cycle_s = time.monotonic()
        self._tick_rate()

    def _tick_rate(self) -> None:
        windows = self.rate.windows
        self.rate.tick()
        log = self._host.get_logger()
        if self.rate.windows != windows:
            requested = 1.0 / self.period_s
            blame = self._shortfall.window(self.rate.rate_hz, requested)
            budget = self._host.manager.bus_budget()
            if blame == 'bus':
                log.warning(
                    f'the bus cannot keep loop_rate {requested:g} Hz: measured '
                    f'{self.rate.rate_hz:.1f} Hz (bus limit {budget.rate_limit_hz:.0f} Hz); '
                    'running as fast as it allows')
            elif blame == 'machine':
                log.warning(
                    f'loop_rate {requested:g} Hz not reached: measured '
                    f'{self.rate.rate_hz:.1f} Hz while the bus had time to spare (the '
                    'machine is busy)')
        if time.monotonic() >= self._next_rate_log_s:
            self._log_rate()

    def _log_rate(self) -> None:
        # A first report once the rate has settled, then one a minute.
        first = self._next_rate_log_s == 0.0
        self._next_rate_log_s = time.monotonic() + (3.0 if first else RATE_LOG_INTERVAL_S)
        if first:
            return
        manager = self._host.manager
        budget = manager.bus_budget()
        self._host.get_logger().info(
            f'measured loop rate {self.rate.rate_hz:.1f} Hz (requested '
            f'{1.0 / self.period_s:g} Hz, bus limit {budget.rate_limit_hz:.0f} Hz); '
            f'{manager.stats.read_failures} read failures, {manager.stats.retries} retries')
