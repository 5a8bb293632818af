"""
The manager: servos by joint name over one bus, the facade the node uses.

It owns what the node must never get wrong: configuration applied and verified before anything
moves, goal = present before torque on, one packed read and one sync write per cycle, refusals
that write nothing, what a mode change resets re-applied, samples dated so a late reply is never
published as current, servos that restart on their own given their configuration back step by
step (never stalling the others), and every torque-on matched by a torque-off at the end. No
ROS here: the node calls these methods and publishes.

The parts in driver/ do the work; each is handed the shared Context (driver/context.py) and the
parts it uses, built here in the order they depend on one another. Locks: the context's `lock`
(re-entrant, and handed to a caller waiting for it before the next read: SharedLock)
serialises requests and the cycle; the goal queue has a small lock of its own that commands
take instead, so a command never waits for the bus. Order when both are needed: the context's
lock, then the queue's. A read in flight holds the context's lock from cycle_begin()
to cycle_end() or abort_read() (driver/cycle.ReadInFlight).
"""

import time
from typing import Callable, Dict, List, Optional, Sequence, Tuple, Type, TYPE_CHECKING

from dxl_servo_driver.bus import Bus
from dxl_servo_driver.config import DriverConfig
from dxl_servo_driver.driver import state_block
from dxl_servo_driver.driver.context import Context, Logs, SharedLock, Stats
from dxl_servo_driver.driver.cycle import Cycle, SILENT_AFTER_FAILURES
from dxl_servo_driver.driver.goals import Goals
from dxl_servo_driver.driver.link import Link
from dxl_servo_driver.driver.pairs import Pairs
from dxl_servo_driver.driver.port_watch import PortWatch
from dxl_servo_driver.driver.recovery import Recovery
from dxl_servo_driver.driver.services import Services
from dxl_servo_driver.driver.servo import (
    BLOCK, IDX_CANARY, IDX_EFFORT, IDX_HW_ERROR, IDX_MOVING, IDX_MOVING_STATUS, IDX_POSITION,
    IDX_PWM, IDX_TEMPERATURE, IDX_TICK, IDX_TORQUE, IDX_VELOCITY, IDX_VOLTAGE, Log,
    ManagerError, PortState, Result, Roster, Servo, StaleGuard)
from dxl_servo_driver.driver.setup import Setup
from dxl_servo_driver.driver.tasks import Task, TaskRunner
from dxl_servo_driver.driver.transports import open_transport, PortFactory, Transport
from dxl_servo_driver.errors import CommError, Interrupted, PortError, Refused
from dxl_servo_driver.port import RawPort
from dxl_servo_driver.protocol import RETURN_DELAY_UNIT_S

if TYPE_CHECKING:
    from dxl_servo_driver.driver.roles import ManagerForFollower, ManagerForLoop

__all__ = [
    'BLOCK', 'IDX_CANARY', 'IDX_EFFORT', 'IDX_HW_ERROR', 'IDX_MOVING', 'IDX_MOVING_STATUS',
    'IDX_POSITION', 'IDX_PWM', 'IDX_TEMPERATURE', 'IDX_TICK', 'IDX_TORQUE', 'IDX_VELOCITY',
    'IDX_VOLTAGE', 'Interrupted', 'Log', 'Manager', 'ManagerError', 'open_transport',
    'PortFactory', 'Result', 'Servo', 'Stats',
]


def _transactions(budget: state_block.BusBudget) -> str:
    """Return a cycle's transactions as 'sync read, 12 x read (Protocol 1.0), sync write'."""
    counts: Dict[str, int] = {}
    for each in budget.transactions:
        counts[each.what] = counts.get(each.what, 0) + 1
    return ', '.join(what if count == 1 else f'{count} x {what}'
                     for what, count in counts.items()) or 'nothing read'


