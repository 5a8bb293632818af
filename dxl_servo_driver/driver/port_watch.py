"""
The port: opened at configure, watched for loss, back when the device returns.

What a loss means for the device is the transport's (transports.py): a real adapter is closed
and opened again as a new device, the simulated one is the same port plugged back. Here: what
it means for the driver. Goals and tasks are dropped, nothing is fresh, the cycle stops its bus
work (the node stays up), and once the port is back every servo rejoins on its own.
"""

from typing import Optional

from dxl_servo_driver.bus import Bus, BusTrace, FRAMERS
from dxl_servo_driver.driver.context import Context
from dxl_servo_driver.driver.cycle import Cycle
from dxl_servo_driver.driver.goals import Goals
from dxl_servo_driver.driver.recovery import Recovery, RESTORING_TASKS
from dxl_servo_driver.driver.servo import ManagerError
from dxl_servo_driver.driver.transports import PortFactory, Transport
from dxl_servo_driver.errors import CommError, PortError
from dxl_servo_driver.port import RawPort


RECONNECT_INTERVAL_S = 1.0   # a lost port is tried again this often


class PortWatch:
    """The port the bus runs on, and what its loss and return mean."""

    def __init__(self, ctx: Context, factory: PortFactory, recovery: Recovery, goals: Goals,
                 cycle: Cycle) -> None:
        self._ctx = ctx
        self._factory = factory
        self._recovery = recovery
        self._goals = goals
        self._cycle = cycle
        self.transport: Optional[Transport] = None
        self.port: Optional[RawPort] = None
        self.reconnect_interval_s = RECONNECT_INTERVAL_S
        self._next_reconnect_s = 0.0

    def connect(self) -> None:
        """Open the port and the bus on it; ManagerError when the port cannot be opened."""
        config = self._ctx.config
        try:
            self.transport = self._factory(config)
            self.port = self.transport.open_port()
        except PortError as exc:
            raise ManagerError(str(exc)) from None
        # A reconnection keeps the latency timer configure found (driver/adapter.py).
        before = self._ctx.link.bus
        latency_s = (before.latency_timer_s if before is not None
                     else config.latency_timer / 1000.0)
        try:
            trace = (BusTrace(config.trace, config.baud_rate, f'port {config.port}')
                     if config.trace else None)
        except OSError as exc:
            self.port.close()
            raise ManagerError(f'trace {config.trace!r} cannot be written: {exc}') from None
        bus = Bus(self.port, config.baud_rate, latency_timer_s=latency_s,
                  framer=FRAMERS[config.protocol])
        bus.trace_to(trace)
        for servo in self._ctx.roster.order:
            bus.speak(servo.servo_id, FRAMERS[servo.joint.protocol])
        self._ctx.link.bus = bus
        self._ctx.port.lost = False
        self._ctx.port.error = ''

    def lose(self, exc: PortError) -> None:
        """Take the port as gone: goals and tasks dropped, nothing fresh, reconnection due."""
        state = self._ctx.port
        if state.lost:
            return
        state.lost = True
        state.error = str(exc)
        self._goals.clear()
        cut_short = {task.joint for task in self._ctx.tasks.tasks()
                     if task.kind in RESTORING_TASKS}
        self._ctx.tasks.cancel_all('the port was lost')
        for servo in self._ctx.roster.order:
            servo.fresh = False
            if servo.name in cut_short or servo.status in ('restoring', 'rebooting'):
                servo.restore_due = True
            servo.status = ''
        self._cycle.refresh()
        self._ctx.log.error(f'{self._ctx.config.port}: {exc}. The node stays up and reconnects '
                            'when the device returns; pending goals were dropped.')
        if self.transport is not None and self.port is not None:
            self.transport.release(self.port)
        self._next_reconnect_s = self._ctx.clock() + self.reconnect_interval_s

    def reconnect(self) -> bool:
        """
        Try to get the port back; True when it is.

        Every servo then rejoins on its own (a task each): one that kept its power goes on
        holding what it held, one that lost it is restored to hold where it is, and one that
        does not answer is probed every second without holding up the others.
        """
        now = self._ctx.clock()
        if now < self._next_reconnect_s or self.transport is None or self.port is None:
            return False
        self._next_reconnect_s = now + self.reconnect_interval_s
        bus = self._ctx.link.io()
        try:
            self.port = self.transport.reopen(self.port)
        except (PortError, CommError, OSError):
            return False
        bus.attach(self.port)
        state = self._ctx.port
        state.lost = False
        state.error = ''
        self._cycle.want_full()
        bus.mark_dirty()
        active = self._ctx.roster.active()
        for servo in active:
            self._recovery.start(servo, 'rejoin', self._recovery.rejoin(servo))
        self._ctx.log.info(f'{self._ctx.config.port}: port back; checking {len(active)} servos')
        return True
