"""
What every part of the driver shares: one context, handed to each part at construction.

The configuration (replaced whole when a runtime parameter changes: every part reads it from
here, so none keeps a stale copy), the servos (Roster), the link to the bus, the tasks in
progress, whether the port is lost, the guard that dates samples, the clock, the log and the
lock that serialises requests with the cycle.
"""

from dataclasses import dataclass
import threading
from typing import Callable

from dxl_servo_driver.config import DriverConfig
from dxl_servo_driver.driver.link import Link
from dxl_servo_driver.driver.servo import Log, PortState, Roster, StaleGuard
from dxl_servo_driver.tasks import TaskRunner


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
    lock: threading.RLock


@dataclass(frozen=True)
class Stats:
    """What the cycle and recovery counted, for diagnostics and the rate log."""

    cycles: int = 0            # state reads completed
    read_failures: int = 0     # servo reads that failed in the cycle
    retries: int = 0           # single-servo reads again within a cycle
    retry_successes: int = 0   # ... that got an answer
    stale_refused: int = 0     # samples refused as older than their request
    recoveries: int = 0        # hardware-error recoveries started
