"""
What every part of the driver shares: one context, handed to each part at construction.

The configuration (replaced whole when a runtime parameter changes: every part reads it from
here, so none keeps a stale copy), the servos (Roster), the link to the bus, the tasks in
progress, whether the port is lost, the guard that dates samples, the clock, the log and the
lock that serialises requests with the cycle.
"""

from dataclasses import dataclass
import threading
from typing import Any, Callable

from dxl_servo_driver.config import DriverConfig
from dxl_servo_driver.driver.link import Link
from dxl_servo_driver.driver.servo import Log, PortState, Roster, StaleGuard
from dxl_servo_driver.driver.tasks import TaskRunner


# The C re-entrant lock's type (threading.RLock is a factory, and typeshed names no such class):
# a subclass keeps its release and its fast acquire in C, with no Python frame more.
_CRLock: Any = type(threading.RLock())
_rlock_acquire = _CRLock.acquire


class SharedLock(_CRLock):
    """
    The re-entrant lock of the context, which the cycle hands to whoever waits for it.

    Python's locks are not fair: a cycle running flat out lets the lock go and takes it again
    before a service's thread woken by the release is even scheduled, so a service (a register
    read, a goal written at once) would wait out hundreds of bus cycles for its turn. A caller
    that has to wait is counted (arrived, then served once it holds the lock); the cycle chains
    no read while anyone waits (`waiting`), and lets those who wait in before it starts a read
    (`let_waiting_in`). Releasing is the RLock's own.
    """

    def __init__(self) -> None:
        super().__init__()
        self._turns = threading.Condition(threading.Lock())
        self._arrived = 0
        self._served = 0

    def acquire(self, blocking: bool = True, timeout: float = -1.0) -> bool:
        """Take the lock (as threading.RLock.acquire); a caller that must wait is counted."""
        if _rlock_acquire(self, False):
            return True
        if not blocking:
            return False
        with self._turns:
            self._arrived += 1
        try:
            return _rlock_acquire(self, True, timeout)
        finally:
            with self._turns:
                self._served += 1
                self._turns.notify_all()

    __enter__ = acquire

    @property
    def waiting(self) -> int:
        """Return how many callers wait for the lock now."""
        return self._arrived - self._served

    def let_waiting_in(self, timeout_s: float) -> None:
        """
        Wait, not holding the lock, until those waiting now have had it (timeout_s at most).

        Only those there when called: a stream of new callers cannot hold the cycle up for
        longer than one turn each.
        """
        if self._arrived == self._served or self._is_owned():
            return   # nobody waits, or this thread holds it: the waiters could not take it
        with self._turns:
            due = self._arrived
            self._turns.wait_for(lambda: self._served >= due, timeout_s)


@dataclass
class Logs:
    """Where the driver says things: info, warnings, errors (the node's logger, or print)."""

    info: Log
    warn: Log
    error: Log


@dataclass
class Context:
    """The state the driver's parts share (see the module docstring)."""

    config: DriverConfig
    roster: Roster
    link: Link
    tasks: TaskRunner
    port: PortState
    stale: StaleGuard
    clock: Callable[[], float]
    log: Logs
    # Serialises requests (services, topics, the cycle) over the driver's state; a read in
    # flight holds it from begin to end (driver/cycle.ReadInFlight).
    lock: SharedLock


@dataclass(frozen=True)
class Stats:
    """What the cycle and recovery counted, for diagnostics and the rate log."""

    cycles: int = 0            # state reads completed
    read_failures: int = 0     # servo reads that failed in the cycle
    retries: int = 0           # single-servo reads again within a cycle
    retry_successes: int = 0   # ... that got an answer
    stale_refused: int = 0     # samples refused as older than their request
    recoveries: int = 0        # hardware-error recoveries started