class Manager:
    """Servos by joint name on one bus."""

    def __init__(self, config: DriverConfig, info: Log = print, warn: Log = print,
                 error: Log = print, port_factory: PortFactory = open_transport,
                 clock: Callable[[], float] = time.monotonic,
                 should_stop: Callable[[], bool] = lambda: False) -> None:
        roster = Roster(config.joints)
        stale = StaleGuard(warn, clock)
        # Transactions outside the cycle are tried ping_retries times (lost replies happen);
        # should_stop is asked between them, so a signal stops configure and activate promptly.
        link = Link(max(1, config.ping_retries), should_stop, stale)
        ctx = Context(config=config, roster=roster, link=link, tasks=TaskRunner(clock),
                      port=PortState(), stale=stale, clock=clock,
                      log=Logs(info, warn, error), lock=SharedLock())
        self._ctx = ctx
        self.lock = ctx.lock
        self.servos = roster.by_name
        self.order = roster.order        # every servo on the bus (second servos included)
        self.joints = roster.joints      # one servo per joint: what ROS sees
        self.secondary = roster.secondary
        self.tasks = ctx.tasks
        self._goals = Goals(ctx)
        self._cycle = Cycle(ctx, self._goals)
        self._setup = Setup(ctx)
        self._recovery = Recovery(ctx, self._setup, self._goals, self._cycle)
        self._ports = PortWatch(ctx, port_factory, self._recovery, self._goals, self._cycle)
        self._services = Services(ctx, self._setup, self._goals, self._cycle, self._recovery,
                                  self._ports)
        self.pairs = Pairs(ctx, lambda names: self._services.set_torque(names, False))

    # what the node reads and sets ---------------------------------------------------------
    @property
    def config(self) -> DriverConfig:
        """Return the configuration."""
        return self._ctx.config

    @config.setter
    def config(self, config: DriverConfig) -> None:
        # Runtime parameters (command_timeout) reach every part at once: they read it here.
        self._ctx.config = config

    @property
    def bus(self) -> Optional[Bus]:
        """Return the open bus; None while the port is closed."""
        return self._ctx.link.bus

    @property
    def port(self) -> Optional[RawPort]:
        """Return the port the bus runs on."""
        return self._ports.port

    @property
    def transport(self) -> Optional[Transport]:
        """Return the transport the port came from (None before the first configure)."""
        return self._ports.transport

    @property
    def port_lost(self) -> bool:
        """Return True while the port is lost (the cycle stops reading, reconnection is tried)."""
        return self._ctx.port.lost

    @property
    def port_error(self) -> str:
        """Return why the port was lost."""
        return self._ctx.port.error

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
    def stats(self) -> Stats:
        """Return what the cycle and recovery counted so far."""
        cycle = self._cycle
        samples = cycle.samples
        return Stats(cycles=cycle.cycles, read_failures=samples.read_failures,
                     retries=samples.retries, retry_successes=samples.retry_successes,
                     stale_refused=self._ctx.stale.refused,
                     recoveries=self._recovery.recoveries)

    # configure / activate / stop ----------------------------------------------------------
    def configure(self) -> None:
        """Open the port, find and verify every servo, apply the configuration."""
        with self.lock:
            self._ports.connect()
            self._forget_clocks()
            try:
                with self._ctx.link.patient():
                    self._setup.configure()
                self._cycle.refresh()
            except (PortError, CommError) as exc:
                raise ManagerError(f'configuration failed: {exc}') from None
            budget = self.bus_budget()
            self._ctx.log.info(
                f'bus limit for {len(self.active_servos())} servos at {self.config.baud_rate} bps '
                f'(return delay {self._ctx.link.io().return_delay_s * 1e6:.0f} us, latency timer '
                f'{self.latency_timer_s * 1000.0:g} ms): {budget.rate_limit_hz:.0f} Hz '
                f'({budget.bytes_per_cycle} bytes per cycle: {_transactions(budget)})')
            if budget.rate_limit_hz < self.config.loop_rate:
                self._ctx.log.warn(
                    f'loop_rate {self.config.loop_rate:g} Hz is above what the bus can carry '
                    f'({budget.rate_limit_hz:.0f} Hz): running as fast as the bus allows')

    def _forget_clocks(self) -> None:
        # Nobody watched the servos since the last activation (or ever): any of them may have
        # restarted (a simulator: be a new one) with its Realtime Tick from 0.
        for servo in self.order:
            servo.tick.reset()

    def bus_budget(self) -> state_block.BusBudget:
        """Return what one cycle costs on this bus."""
        bus = self._ctx.link.bus
        rdt_raw = int(round((bus.return_delay_s if bus else 0.0005) / RETURN_DELAY_UNIT_S))
        plan = self._cycle.wire_plan()
        if not plan:   # nobody to read: what one servo would cost
            return state_block.bus_budget(1, self.config.baud_rate, rdt_raw,
                                          self.latency_timer_s, fast=self._cycle.plan.fast)
        return state_block.plan_budget(plan, self.config.baud_rate, rdt_raw,
                                       self.latency_timer_s)

    @property
    def latency_timer_s(self) -> float:
        """
        Return the adapter's latency timer, as configure found it (driver/adapter.py).

        Linux's word for it, or the one a ping's answer implies; before that (or where nothing
        answered) the bus's timer in force, else the file's. What the bus limit counts.
        """
        link = self._ctx.link
        if link.adapter_latency_s is not None:
            return link.adapter_latency_s
        return (link.bus.latency_timer_s if link.bus is not None
                else self.config.latency_timer / 1000.0)

    @property
    def read_mode_in_use(self) -> str:
        """Return how the state is read now: 'sync' or 'fast_sync' (read_mode auto decides)."""
        return 'fast_sync' if self._cycle.plan.fast else 'sync'

    @property
    def goal_slots_in_use(self) -> str:
        """Return how many servos take their goals through a goal slot, as 'k of n'."""
        active = self._ctx.roster.active()
        slotted = sum(servo.goal_slot is not None for servo in active)
        return f'{slotted} of {len(active)}'

    def active_servos(self) -> List[Servo]:
        """Return the servos that answered at configure."""
        return self._ctx.roster.active()

    def activate(self) -> None:
        """Goal = present for every servo, then torque on (if torque_on_start)."""
        with self.lock:
            self._forget_clocks()
            with self._ctx.link.patient():
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
            if self._ctx.link.bus is None:
                return [(s.name, 'the port is closed') for s in self.order if s.torque_maybe_on]
            lost = (self._ctx.port.error or 'no reason given') if self._ctx.port.lost else ''
            failures = []
            with self._ctx.link.uninterruptible():   # a signal must not cut it
                for servo in self.order:
                    if not (servo.online or servo.torque_maybe_on):
                        continue
                    if lost:
                        # Nothing reaches the servos: said, not tried (the port is closed).
                        if servo.torque_maybe_on:
                            failures.append((servo.name, f'the port is lost ({lost})'))
                        continue
                    try:
                        self._ctx.link.write(servo, 'torque_enable', 0)
                    except PortError as exc:
                        lost = str(exc)
                        failures.append((servo.name, f'the port is lost ({lost})'))
                    except CommError as exc:
                        failures.append((servo.name, str(exc)))
            return failures

    def close(self) -> None:
        """Close the port."""
        with self.lock:
            self._cycle.abort_read()   # only this thread's can be in flight: it holds lock
            if self._ctx.link.bus is not None:
                self._ctx.link.bus.close()
            self._ctx.link.bus = None

    # the cycle ----------------------------------------------------------------------------
    def cycle_begin(self, full: Optional[bool] = None,
                    stamp: Optional[Callable[[], None]] = None) -> bool:
        """
        Put the cycle's state read on the wire unless the port is lost; False when none is.

        full: read the whole state block (health too); None: when it is due. The read holds
        the lock until cycle_end() or abort_read(), in the same thread. stamp: called right
        before the read goes on the wire, the lock held (the caller's stamp of its samples).
        """
        if self.port_lost:
            with self.lock:
                if not self._ports.reconnect():
                    return False
        try:
            return self._cycle.begin_read(full, stamp)
        except PortError as exc:
            with self.lock:
                self._ports.lose(exc)
            return False

    def cycle_end(self, retry_until: Optional[float] = None,
                  chain: Optional[Callable[[], None]] = None) -> bool:
        """
        Collect the read of cycle_begin(); False when the port was lost meanwhile.

        A servo whose reply was lost or corrupted is read again on its own while the clock is
        before retry_until (the cycle's budget); a servo found restarted on its own is handed
        to recovery. chain: the next read may go on the wire at once, before this one's samples
        are taken, when nothing waits to be written first (driver/cycle.Cycle.end_read; chain()
        is called right before it goes); `read_in_flight` then says so, and that read is
        collected by the next cycle_end, with no cycle_write between.
        """
        try:
            self._cycle.end_read(retry_until, chain)
        except PortError as exc:
            with self.lock:
                self._ports.lose(exc)
            return False
        with self.lock:
            samples = self._cycle.samples
            restarted, samples.restarted = samples.restarted, []
            for servo in restarted:
                self._recovery.restarted(servo)
        return True

    def abort_read(self) -> None:
        """Give up the sync read in flight, if any, and release the locks (idempotent)."""
        self._cycle.abort_read()

    @property
    def read_in_flight(self) -> bool:
        """Return True while a cycle read is on the wire (begun, or chained by cycle_end)."""
        return self._cycle.reading

    def cycle_write(self, tasks_until: Optional[float] = None) -> None:
        """Command timeouts, pending goals, recovery steps; port loss handled."""
        with self.lock:
            if self.port_lost or self._ctx.link.bus is None:
                return
            try:
                # The parts themselves: their public faces would take the lock held here again.
                self._goals.check_timeout()
                self._goals.check_ranges()
                self.pairs.check()
                self._cycle.write_pending()
                self._recovery.recover_hardware_errors()
                if tasks_until is not None:
                    _, ended = self.tasks.run(tasks_until)
                    for task, error in ended:
                        self._recovery.ended(task, error)
            except PortError as exc:
                self._ports.lose(exc)

    def write_pending(self) -> int:
        """Write the goals queued since the last cycle: one sync write per register."""
        return self._cycle.write_pending()

    def check_command_timeout(self) -> None:
        """Velocity, current and pwm goals fall back to zero after command_timeout or at an end."""
        with self.lock:
            self._goals.check_timeout()
            self._goals.check_ranges()

    def recover_hardware_errors(self) -> None:
        """With hardware_error_recovery: reboot a faulty servo alone, rate-limited, restored."""
        with self.lock:
            self._recovery.recover_hardware_errors()

    # commands and services ----------------------------------------------------------------
    def joint_trouble(self, name: str) -> str:
        """Return why a joint cannot follow goals now ('' when it can): it ends a trajectory."""
        servo = self.servos.get(name)
        if servo is None or not servo.online:
            return 'is not on the bus'
        if self._ctx.port.lost:
            return f'cannot be driven: the port is lost ({self._ctx.port.error})'
        tripped = self.pairs.trouble(name)
        if tripped:
            return f'is off: {tripped}'
        second = self.secondary.get(name)
        if second is not None:
            why = self._servo_trouble(second)
            if why:
                return f'has a second servo that {why}'
        return self._servo_trouble(servo)

    def _servo_trouble(self, servo: Servo) -> str:
        if not servo.online:
            return 'is not on the bus'
        if servo.joint.refusal():
            return 'takes no goals: ' + servo.joint.refusal()
        if servo.name in self.tasks:
            return f'is {servo.status or "busy"}'
        if servo.consecutive_failures >= SILENT_AFTER_FAILURES:
            return f'stopped answering ({servo.consecutive_failures} reads in a row missed)'
        if servo.state is not None and servo.state[IDX_HW_ERROR]:
            errors = ', '.join(servo.model.decode_hardware_errors(servo.state[IDX_HW_ERROR]))
            return f'latched a hardware error ({errors}): its torque is off'
        return ''

    def check_goals(self, kind: str, names: Sequence[str], values: Sequence[float]) -> Result:
        """Validate and convert goals (Result.value: the goals); nothing is queued."""
        try:
            return Result(True, '', self._goals.check(kind, names, values))
        except Refused as exc:
            return Result(False, str(exc))

    def command(self, kind: str, names: Sequence[str], values: Sequence[float],
                owner: str = '') -> Result:
        """Queue goals (topic path): written by the next cycle's sync write."""
        return self._goals.command(kind, names, values, owner)

    def hold(self, names: Sequence[str], owner: str, why: str) -> None:
        """Let only owner's goals reach these joints; others' are refused: 'joint <name> why'."""
        with self._goals.lock:
            for name in names:
                self._goals.held[name] = (owner, why)

    def release(self, owner: str) -> None:
        """Let everyone command the joints owner held."""
        with self._goals.lock:
            for name in [n for n, (o, _) in self._goals.held.items() if o == owner]:
                del self._goals.held[name]

    def holder(self, name: str) -> str:
        """Return why a joint takes no goals but its commander's ('' when it takes anyone's)."""
        held = self._goals.held.get(name)
        return '' if held is None else f'joint {name!r} {held[1]}'

    def command_now(self, kind: str, names: Sequence[str], values: Sequence[float]) -> Result:
        """Write goals at once (service path): answered after they were written."""
        return self._services.command_now(kind, names, values)

    def set_torque(self, names: Sequence[str], enable: bool) -> Result:
        """Torque on (goal = present first) or off; on forgives a pair that disagreed."""
        result = self._services.set_torque(names, enable)
        if enable and result.success:
            self.pairs.clear(names)
        return result

    def set_operating_mode(self, names: Sequence[str], mode: str) -> Result:
        """Torque off, mode, what a mode change resets re-applied, goal = present, torque back."""
        return self._services.set_operating_mode(names, mode)

    def reboot(self, names: Sequence[str], wait: Optional[Callable[[List[Task]], None]] = None
               ) -> Result:
        """Reboot and restore; wait(tasks) blocks until the cycle ran them (else run here)."""
        return self._services.reboot(names, wait)

    def read_register(self, name: str, register: str) -> Result:
        """Read one register by snake_case name or decimal address (Result.value: the value)."""
        return self._services.read_register(name, register)

    def write_register(self, name: str, register: str, value: int) -> Result:
        """Write one register; EEPROM while torque is on is refused with the reason."""
        return self._services.write_register(name, register, value)


if TYPE_CHECKING:
    # The manager is what the cycle loop and the follower are given (driver/roles.py).
    _FOR_LOOP: Type[ManagerForLoop] = Manager
    _FOR_FOLLOWER: Type[ManagerForFollower] = Manager
