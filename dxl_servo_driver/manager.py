"""
The manager: servos by joint name over one Bus, with batching and safety ordering.

It owns what the node must never get wrong: configuration applied and verified before anything
moves, goal = present before torque on, one packed read and one sync write per register per cycle,
refusals that write nothing, what a mode change resets re-applied, samples dated so a late reply
is never published as current, servos that restart on their own given their configuration back
step by step (never stalling the others), and every torque-on matched by a torque-off at the end.
No ROS here: the node calls these methods and publishes.

This is the facade the node uses; the parts in driver/ do the work, each handed what it needs.
Locks: `lock` (an RLock) serialises requests and the cycle; the goal queue has a small lock of
its own that commands take instead, so a command never waits for the bus. Order when both are
needed: `lock`, then the queue's. begin_read() holds `lock` until end_read() or abort_read().
"""

import threading
import time
from typing import Any, Callable, List, Optional, Sequence, Tuple

from dxl_servo_driver import state_block
from dxl_servo_driver.bus import Bus
from dxl_servo_driver.config import DriverConfig
from dxl_servo_driver.driver.cycle import Cycle
from dxl_servo_driver.driver.goals import Goal, Goals
from dxl_servo_driver.driver.link import Link
from dxl_servo_driver.driver.recovery import PortWatch, Recovery
from dxl_servo_driver.driver.services import Services
from dxl_servo_driver.driver.servo import (
    BLOCK, IDX_CANARY, IDX_EFFORT, IDX_HW_ERROR, IDX_MOVING, IDX_MOVING_STATUS, IDX_POSITION,
    IDX_PWM, IDX_TEMPERATURE, IDX_TICK, IDX_TORQUE, IDX_VELOCITY, IDX_VOLTAGE, Log,
    ManagerError, PortState, Result, Roster, Servo, StaleGuard)
from dxl_servo_driver.driver.setup import Setup
from dxl_servo_driver.errors import CommError, Interrupted, PortError
from dxl_servo_driver.protocol import RETURN_DELAY_UNIT_S
from dxl_servo_driver.serial_port import RawPort
from dxl_servo_driver.tasks import Task, TaskRunner
from dxl_servo_driver.transports import open_transport, PortFactory

__all__ = [
    'BLOCK', 'IDX_CANARY', 'IDX_EFFORT', 'IDX_HW_ERROR', 'IDX_MOVING', 'IDX_MOVING_STATUS',
    'IDX_POSITION', 'IDX_PWM', 'IDX_TEMPERATURE', 'IDX_TICK', 'IDX_TORQUE', 'IDX_VELOCITY',
    'IDX_VOLTAGE', 'Interrupted', 'Log', 'Manager', 'ManagerError', 'open_transport',
    'Result', 'Servo',
]


