"""The cycle's measured rate, and who is to blame when it falls short (driver/loop.py)."""

import time


class RateMeter:
    """Measured cycles per second over a sliding window."""

    def __init__(self, window_s: float = 1.0) -> None:
        self._window_s = window_s
        self.reset()

    def reset(self) -> None:
        """Start measuring afresh (a new activation)."""
        self._count = 0
        self._start = time.monotonic()
        self.rate_hz = 0.0
        self.windows = 0

    def tick(self) -> None:
        """Count one cycle."""
        self._count += 1
        now = time.monotonic()
        if now - self._start >= self._window_s:
            self.rate_hz = self._count / (now - self._start)
            self._count = 0
            self._start = now
            self.windows += 1


class Shortfall:
    """
    Decide whether the bus is why the loop falls short of loop_rate.

    A rate window below 90 % of the requested rate counts only when the bus work of the cycles
    (read, retries, write) took 90 % of the period or more; two such windows in a row blame the
    bus, once, with the measured rate. A loop slowed by a busy machine is reported as that.
    """

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the past (a new activation, a new loop_rate)."""
        self._bus_s = 0.0
        self._cycles = 0
        self._windows_bus = 0
        self._windows_cpu = 0
        self.blamed = False

    def add_cycle(self, bus_s: float) -> None:
        """Count one cycle and the time it spent on the bus."""
        self._bus_s += bus_s
        self._cycles += 1

    def window(self, measured_hz: float, requested_hz: float) -> str:
        """Close a rate window; return 'bus', 'machine' or '' (what to report, once)."""
        busy = self._bus_s / self._cycles if self._cycles else 0.0
        self._bus_s = 0.0
        self._cycles = 0
        if measured_hz >= 0.9 * requested_hz:
            self._windows_bus = self._windows_cpu = 0
            self.blamed = False
            return ''
        if busy >= 0.9 / requested_hz:
            self._windows_bus += 1
            self._windows_cpu = 0
        else:
            self._windows_cpu += 1
            self._windows_bus = 0
        if self.blamed:
            return ''
        if self._windows_bus >= 2:
            self.blamed = True
            return 'bus'
        if self._windows_cpu >= 2:
            self.blamed = True
            return 'machine'
        return ''