class Manager:
    """Servos by joint name on one bus."""

    def __init__(self, config: DriverConfig, info: Log = print, warn: Log = print,
                 error: Log = print, port_factory: PortFactory = open_transport,
                 clock: Callable[[], float] = time.monotonic,
                 should_stop: Callable[[], bool] = lambda: False) -> None:
        self._config = config
        self._info = info
        self._warn = warn
        roster = Roster(config.joints)
        self._roster = roster
        self.servos = roster.by_name
        self.order = roster.order
        # Serialises requests (services, topics, the cycle) over the manager's state.
        self.lock = threading.RLock()
        port = PortState()
        self._port = port
        self._stale = StaleGuard(warn, clock)
        # Transactions outside the cycle are tried this many times (lost replies happen);
        # should_stop is asked between them, so a signal stops configure and activate promptly.
        self._link = Link(max(1, config.ping_retries), should_stop, self._stale)
        # Late-bound: what a task's end means is recovery's, and recovery is built on the cycle,
        # which needs the tasks.
        self.tasks = TaskRunner(lambda task: self._recovery.task_done(task),
                                lambda task, exc: self._recovery.task_failed(task, exc), clock)
        self._goals = Goals(config, roster, self.tasks, port, clock, warn)
        self._cycle = Cycle(config, self.lock, roster, self._link, self.tasks, self._goals,
                            self._stale, lambda servo: self._recovery.restarted(servo), clock,
                            warn)
        self._setup = Setup(config, roster, self._link, clock, info, warn)
        self._recovery = Recovery(config, roster, self._link, self._setup, self._goals,
                                  self._cycle, self.tasks, port, clock, info, warn)
        self._ports = PortWatch(config, port_factory, port, roster, self._link, self._goals,
                                self._cycle, self.tasks, self._recovery, clock, info, error)
        self._services = Services(self.lock, roster, self._link, self._setup, self._goals,
                                  self._cycle, self._recovery, self.tasks, port, self._ports)

    # what the node reads and sets ---------------------------------------------------------
    @property
    def config(self) -> DriverConfig:
        """Return the configuration."""
        return self._config

    @config.setter
    def config(self, config: DriverConfig) -> None:
        # Runtime parameters (command_timeout) reach every part at once.
        self._config = config
        for part in (self._goals, self._cycle, self._setup, self._recovery, self._ports):
            part.config = config

    @property
    def bus(self) -> Optional[Bus]:
        """Return the open bus; None while the port is closed."""
        return self._link.bus

    @property
    def port(self) -> Optional[RawPort]:
        """Return the port the bus runs on."""
        return self._ports.port

    @property
    def sim_bus(self) -> Any:
        """Return the SimBus behind `port: sim` (None for hardware)."""
        return self._ports.sim_bus

    @property
    def _port_factory(self) -> PortFactory:
        return self._ports.factory

    @_port_factory.setter
    def _port_factory(self, factory: PortFactory) -> None:
        self._ports.factory = factory

    @property
    def should_stop(self) -> Callable[[], bool]:
        """Return what is asked between transactions at configure and activate."""
        return self._link.should_stop

    @should_stop.setter
    def should_stop(self, should_stop: Callable[[], bool]) -> None:
        self._link.should_stop = should_stop

    @property
    def port_lost(self) -> bool:
        """Return True while the port is lost (the cycle stops reading, reconnection is tried)."""
        return self._port.lost

    @property
    def port_error(self) -> str:
        """Return why the port was lost."""
        return self._port.error

    @property
    def reconnect_interval_s(self) -> float:
        """Return how often a lost port is tried again."""
        return self._ports.reconnect_interval_s

    @reconnect_interval_s.setter
    def reconnect_interval_s(self, interval_s: float) -> None:
        self._ports.reconnect_interval_s = interval_s

    @property
    def health_period_s(self) -> float:
        """Return how often the whole state block (health too) is read."""
        return self._cycle.health_period_s

    @health_period_s.setter
    def health_period_s(self, period_s: float) -> None:
        self._cycle.health_period_s = period_s

    @property
    def cycles(self) -> int:
        """Return the number of state reads completed."""
        return self._cycle.cycles

    @property
    def read_failures(self) -> int:
        """Return the number of servo reads that failed in the cycle."""
        return self._cycle.read_failures

    @property
    def stale_refused(self) -> int:
        """Return the number of samples refused as older than their request."""
        return self._stale.refused

    @property
    def retries(self) -> int:
        """Return the number of single-servo retries within a cycle."""
        return self._cycle.retries

    @property
    def retry_successes(self) -> int:
        """Return the number of those retries that got an answer."""
        return self._cycle.retry_successes

    @property
    def recoveries(self) -> int:
        """Return the number of hardware-error recoveries started."""
        return self._recovery.recoveries

    # configure / activate / stop ----------------------------------------------------------
    def configure(self) -> None:
        """Open the port, find and verify every servo, apply the configuration."""
        with self.lock:
            self._ports.connect()
            self._forget_clocks()
            try:
                self._setup.configure()
                self._cycle.refresh()
            except (PortError, CommError) as exc:
                raise ManagerError(f'configuration failed: {exc}') from None
            budget = self.bus_budget()
            self._info(
                f'bus limit for {len(self.active_servos())} servos at {self.config.baud_rate} bps '
                f'(return delay {self._link.io().return_delay_s * 1e6:.0f} us, latency timer '
                f'{self.config.latency_timer:g} ms): {budget.rate_limit_hz:.0f} Hz '
                f'({budget.bytes_per_cycle} bytes per cycle)')
            if budget.rate_limit_hz < self.config.loop_rate:
                self._warn(f'loop_rate {self.config.loop_rate:g} Hz is above what the bus can '
                           f'carry ({budget.rate_limit_hz:.0f} Hz): running as fast as the bus '
                           'allows')

    def _forget_clocks(self) -> None:
        # Nobody watched the servos since the last activation (or ever): any of them may have
        # restarted (a simulator: be a new one) with its Realtime Tick from 0.
        for servo in self.order:
            servo.tick.reset()

    def bus_budget(self) -> state_block.BusBudget:
        """Return what one cycle costs on this bus."""
        bus = self._link.bus
        rdt_raw = int(round((bus.return_delay_s if bus else 0.0005) / RETURN_DELAY_UNIT_S))
        return state_block.bus_budget(max(1, len(self.active_servos())), self.config.baud_rate,
                                      rdt_raw, self.config.latency_timer / 1000.0,
                                      fast=self._cycle.fast)

    @property
    def read_mode_in_use(self) -> str:
        """Return how the state is read now: 'sync' or 'fast_sync' (read_mode auto decides)."""
        return 'fast_sync' if self._cycle.fast else 'sync'

    @property
    def goal_slots_in_use(self) -> str:
        """Return how many servos take their goals through a goal slot, as 'k of n'."""
        active = self._roster.active()
        slotted = sum(servo.goal_slot is not None for servo in active)
        return f'{slotted} of {len(active)}'

    def active_servos(self) -> List[Servo]:
        """Return the servos that answered at configure."""
        return self._roster.active()

    def activate(self) -> None:
        """Goal = present for every servo, then torque on (if torque_on_start)."""
        with self.lock:
            self._forget_clocks()
            self._setup.activate(self.active_servos())
            self._goals.clear()
            self._cycle.want_full()

    def deactivate(self) -> List[Tuple[str, str]]:
        """
        Torque off (if torque_off_on_shutdown); pending goals and tasks dropped.

        Returns what could not be done: (joint, why) for each servo whose torque-off was not
        acknowledged (empty: every one was).
        """
        with self.lock:
            self._goals.clear()
            self.tasks.cancel_all('the node is stopping')
            self._cycle.refresh()
            if not self.config.torque_off_on_shutdown:
                return []
            return self.torque_off_all()

    def torque_off_all(self) -> List[Tuple[str, str]]:
        """Torque off every servo that may have torque on; return (joint, why) of the failures."""
        with self.lock:
            if self._link.bus is None:
                return [(s.name, 'the port is closed') for s in self.order if s.torque_maybe_on]
            lost = (self._port.error or 'no reason given') if self._port.lost else ''
            failures = []
            with self._link.uninterruptible():   # a signal must not cut it
                for servo in self.order:
                    if not (servo.online or servo.torque_maybe_on):
                        continue
                    if lost:
                        # Nothing reaches the servos: said, not tried (the port is closed).
                        if servo.torque_maybe_on:
                            failures.append((servo.name, f'the port is lost ({lost})'))
                        continue
                    try:
                        self._link.write(servo, 'torque_enable', 0)
                    except PortError as exc:
                        lost = str(exc)
                        failures.append((servo.name, f'the port is lost ({lost})'))
                    except CommError as exc:
                        failures.append((servo.name, str(exc)))
            return failures

    def close(self) -> None:
        """Close the port."""
        with self.lock:
            self._cycle.drop_read()
            if self._link.bus is not None:
                self._link.bus.close()
            self._link.bus = None

    # the cycle ----------------------------------------------------------------------------
    def read_states(self, full: Optional[bool] = None,
                    retry_until: Optional[float] = None) -> float:
        """Read every servo's state with one sync read; return its time (see Cycle)."""
        return self._cycle.read_states(full, retry_until)

    def begin_read(self, full: Optional[bool] = None) -> bool:
        """Put the sync read on the wire, holding the lock until end_read or abort_read."""
        return self._cycle.begin_read(full)

    def end_read(self, retry_until: Optional[float] = None) -> float:
        """Collect the sync read begun by begin_read(); return its monotonic time."""
        return self._cycle.end_read(retry_until)

    def abort_read(self) -> None:
        """Give up the sync read in flight, if any, and release the locks (idempotent)."""
        self._cycle.abort_read()

    def cycle_begin(self) -> bool:
        """begin_read() unless the port is lost; False when no read is in flight."""
        if self.port_lost:
            with self.lock:
                if not self._ports.reconnect():
                    return False
        try:
            return self.begin_read()
        except PortError as exc:
            with self.lock:
                self._ports.lose(exc)
            return False

    def cycle_end(self, retry_until: Optional[float] = None) -> bool:
        """end_read() of a cycle_begin(); False when the port was lost meanwhile."""
        try:
            self.end_read(retry_until)
        except PortError as exc:
            with self.lock:
                self._ports.lose(exc)
            return False
        return True

    def cycle_read(self, retry_until: Optional[float] = None) -> bool:
        """Read states unless the port is lost; False when nothing was read this cycle."""
        return self.cycle_begin() and self.cycle_end(retry_until)

    def cycle_write(self, tasks_until: Optional[float] = None) -> None:
        """Command timeouts, pending goals, recovery steps; port loss handled."""
        with self.lock:
            if self.port_lost or self._link.bus is None:
                return
            try:
                self.check_command_timeout()
                self.write_pending()
                self.recover_hardware_errors()
                if tasks_until is not None:
                    self.tasks.run(tasks_until)
            except PortError as exc:
                self._ports.lose(exc)

    def write_pending(self) -> int:
        """Write the goals queued since the last cycle: one sync write per register."""
        return self._cycle.write_pending()

    def check_command_timeout(self) -> None:
        """Velocity, current and pwm goals fall back to zero after command_timeout."""
        with self.lock:
            self._goals.check_timeout()

    def recover_hardware_errors(self) -> None:
        """With hardware_error_recovery: reboot a faulty servo alone, rate-limited, restored."""
        with self.lock:
            self._recovery.recover_hardware_errors()

    # commands and services ----------------------------------------------------------------
    def check_goals(self, kind: str, names: Sequence[str],
                    values: Sequence[float]) -> Tuple[Optional[List[Goal]], str]:
        """Validate and convert goals: (goals, '') or (None, reason); nothing is queued."""
        return self._goals.check(kind, names, values)

    def command(self, kind: str, names: Sequence[str], values: Sequence[float]) -> Result:
        """Queue goals (topic path): written by the next cycle's sync write."""
        return self._goals.command(kind, names, values)

    def command_now(self, kind: str, names: Sequence[str], values: Sequence[float]) -> Result:
        """Write goals at once (service path): answered after they were written."""
        return self._services.command_now(kind, names, values)

    def set_torque(self, names: Sequence[str], enable: bool) -> Result:
        """Torque on (goal = present first) or off."""
        return self._services.set_torque(names, enable)

    def set_operating_mode(self, names: Sequence[str], mode: str) -> Result:
        """Torque off, mode, what a mode change resets re-applied, goal = present, torque back."""
        return self._services.set_operating_mode(names, mode)

    def reboot(self, names: Sequence[str], wait: Optional[Callable[[List[Task]], None]] = None
               ) -> Result:
        """Reboot and restore; wait(tasks) blocks until the cycle ran them (else run here)."""
        return self._services.reboot(names, wait)

    def read_register(self, name: str, register: str) -> Tuple[Optional[int], str]:
        """Read one register by snake_case name or decimal address: (value, message)."""
        return self._services.read_register(name, register)

    def write_register(self, name: str, register: str, value: int) -> Result:
        """Write one register; EEPROM while torque is on is refused with the reason."""
        return self._services.write_register(name, register, value)
